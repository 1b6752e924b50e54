"""Blender: bake a shadow map of the active Volume object for the scene's sun, with umbra.

Run from Blender's Text Editor, or ``blender scene.blend --background --python
blender_shadow_map.py``, with the umbra wheel installed into Blender's Python
(``<blender python> -m pip install ./python`` from the umbra checkout).

It reads the active object's OpenVDB file (a Volume object: its data's ``filepath``; for a
sequence the file of the current frame), places the grid with the object's world matrix (as
Cycles does), takes the direction the first sun lamp shines, and writes ``//shadow_####.exr``
beside the .blend: a transmittance map from the sun (T = 1 in clear air, 0 behind opaque
cloud) whose camera is in its header. The camera of the first frame is kept for the whole
frame range, so the maps of a sequence line up pixel for pixel instead of swimming as the cloud
changes shape. The map is also loaded as an image data-block to look at or to use in a shader.
"""

import json
import os

import numpy as np

import umbra


def bake_frame(vdb_path, matrix_world, sun_dir, out_path, res=512, camera=None, grid="density",
               density_scale=1.0):
    """Bake one frame: the map and its camera (pass it back in for the next frames)."""
    vol = umbra.Volume(vdb_path, grid=grid, density_scale=density_scale,
                       xform=np.asarray(matrix_world, dtype=np.float64))
    if camera is None:
        image, camera = vol.bake(light_dir=sun_dir, res=res)
    else:
        image, camera = vol.bake(camera=camera)
    umbra.write_exr(out_path, image, camera, overwrite=True)
    return image, camera


def sun_direction(light_object):
    """The direction a Blender sun shines: its local -Z in world space."""
    m = light_object.matrix_world
    return tuple(-m[r][2] for r in range(3))


def main():
    import bpy  # noqa: PLC0415 (only inside Blender)

    scene = bpy.context.scene
    obj = bpy.context.active_object
    if obj is None or obj.type != "VOLUME":
        raise RuntimeError("select a Volume object (an imported OpenVDB file)")
    suns = [o for o in scene.objects if o.type == "LIGHT" and o.data.type == "SUN"]
    if not suns:
        raise RuntimeError("the scene has no sun lamp")
    sun = sun_direction(suns[0])
    camera = None
    for frame in range(scene.frame_start, scene.frame_end + 1):
        scene.frame_set(frame)
        vdb = bpy.path.abspath(obj.data.filepath)
        if obj.data.is_sequence:
            vdb = bpy.path.abspath(obj.data.grids.frame_filepath)
        out = bpy.path.abspath(f"//shadow_{frame:04d}.exr")
        matrix = [list(row) for row in obj.matrix_world]
        try:
            _, camera = bake_frame(vdb, matrix, sun, out, camera=camera)
        except umbra.Error as e:
            raise RuntimeError(f"frame {frame}: {e}") from e
        print(f"umbra: {out}")
    with open(bpy.path.abspath("//shadow_camera.json"), "w") as f:
        json.dump(camera, f)
    bpy.data.images.load(out, check_existing=True)


if __name__ == "__main__":
    try:
        import bpy  # noqa: F401
    except ImportError:
        raise SystemExit("run this inside Blender (see the module docstring)")
    main()
