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
            # Point i has ray id i (its stage light's directions, a sun 0.53 degrees across).
            _, one, _ = cli("query", stage, "--frame", f["frame"], "--light", "sun",
                            "--at", f"{w[0]!r},{w[1]!r},{w[2]!r}", "--ray-id", i, "--json")
            assert f["T"][i] == json.loads(one)["T"], (f["frame"], i)
        assert min(f["T"]) < 1.0  # some points are in the cloud's shadow


def test_a_subframe_and_a_point_light(cli, tmp_path):
    """At a subframe usd-core interpolates the f32 samples in f32 (its answer rounded to f32),
    umbra in f64: the world positions agree to within an f32 ulp of the local coordinates
    (2.0e-7 world units at most over this stage's subframes, points up to 5 units from the
    origin). Each answer is the explicit query at umbra's own position, bit for bit, and
    within 1e-6 of the one at usd-core's."""
    stage = tmp_path / "shot.usdc"
    st = _with_points(stage)
    for t in (1.5, 1.7, 1.95):
        _, js, _ = cli("query", stage, "--positions", "/World/forest/trees", "--light", "lamp",
                       "--frame", t, "--json")
        f = json.loads(js)["frames"][0]
        world = np.array([list(w) for w in _world(st, "/World/forest/trees", t)])
        gap = np.abs(np.array(f["positions"]) - world).max()
        assert gap <= 2.5e-7, (t, gap)
        for i in (0, 13, 39):
            own, usd = f["positions"][i], world[i]
            _, one, _ = cli("query", stage, "--frame", t, "--light", "lamp",
                            "--at", ",".join(repr(c) for c in own), "--ray-id", i, "--json")
            assert f["T"][i] == json.loads(one)["T"], (t, i)
            _, two, _ = cli("query", stage, "--frame", t, "--light", "lamp",
                            "--at", ",".join(repr(float(c)) for c in usd), "--ray-id", i,
                            "--json")
            assert f["T"][i] == pytest.approx(json.loads(two)["T"], rel=1e-6), (t, i)


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


def _points_job(tmp_path, extra=""):
    """A job of two bakes (the shot under the sun, frames 1-2) and a `[[positions]]` entry
    over frames 1-2: tasks 0-1 bake, tasks 2-3 answer the trees."""
    job = tmp_path / "job.toml"
    job.write_text(f"""output = "out/{{light}}.{{frame:04}}.exr"
[[inputs]]
usd = "shot.usdc"
frames = [1, 2]
[[lights]]
usd = "/Lights/sun"
[bake]
res = 16
framing = "per-frame"
[[positions]]
usd = "shot.usdc"
prim = "/World/forest/trees"
light = "sun"
frames = [1, 2]
usd_out = "out/trees.usda"
{extra}""")
    return job


