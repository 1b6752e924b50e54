"""Per-point attenuation over a shot (`umbra query STAGE --positions PRIM`): every point of a
`Points` prim or `PointInstancer`, placed by usd-core's local-to-world at each frame, equals
the explicit `query --at` at that world position; the `--usd-out` layer reads back in usd-core
as a vertex primvar, one time sample per frame; Python's `usd_point_transmittance` is the CLI."""

import json
import pathlib

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core (pip install usd-core) writes the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom, Vt  # noqa: E402

from test_usd import _err, _stage  # noqa: E402


def _with_points(path):
    """test_usd's shot (an animated cloud, a sun and a lamp) with a Points prim of 40 points
    under an animated group, and a PointInstancer of 25 under the same group."""
    st = _stage(path)
    g = UsdGeom.Xform.Define(st, "/World/forest")
    op = g.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 1)
    op.Set(Gf.Vec3d(0.3, -0.2, 0.1), 2)
    g.AddRotateZOp().Set(15.0)
    rng = np.random.default_rng(7)
    pts = UsdGeom.Points.Define(st, "/World/forest/trees")
    a = rng.uniform(-1.5, 1.5, (40, 3)).astype(np.float32)
    pts.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(a), 1)
    pts.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(a + np.float32(0.25)), 2)
    inst = UsdGeom.PointInstancer.Define(st, "/World/forest/rocks")
    b = rng.uniform(-1.5, 1.5, (25, 3)).astype(np.float32)
    inst.GetPositionsAttr().Set(Vt.Vec3fArray.FromNumpy(b))
    inst.GetProtoIndicesAttr().Set(Vt.IntArray([0] * 25))
    st.Save()
    return st


def _world(st, prim, t):
    p = st.GetPrimAtPath(prim)
    attr = "points" if p.IsA(UsdGeom.Points) else "positions"
    m = UsdGeom.XformCache(t).GetLocalToWorldTransform(p)
    return [m.Transform(Gf.Vec3d(*map(float, q))) for q in p.GetAttribute(attr).Get(t)]


@pytest.mark.parametrize("prim", ["/World/forest/trees", "/World/forest/rocks"])
def test_every_point_is_the_explicit_query(cli, tmp_path, prim):
    stage = tmp_path / "shot.usdc"
    st = _with_points(stage)
    _, js, _ = cli("query", stage, "--positions", prim, "--light", "sun", "--frames", "1-2",
                   "--json")
    doc = json.loads(js)
    assert doc["prim"] == prim and doc["light"] == "/Lights/sun"
    assert [f["frame"] for f in doc["frames"]] == [1, 2]
    for f in doc["frames"]:
        world = _world(st, prim, f["frame"])
        assert len(f["T"]) == len(world)
        assert np.allclose(f["positions"], [list(w) for w in world], rtol=0, atol=1e-12)
        for i in range(0, len(world), 7):
            w = world[i]
            _, one, _ = cli("query", stage, "--frame", f["frame"], "--light", "sun",
                            "--at", f"{w[0]!r},{w[1]!r},{w[2]!r}", "--json")
            assert f["T"][i] == json.loads(one)["T"], (f["frame"], i)
        assert min(f["T"]) < 1.0  # some points are in the cloud's shadow


def test_a_subframe_and_a_point_light(cli, tmp_path):
    stage = tmp_path / "shot.usdc"
    st = _with_points(stage)
    _, js, _ = cli("query", stage, "--positions", "/World/forest/trees", "--light", "lamp",
                   "--frame", 1.5, "--json")
    f = json.loads(js)["frames"][0]
    world = _world(st, "/World/forest/trees", 1.5)
    for i in (0, 13, 39):
        w = world[i]
        _, one, _ = cli("query", stage, "--frame", 1.5, "--light", "lamp",
                        "--at", f"{w[0]!r},{w[1]!r},{w[2]!r}", "--json")
        assert f["T"][i] == json.loads(one)["T"]


def test_usd_out_reads_back_as_a_vertex_primvar(cli, tmp_path):
    stage = tmp_path / "shot.usdc"
    _with_points(stage)
    layer = tmp_path / "t.usda"
    _, text, _ = cli("query", stage, "--positions", "/World/forest/trees", "--light", "sun",
                     "--frames", "1-2", "--usd-out", layer)
    assert "frame 1: 40 points" in text and "frame 2: 40 points" in text, text
    _, js, _ = cli("query", stage, "--positions", "/World/forest/trees", "--light", "sun",
                   "--frames", "1-2", "--json")
    doc = json.loads(js)
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths = [str(layer), str(stage)]
    st = Usd.Stage.Open(root)
    pv = UsdGeom.PrimvarsAPI(st.GetPrimAtPath("/World/forest/trees")).GetPrimvar(
        "umbra:transmittance:sun")
    assert pv and pv.GetInterpolation() == "vertex"
    assert pv.GetTimeSamples() == [1.0, 2.0]
    for f in doc["frames"]:
        got = np.array(pv.Get(f["frame"]))
        assert got.dtype == np.float32
        assert np.array_equal(got, np.array(f["T"], dtype=np.float32))
    # Checked before any work, written atomically: an existing layer needs --force.
    e = _err(cli, "query", stage, "--positions", "/World/forest/trees", "--light", "sun",
             "--usd-out", layer)
    assert "t.usda" in e, e
    cli("query", stage, "--positions", "/World/forest/trees", "--light", "sun", "--usd-out",
        layer, "--force")


def test_python_is_the_cli(cli, tmp_path):
    import umbra

    stage = tmp_path / "shot.usdc"
    _with_points(stage)
    got = umbra.usd_point_transmittance(stage, "/World/forest/rocks", light="sun",
                                        frames=[1, 2])
    _, js, _ = cli("query", stage, "--positions", "/World/forest/rocks", "--light", "sun",
                   "--frames", "1-2", "--json")
    doc = json.loads(js)
    assert sorted(got) == [1.0, 2.0]
    for f in doc["frames"]:
        assert isinstance(got[f["frame"]], np.ndarray)
        assert np.array_equal(got[f["frame"]], np.array(f["T"]))


def test_bad_positions_get_one_clear_error(cli, tmp_path):
    stage = tmp_path / "shot.usdc"
    st = _with_points(stage)
    e = _err(cli, "query", stage, "--positions", "/World/cloud", "--light", "sun")
    assert "/World/cloud" in e and "Volume" in e and "Points" in e, e
    e = _err(cli, "query", stage, "--positions", "/World/nope", "--light", "sun")
    assert "/World/nope" in e and "/World/forest/trees" in e, e
    e = _err(cli, "query", stage, "--positions", "/World/forest/trees", "--light", "moon")
    assert "moon" in e, e
    e = _err(cli, "query", pathlib.Path(__file__).parents[2] / "data" / "cloud.vdb",
             "--positions", "/World/forest/trees")
    assert "--positions" in e, e
    # A point count that changes between frames: said on stderr, each frame as authored.
    pts = UsdGeom.Points(st.GetPrimAtPath("/World/forest/trees"))
    pts.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, 0)] * 3), 2)
    st.Save()
    code, js, err = cli("query", stage, "--positions", "/World/forest/trees", "--light", "sun",
                        "--frames", "1-2", "--json")
    assert code == 0 and "40 points at frame 1 and 3 at frame 2" in err, err
    assert [len(f["T"]) for f in json.loads(js)["frames"]] == [40, 3]
