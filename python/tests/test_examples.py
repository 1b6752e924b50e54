"""The examples' Python halves run on real files (the DCC glue is checked by compiling it)."""

import importlib.util
import pathlib
import py_compile

import numpy as np
import pytest

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


class _Geometry:
    """What the Houdini example uses of hou.Geometry, over a NumPy array of P."""

    def __init__(self, p):
        self.p = np.ascontiguousarray(p, dtype=np.float32)
        self.attribs = {}

    def pointFloatAttribValuesAsString(self, name):
        assert name == "P"
        return self.p.tobytes()

    def findPointAttrib(self, name):
        return self.attribs.get(name)

    def addAttrib(self, kind, name, default):
        assert kind == "point" and default == 1.0
        self.attribs[name] = np.full(len(self.p), default, dtype=np.float32)

    def setPointFloatAttribValuesFromString(self, name, data):
        assert name in self.attribs
        self.attribs[name] = np.frombuffer(data, dtype=np.float32).copy()


class _ParmTuple:
    def __init__(self, v):
        self.v = v

    def eval(self):
        return self.v


def test_houdini_sop_body_with_a_stand_in_hou(monkeypatch):
    """The SOP's code run as a Python SOP runs it, against a stand-in for the hou calls it
    makes (point positions in, the shadowT attribute out, spare parameters, errors)."""
    import sys
    import types

    rng = np.random.default_rng(1)
    geo = _Geometry(rng.uniform([-2, 0, -2], [2, 3, 2], (300, 3)))
    parms = {"vdb": ("$DATA/cloud.vdb",), "lightdir": (0.0, -1.0, 0.5), "density": (2.0,)}

    class NodeError(Exception):
        pass

    node = types.SimpleNamespace(
        geometry=lambda: geo,
        parmTuple=lambda name: _ParmTuple(parms[name]) if name in parms else None,
        type=lambda: types.SimpleNamespace(name=lambda: "python"),
    )
    hou = types.ModuleType("hou")
    hou.pwd = lambda: node
    hou.expandString = lambda s: s.replace("$DATA", str(DATA))
    hou.session = types.ModuleType("hou.session")
    hou.NodeError = NodeError
    hou.attribType = types.SimpleNamespace(Point="point")
    monkeypatch.setitem(sys.modules, "hou", hou)
    import runpy

    runpy.run_path(str(EXAMPLES / "houdini_shadow_sop.py"), run_name="__main__")
    vol = umbra.Volume(DATA / "cloud.vdb", density_scale=2.0)
    want = vol.transmittance_to_light(geo.p.astype(np.float64), light_dir=(0, -1, 0.5))
    assert np.array_equal(geo.attribs["shadowT"], want.astype(np.float32))
    assert (want < 0.5).any()
    # A missing file is the node's error, with umbra's message.
    parms["vdb"] = ("$DATA/nope.vdb",)
    with pytest.raises(NodeError, match="nope.vdb"):
        runpy.run_path(str(EXAMPLES / "houdini_shadow_sop.py"), run_name="__main__")


def _readme_block(heading: str, lang: str) -> str:
    text = (pathlib.Path(__file__).resolve().parents[2] / "README.md").read_text()
    section = text.split(heading, 1)[1]
    return section.split(f"```{lang}\n", 1)[1].split("```", 1)[0]


def test_readme_python_example_runs_as_written(tmp_path, monkeypatch):
    # In a scratch directory beside a link to data/, so the example's file lands there.
    (tmp_path / "data").symlink_to(DATA)
    monkeypatch.chdir(tmp_path)
    names: dict = {}
    exec(compile(_readme_block("## Python", "python"), "README.md", "exec"), names)
    assert names["T"].shape == (2,) and names["image"].shape == (256, 256)
    assert abs(float(names["T_sun"][0]) - 0.3116) < 1e-3
    assert (tmp_path / "shadow_py.exr").is_file()
    # Run from the repository root, as the README says, what it writes is git-ignored (no
    # untracked files left in the checkout).
    ignored = (pathlib.Path(__file__).resolve().parents[2] / ".gitignore").read_text().split()
    written = sorted(p.name for p in tmp_path.iterdir() if p.name != "data")
    assert written == ["shadow_py.exr", "shadow_tiled.exr"], written
    assert all(f"/{n}" in ignored for n in written), (written, ignored)
