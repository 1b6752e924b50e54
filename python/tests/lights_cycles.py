"""Render receivers under a VDB cloud with Blender's Cycles (the `bpy` module) for
test_lights_cycles.py: the soft shadows of a sun with an angle and of a sphere light.

Run with the Python that has `bpy` (a venv of its own: bpy pins its own numpy). Reads a JSON
job on stdin:

    {"vdb": path, "density_scale": S, "work": folder, "res": N, "threads": 2,
     "plane": {"y": Y, "x": [X0, X1], "z": [Z0, Z1]},
     "cap": {"centre": [x, y, z], "radius": R, "quads": n},  (optional)
     "step_rate": r, "max_steps": n,
     "renders": [{"name": ..., "light": {"kind": "sun", "dir": [dx, dy, dz], "angle": deg}
                                  or {"kind": "sphere", "pos": [x, y, z], "radius": r,
                                      "soft_falloff": false},
                  "receiver": "plane" or "cap", "volume": true/false,
                  "volume_offset": [dx, dy, dz], "samples": n, "seed": s}, ...]}

and writes `<work>/<name>.exr` per render (multilayer, 32-bit float: the combined pass, and the
position and normal passes: the world point each pixel sees and its normal), then
`{"seconds": {name: s}}` on stdout.

The scene, in the VDB's own world coordinates:

- the receiver, seen from below by an orthographic camera looking up +y over [X0, X1] x
  [Z0, Z1] (so no camera ray meets the cloud above it), a white Translucent BSDF: light from
  above reaches the camera through it weighted by |cos| to its normal. Either the plane
  y = Y, or the lower cap of the sphere of radius R around `centre` (flat quads): every point
  of the cap faces the centre;
- the cloud: a Volume object of the file, moved by `volume_offset` (test_lights_cycles.py
  moves it by half a voxel: Cycles' voxel centres are half a voxel off OpenVDB's), its
  material a Volume Absorption of black colour (absorption = (1 - colour) x density) whose
  density is the grid `density` x S: sigma = value x S per world unit, umbra's
  `--density-scale S`; linear interpolation, full (32-bit) precision, no clipping; no
  scattering, so nothing is added, only absorbed. Heterogeneous ray marching at `step_rate`
  times the voxel size, each shadow ray's steps jittered;
- the light: a sun of angle `angle` (Cycles' `angle` is the disc's angular diameter, sampled
  uniformly in solid angle over the cone of half-angle angle / 2, kernel/light/distant.h),
  or a point light of radius r with Soft Falloff off (Cycles then samples the sphere's
  visible cap uniformly in solid angle and ends the shadow ray on the sphere,
  kernel/light/point.h);
- a black world, no bounces (direct light only), no clamping, no denoising, a pixel filter of
  0.01 pixel (each pixel's samples sit at its centre), the Standard view transform, linear.
"""

import json
import math
import os
import sys
import time

import bpy
from mathutils import Matrix, Vector


