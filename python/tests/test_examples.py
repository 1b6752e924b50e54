"""The examples' Python halves run on real files (the DCC glue is checked by compiling it)."""

import importlib.util
import pathlib
import py_compile

import numpy as np

import umbra
from conftest import DATA

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_examples_compile():
    files = sorted(EXAMPLES.glob("*.py"))
    assert len(files) >= 2
    for f in files:
        py_compile.compile(str(f), doraise=True)


def test_houdini_shadow_attribute():
    sop = load("houdini_shadow_sop")
    rng = np.random.default_rng(0)
    p = rng.uniform([-2, 0, -2], [2, 3, 2], (5000, 3)).astype(np.float32)  # Houdini's P is f32
    cache = {}
    t = sop.shadow_at_points(p.reshape(-1), str(DATA / "cloud.vdb"), cache=cache)
    assert t.dtype == np.float32 and t.shape == (5000,)
    vol = umbra.Volume(DATA / "cloud.vdb")
    want = vol.transmittance_to_light(p.astype(np.float64), light_dir=(-1, -1, 0))
    assert np.array_equal(t, want.astype(np.float32))
    assert len(cache) == 1
    sop.shadow_at_points(p[:10], str(DATA / "cloud.vdb"), cache=cache)
    assert len(cache) == 1  # loaded once


def test_blender_sequence_keeps_its_camera(tmp_path):
    bl = load("blender_shadow_map")
    m = np.eye(4)
    m[:3, 3] = (1.0, 0.0, -2.0)
    img1, cam1 = bl.bake_frame(str(DATA / "cloud.vdb"), m.tolist(), (0.3, -1, 0.1), str(tmp_path / "a.exr"), res=64)
    img2, cam2 = bl.bake_frame(str(DATA / "cloud.vdb"), m.tolist(), (0.3, -1, 0.1), str(tmp_path / "b.exr"),
                               camera=cam1, density_scale=2.0)
    assert cam2["camera"] == cam1["camera"] and img2.shape == img1.shape
    assert (img2 <= img1).all() and img1.min() < 0.5
    assert (tmp_path / "a.exr").exists() and (tmp_path / "b.exr").exists()