def test_a_positions_job_in_shards_is_the_query(cli, tmp_path):
    stage = tmp_path / "shot.usdc"
    _with_points(stage)
    job = _points_job(tmp_path)
    _, schema, _ = cli("batch", "--schema")
    spec = json.loads(schema)["$defs"]["PositionsSpec"]
    assert {"usd", "prim", "usd_out"} <= set(spec["required"]), spec
    assert spec["additionalProperties"] is False and "samples" in spec["properties"]
    assert "positions" in json.loads(schema)["properties"]
    _, plan, _ = cli("batch", job, "--plan")
    assert [l.split()[-1] for l in plan.splitlines()] == ["0", "1", "2", "3"], plan
    code, st, _ = cli("batch", job, "--status", "--json", check=False)
    missing = json.loads(st)["missing"]
    assert code == 3 and [t["task"] for t in missing] == [0, 1, 2, 3], st
    assert missing[2]["output"].endswith("trees.points/1.json") and missing[3]["light"] == "sun"
    _, out, _ = cli("batch", job, "--shard", "1/2")  # tasks 0 and 2: frame 1 of the trees
    layer = tmp_path / "out" / "trees.usda"
    assert "1 frames of per-point transmittance" in out, out
    code, st, _ = cli("batch", job, "--status", check=False)
    assert code == 3 and "missing task 3" in st and "trees.points" in st, st
    cli("batch", job, "--shard", "2/2")
    ref = tmp_path / "ref.usda"
    cli("query", stage, "--positions", "/World/forest/trees", "--light", "sun",
        "--frames", "1-2", "--usd-out", ref)
    assert layer.read_text() == ref.read_text()
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths = [str(layer), str(stage)]
    st = Usd.Stage.Open(root)
    pv = UsdGeom.PrimvarsAPI(st.GetPrimAtPath("/World/forest/trees")).GetPrimvar(
        "umbra:transmittance:sun")
    assert pv.GetTimeSamples() == [1.0, 2.0]
    code, st, _ = cli("batch", job, "--status")
    assert code == 0 and "4 done" in st, st
    # Resumed: every task up to date; the log records the positions tasks like bakes.
    log = tmp_path / "again.jsonl"
    _, out, _ = cli("batch", job, "--log", log)
    assert "0 baked, 4 skipped" in out, out
    recs = [json.loads(l) for l in log.read_text().splitlines()]
    pos = [r for r in recs if r["task"] >= 2]
    assert [(r["status"], r["light"]) for r in pos] == [("skipped", "sun")] * 2, recs
    assert pos[0]["output"].endswith("1.json") and pos[0]["input"].endswith("shot.usdc")
    # A stage only touched is no change; a re-authored one answers again.
    stage.touch()
    _, out, _ = cli("batch", job, "--task", "3")
    assert "0 baked, 1 skipped" in out, out
    layer = Sdf.Layer.FindOrOpen(str(stage))
    layer.customLayerData = {"note": "re-authored"}
    layer.Save()
    _, out, _ = cli("batch", job, "--task", "3")
    assert "1 baked" in out, out


def test_a_positions_only_job(cli, tmp_path):
    stage = tmp_path / "shot.usdc"
    _with_points(stage)
    job = tmp_path / "job.toml"
    job.write_text("""[bake]
estimator = "ratio"
samples = 8
[[positions]]
usd = "shot.usdc"
prim = "/World/forest/rocks"
light = "lamp"
frames = [2, 2]
usd_out = "rocks.usda"
estimator = "regular"
""")
    _, out, _ = cli("batch", job)
    assert "1 baked" in out, out
    ref = tmp_path / "ref.usda"
    cli("query", stage, "--positions", "/World/forest/rocks", "--light", "lamp",
        "--frame", 2, "--usd-out", ref)
    assert (tmp_path / "rocks.usda").read_text() == ref.read_text()
    assert (tmp_path / "umbra_batch.jsonl").is_file()


@pytest.mark.parametrize("extra, key", [
    ('colour = 1', "colour"),
    ('estimator = "nope"', "positions[0].estimator"),
    ('density_scale = -1.0', "positions[0].density_scale"),
])
def test_bad_positions_entries_are_refused_before_any_work(cli, tmp_path, extra, key):
    _with_points(tmp_path / "shot.usdc")
    job = _points_job(tmp_path, extra)
    e = _err(cli, "batch", job)
    assert key in e, e
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("entry, key", [
    ('usd = "shot.usdc"\nusd_out = "t.usda"', "prim"),
    ('prim = "/World/forest/trees"\nusd_out = "t.usda"', "usd"),
    ('usd = "shot.usdc"\nprim = "/World/forest/trees"\nusd_out = "t.usdc"',
     "positions[0].usd_out"),
    ('usd = "shot.usdc"\nprim = "/World/nope"\nusd_out = "t.usda"', "positions[0]"),
])
def test_bad_positions_keys_name_their_key(cli, tmp_path, entry, key):
    _with_points(tmp_path / "shot.usdc")
    job = tmp_path / "job.toml"
    job.write_text(f"[[positions]]\n{entry}\n")
    e = _err(cli, "batch", job)
    assert key in e, e
    assert not (tmp_path / "t.usda").exists() and not (tmp_path / "umbra_batch.jsonl").exists()