def scene_setup(job: dict):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.filter_width = 0.01
    c.max_bounces = 0
    c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = c.volume_bounces = 0
    # A shadow ray crosses the volume's hull (a mesh) as transparent hits: with 0 allowed, the
    # hull would be opaque.
    c.transparent_max_bounces = 1024
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.volume_step_rate = float(job["step_rate"])
    c.volume_max_steps = int(job["max_steps"])
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(job.get("threads", 2))
    n = int(job["res"])
    scene.render.resolution_x = scene.render.resolution_y = n
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    settings.exr_codec = "NONE"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.view_layers[0].use_pass_position = True
    scene.view_layers[0].use_pass_normal = True
    world = bpy.data.worlds.new("black")
    world.use_nodes = False
    world.color = (0.0, 0.0, 0.0)
    scene.world = world

    # The receivers, seen from below: a plane, and a cap of a sphere around the sphere light.
    p = job["plane"]
    y, (x0, x1), (z0, z1) = p["y"], p["x"], p["z"]
    mat = bpy.data.materials.new("receiver")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    bsdf = nodes.new("ShaderNodeBsdfTranslucent")
    bsdf.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    out = nodes.new("ShaderNodeOutputMaterial")
    links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    # Larger than the view, unevenly: the quads' diagonals (between their two triangles) must
    # not pass through pixel centres, where the 0.01-pixel filter puts every sample (a sample
    # exactly on a shared edge can miss both triangles).
    a0, a1, b0, b1 = x0 - 0.31, x1 + 0.73, z0 - 0.57, z1 + 0.19
    receivers = {}
    for name in ("plane", "cap"):
        if name == "cap" and "cap" not in job:
            continue
        n = 1 if name == "plane" else int(job["cap"].get("quads", 96))
        xs = [a0 + (a1 - a0) * i / n for i in range(n + 1)]
        zs = [b0 + (b1 - b0) * k / n for k in range(n + 1)]
        if name == "plane":
            verts = [(x, y, z) for z in zs for x in xs]
        else:
            (cx, cy, cz), rad = job["cap"]["centre"], job["cap"]["radius"]
            verts = [(x, cy - math.sqrt(rad * rad - (x - cx) ** 2 - (z - cz) ** 2), z)
                     for z in zs for x in xs]
        w = n + 1
        faces = [(k * w + i, k * w + i + 1, (k + 1) * w + i + 1, (k + 1) * w + i)
                 for k in range(n) for i in range(n)]
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata(verts, [], faces)
        mesh.materials.append(mat)
        ob = bpy.data.objects.new(name, mesh)
        scene.collection.objects.link(ob)
        receivers[name] = ob

    # The orthographic camera below the plane, looking up +y: image right = +x, image up = +z.
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = float(max(x1 - x0, z1 - z0))
    cam_data.clip_start, cam_data.clip_end = 0.1, 100.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.matrix_world = Matrix(
        (
            (1.0, 0.0, 0.0, (x0 + x1) / 2),
            (0.0, 0.0, -1.0, y - 5.0),
            (0.0, 1.0, 0.0, (z0 + z1) / 2),
            (0.0, 0.0, 0.0, 1.0),
        )
    )
    scene.collection.objects.link(cam)
    scene.camera = cam

    # The cloud: the file's grids in its own world coordinates.
    vol = bpy.data.volumes.new("cloud")
    vol.filepath = job["vdb"]
    vol.render.precision = "FULL"
    vol.render.clipping = 0.0
    vol.render.space = "OBJECT"
    vol.render.step_size = 0.0  # automatic: the voxel size, times the step rates
    cloud = bpy.data.objects.new("cloud", vol)
    scene.collection.objects.link(cloud)
    vmat = bpy.data.materials.new("absorb")
    vmat.use_nodes = True
    vmat.cycles.volume_interpolation = "LINEAR"
    vmat.cycles.homogeneous_volume = False
    vmat.cycles.volume_step_rate = 1.0
    vn, vl = vmat.node_tree.nodes, vmat.node_tree.links
    vn.clear()
    attr = vn.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = "density"
    scale = vn.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = float(job["density_scale"])
    absorb = vn.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    vout = vn.new("ShaderNodeOutputMaterial")
    vl.new(attr.outputs["Fac"], scale.inputs[0])
    vl.new(scale.outputs["Value"], absorb.inputs["Density"])
    vl.new(absorb.outputs["Volume"], vout.inputs["Volume"])
    vol.materials.append(vmat)
    return scene, cloud, receivers


def set_light(scene, spec: dict):
    for ob in [o for o in scene.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(ob, do_unlink=True)
    if spec["kind"] == "sun":
        light = bpy.data.lights.new("sun", "SUN")
        light.angle = math.radians(float(spec["angle"]))
        light.energy = 1.0
        ob = bpy.data.objects.new("sun", light)
        d = Vector(spec["dir"]).normalized()
        # A sun shines along its local -Z.
        ob.matrix_world = d.to_track_quat("-Z", "Y").to_matrix().to_4x4()
    else:
        light = bpy.data.lights.new("sphere", "POINT")
        light.shadow_soft_size = float(spec["radius"])
        # Off: a sphere of uniform radiance. On (Blender's default), Cycles samples a disc of
        # radius r facing the receiver instead (kernel/light/point.h).
        light.use_soft_falloff = bool(spec.get("soft_falloff", False))
        light.energy = 1000.0
        ob = bpy.data.objects.new("sphere", light)
        ob.matrix_world = Matrix.Translation(Vector(spec["pos"]))
    light.use_shadow = True
    scene.collection.objects.link(ob)


def main() -> None:
    job = json.load(sys.stdin)
    scene, cloud, receivers = scene_setup(job)
    seconds = {}
    for r in job["renders"]:
        set_light(scene, r["light"])
        cloud.hide_render = not r["volume"]
        cloud.matrix_world = Matrix.Translation(Vector(r.get("volume_offset", (0.0, 0.0, 0.0))))
        for name, ob in receivers.items():
            ob.hide_render = name != r.get("receiver", "plane")
        scene.cycles.samples = int(r["samples"])
        scene.cycles.seed = int(r["seed"])
        scene.render.filepath = os.path.join(job["work"], r["name"] + ".exr")
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        seconds[r["name"]] = time.perf_counter() - t0
    sys.stdout.write("\n" + json.dumps({"seconds": seconds}) + "\n")


if __name__ == "__main__":
    main()
