"""The Blender example, run in Blender itself (Debian's blender, which .ci/run installs): a
.blend with the cloud as a Volume object (moved and turned) and a sun, the example baked over
two frames in background mode. Its maps equal `umbra bake` with the object's matrix as --xform
and the sun's direction, pixel for pixel, and both frames share one camera."""

import json
import os
import pathlib
import shutil
import subprocess

import numpy as np
import OpenEXR
import pytest

import umbra
from conftest import DATA

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "blender_shadow_map.py"

SETUP = """
import bpy, math
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.object.volume_import(filepath={vdb!r})
vol = bpy.context.active_object
vol.location = (1.0, 0.0, -2.0)
vol.rotation_euler = (0.0, 0.0, math.radians(30))
bpy.ops.object.light_add(type="SUN", rotation=(math.radians(40), 0.0, math.radians(20)))
bpy.context.view_layer.objects.active = vol
scene = bpy.context.scene
scene.frame_start, scene.frame_end = 1, 2
bpy.ops.wm.save_as_mainfile(filepath={blend!r})
"""


@pytest.mark.skipif(shutil.which("blender") is None and not os.environ.get("CI"),
                    reason="no blender (.ci/run installs Debian's; under CI its absence fails)")
def test_blender_example_in_blender(tmp_path, cli):
    assert shutil.which("blender"), "blender is not installed"
    # The installed package alone on Blender's path (Blender's own Python and NumPy).
    site = tmp_path / "site"
    shutil.copytree(pathlib.Path(umbra.__file__).parent, site / "umbra",
                    ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, PYTHONPATH=str(site))
    blend = tmp_path / "scene.blend"
    (tmp_path / "setup.py").write_text(SETUP.format(vdb=str(DATA / "cloud.vdb"), blend=str(blend)))
    run = lambda *a: subprocess.run(["blender", "-b", *map(str, a)], env=env, capture_output=True,
                                    text=True, timeout=600)
    p = run("--factory-startup", "--python", tmp_path / "setup.py")
    assert blend.exists(), p.stdout + p.stderr
    p = run(blend, "--python-exit-code", "1", "--python", EXAMPLE)
    assert p.returncode == 0, p.stdout + p.stderr
    maps = [tmp_path / "shadow_0001.exr", tmp_path / "shadow_0002.exr"]
    assert all(m.exists() for m in maps), p.stdout + p.stderr
    cam = json.loads((tmp_path / "shadow_camera.json").read_text())
    xform = ",".join(repr(v) for row in cam["xform"] for v in row)
    light = ",".join(repr(v) for v in cam["light_dir"])
    assert cam["xform"][0][3] == 1.0 and cam["xform"][2][3] == -2.0  # the object's placement
    out = tmp_path / "cli.exr"
    cli("bake", DATA / "cloud.vdb", f"--xform={xform}", f"--light-dir={light}", "--res", "512",
        "--spp", "1", "-o", out, "--quiet")
    want = OpenEXR.File(str(out)).channels()["T"].pixels
    for m in maps:
        got = OpenEXR.File(str(m)).channels()["T"].pixels
        assert np.array_equal(got, want), m
    assert want.min() < 0.2
