"""USD's value resolution over time, held to usd-core: text layers with time-sampled asset
paths, linear interpolation of whole-number samples at subframes (every xformOp kind,
`umbra:densityScale`, lights), held assets, the three file formats, layer offsets and scales
on references, and value clips. Every answer is the `.vdb` bake or query built from what
usd-core says the stage means at that time."""

import json
import pathlib
import shutil

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core (pip install usd-core) writes the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdUtils, UsdVol  # noqa: E402

from conftest import DATA  # noqa: E402
from test_usd import _err, _same_pixels  # noqa: E402

CLOUD = DATA / "cloud.vdb"
COMMON = ["--res", "64", "--quiet", "--force"]


def _world(st, prim, t):
    return UsdGeom.XformCache(t).GetLocalToWorldTransform(st.GetPrimAtPath(prim))


def _xform(st, prim, t):
    """umbra's --xform (column vectors, row-major) from usd-core's local-to-world (rows)."""
    m = _world(st, prim, t)
    return ",".join(repr(m[c][r]) for r in range(4) for c in range(4))


def _sun(st, prim, t):
    d = _world(st, prim, t).TransformDir(Gf.Vec3d(0, 0, -1)).GetNormalized()
    return ",".join(repr(c) for c in d)


def _origin(st, prim, t):
    return ",".join(repr(c) for c in _world(st, prim, t).ExtractTranslation())


def _up(st):
    return "0,0,1" if UsdGeom.GetStageUpAxis(st) == "Z" else "0,1,0"


def _issue_stage(path):
    """The issue's stage: samples at frames 1 and 2 written as whole numbers in a text layer
    (usd-core writes 0.0 as `0`), a time-sampled asset path, and a sun that turns."""
    path = pathlib.Path(path)
    for f in (1, 2):
        shutil.copy(CLOUD, path.parent / f"cloud.{f:04d}.vdb")
    st = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(st, "Y")
    st.SetStartTimeCode(1)
    st.SetEndTimeCode(2)
    v = UsdVol.Volume.Define(st, "/World/cloud")
    x = UsdGeom.Xformable(v)
    rz, rx = x.AddRotateZOp(), x.AddRotateXOp()
    scale = v.GetPrim().CreateAttribute("umbra:densityScale", Sdf.ValueTypeNames.Double)
    for f, z, xx, s in ((1, 0.0, 10.0, 1.0), (2, 60.0, -30.0, 3.0)):
        rz.Set(z, f)
        rx.Set(xx, f)
        scale.Set(s, f)
    a = UsdVol.OpenVDBAsset.Define(st, "/World/cloud/density")
    for f in (1, 2):
        a.GetFilePathAttr().Set(Sdf.AssetPath(f"./cloud.{f:04d}.vdb"), f)
    a.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", a.GetPath())
    sun = UsdLux.DistantLight.Define(st, "/World/sun")
    sun.CreateAngleAttr(0.0)  # a point sun (extents: test_lights_usd.py)
    so = UsdGeom.Xformable(sun).AddRotateXOp()
    so.Set(-90.0, 1)
    so.Set(-30.0, 2)
    st.Save()
    return st


def _explicit(cli, st, t, out, vdb=None, light="/World/sun", volume="/World/cloud", extra=()):
    """The `.vdb` bake usd-core describes at time t: its file, matrix, densityScale, light."""
    prim = st.GetPrimAtPath(volume)
    field = prim.GetRelationship("field:density").GetTargets()[0]
    fp = st.GetPrimAtPath(field).GetAttribute("filePath").Get(t)
    vdb = vdb or fp.resolvedPath
    scale = prim.GetAttribute("umbra:densityScale").Get(t)
    args = [f"--xform={_xform(st, volume, t)}", f"--up={_up(st)}"]
    if scale is not None:
        args.append(f"--density-scale={scale!r}")
    lp = st.GetPrimAtPath(light)
    if lp.IsA(UsdLux.DistantLight):
        args.append(f"--light-dir={_sun(st, light, t)}")
    else:
        args.append(f"--light-pos={_origin(st, light, t)}")
    cli("bake", vdb, *args, "-o", out, *COMMON, *extra)
    return vdb


def test_the_issues_text_stage_is_interpolated_as_usd_core_does(cli, tmp_path):
    """Whole-number samples in a `.usda` interpolate, the time-sampled asset path reads and
    is held between samples."""
    st = _issue_stage(tmp_path / "shot.usda")
    assert "1: 0," in (tmp_path / "shot.usda").read_text()  # whole-number samples, as written
    for t in (1, 1.25, 1.5, 2):
        assert st.GetPrimAtPath("/World/cloud").GetAttribute("umbra:densityScale").Get(t) \
            == pytest.approx(1 + 2 * (t - 1))
        cli("bake", tmp_path / "shot.usda", "--frame", t, "--light", "sun",
            "-o", tmp_path / "u.exr", *COMMON)
        vdb = _explicit(cli, st, t, tmp_path / "v.exr")
        assert vdb.endswith("cloud.0001.vdb" if t < 2 else "cloud.0002.vdb"), (t, vdb)
        _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")
    # A query at 1.5 is the explicit query with usd-core's values.
    scale = st.GetPrimAtPath("/World/cloud").GetAttribute("umbra:densityScale").Get(1.5)
    _, js, _ = cli("query", tmp_path / "shot.usda", "--frame", 1.5, "--at", "0,1.2,0",
                   "--json")
    _, want, _ = cli("query", CLOUD, f"--xform={_xform(st, '/World/cloud', 1.5)}",
                     f"--light-dir={_sun(st, '/World/sun', 1.5)}",
                     f"--density-scale={scale!r}", "--at", "0,1.2,0", "--json")
    assert json.loads(js)["T"] == json.loads(want)["T"]


# Every xformOp kind USD has, each animated between whole-number samples at frames 1 and 2
# (rotations by distinct angles, so a wrong order or axis shows).
OPS = [
    ("translate", lambda x: x.AddTranslateOp(), Gf.Vec3d(0.3, -0.2, 0.1), Gf.Vec3d(-0.5, 0.4, 1)),
    ("scale", lambda x: x.AddScaleOp(), Gf.Vec3f(1, 1, 1), Gf.Vec3f(1.4, 0.8, 1.1)),
    ("rotateX", lambda x: x.AddRotateXOp(), 0.0, 40.0),
    ("rotateY", lambda x: x.AddRotateYOp(), 10.0, -50.0),
    ("rotateZ", lambda x: x.AddRotateZOp(), 0.0, 60.0),
    ("rotateXYZ", lambda x: x.AddRotateXYZOp(), Gf.Vec3f(10, 20, 30), Gf.Vec3f(-30, 5, 70)),
    ("rotateXZY", lambda x: x.AddRotateXZYOp(), Gf.Vec3f(5, 0, 0), Gf.Vec3f(25, 35, -15)),
    ("rotateYXZ", lambda x: x.AddRotateYXZOp(), Gf.Vec3f(0, 15, 0), Gf.Vec3f(40, -20, 10)),
    ("rotateYZX", lambda x: x.AddRotateYZXOp(), Gf.Vec3f(0, 0, 0), Gf.Vec3f(-10, 30, 50)),
    ("rotateZXY", lambda x: x.AddRotateZXYOp(), Gf.Vec3f(20, 0, 0), Gf.Vec3f(0, 45, 15)),
    ("rotateZYX", lambda x: x.AddRotateZYXOp(), Gf.Vec3f(0, 0, 5), Gf.Vec3f(35, 10, -25)),
    ("orient", lambda x: x.AddOrientOp(),
     Gf.Quatf(1, 0, 0, 0), Gf.Quatf(0.8660254, 0.5, 0, 0)),
    ("orientd", lambda x: x.AddOrientOp(UsdGeom.XformOp.PrecisionDouble, "d"),
     Gf.Quatd(1, 0, 0, 0), Gf.Quatd(0.9238795325112867, 0, 0.3826834323650898, 0)),
    ("transform", lambda x: x.AddTransformOp(),
     Gf.Matrix4d(1), Gf.Matrix4d().SetScale(Gf.Vec3d(1.2, 1, 0.9)).SetTranslateOnly(
         Gf.Vec3d(0.2, 0.1, -0.3))),
]


def _op_stage(path, name, add, a, b):
    """One volume under a pivot (translate, the op, inverse translate), the op animated."""
    path = pathlib.Path(path)
    shutil.copy(CLOUD, path.parent / "cloud.vdb")
    st = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(st, "Y")
    v = UsdVol.Volume.Define(st, "/World/cloud")
    x = UsdGeom.Xformable(v)
    pivot = x.AddTranslateOp(opSuffix="pivot")
    pivot.Set(Gf.Vec3d(0.1, 0.5, -0.2))
    op = add(x)
    x.AddTranslateOp(opSuffix="pivot", isInverseOp=True)
    op.Set(a, 1)
    op.Set(b, 2)
    f = UsdVol.OpenVDBAsset.Define(st, "/World/cloud/density")
    f.GetFilePathAttr().Set(Sdf.AssetPath("./cloud.vdb"))
    f.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", f.GetPath())
    sun = UsdLux.DistantLight.Define(st, "/World/sun")
    sun.CreateAngleAttr(0.0)  # a point sun (extents: test_lights_usd.py)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-70, 20, 0))
    st.Save()
    return st


@pytest.mark.parametrize("name,add,a,b", OPS, ids=[o[0] for o in OPS])
def test_every_xform_op_interpolates_at_subframes_as_usd_core_does(cli, tmp_path, name, add, a,
                                                                   b):
    st = _op_stage(tmp_path / "shot.usda", name, add, a, b)
    text = (tmp_path / "shot.usda").read_text()
    assert "timeSamples" in text
    for t in (1.05, 1.25, 1.5):
        _, js, _ = cli("query", tmp_path / "shot.usda", "--frame", t, "--at", "0.2,0.9,0.1",
                       "--json")
        _, want, _ = cli("query", CLOUD, f"--xform={_xform(st, '/World/cloud', t)}",
                         f"--light-dir={_sun(st, '/World/sun', t)}", "--at", "0.2,0.9,0.1",
                         "--json")
        got, exp = json.loads(js), json.loads(want)
        # Doubles compose to the same matrix within an ulp or so (the README of test_usd.py).
        # A quatf op is slerped by usd-core in f32, by umbra in f64 (docs/usd.md): measured
        # over 20 subframes, tau 3.4e-6 and length 1.8e-6 apart (relative), the worst at 1.05.
        tol = 5e-6 if name == "orient" else 1e-9
        assert got["tau"] == pytest.approx(exp["tau"], rel=tol, abs=1e-12), (name, t)
        assert got["length"] == pytest.approx(exp["length"], rel=tol), (name, t)


def test_usda_usdc_and_usdz_give_the_same_bytes(cli, tmp_path):
    """The same stage (time-sampled asset, animated ops, turning sun) as text, crate and
    package: byte-identical maps at a subframe and at a sample (the header records the input's
    name, `a/shot.usd?`, the only bytes that differ: the extension)."""
    (tmp_path / "a").mkdir()
    _issue_stage(tmp_path / "a" / "shot.usda")
    st = Usd.Stage.Open(str(tmp_path / "a" / "shot.usda"))
    st.Export(str(tmp_path / "a" / "shot.usdc"))
    pkg = tmp_path / "a" / "shot.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(tmp_path / "a" / "shot.usdc")),
                                         str(pkg))
    for t in (1.5, 2):
        maps = []
        for src in (tmp_path / "a" / "shot.usda", tmp_path / "a" / "shot.usdc", pkg):
            out = tmp_path / f"{src.suffix[1:]}.exr"
            cli("bake", src, "--frame", t, "--light", "sun", "-o", out, *COMMON)
            b = out.read_bytes()
            name = str(src).encode()
            assert b.count(name) == 1
            maps.append(b.replace(name, name[:-1] + b"_"))
        assert maps[0] == maps[1] == maps[2], t


def test_layer_offsets_and_scales_on_references_and_sublayers(cli, tmp_path):
    """A referenced cache layer, retimed by `(offset = 10; scale = 2)`, and a sublayer with an
    offset: umbra's time for each sample is USD's."""
    shutil.copy(CLOUD, tmp_path / "cloud.0001.vdb")
    shutil.copy(CLOUD, tmp_path / "cloud.0002.vdb")
    fx = Usd.Stage.CreateNew(str(tmp_path / "fx.usda"))
    v = UsdVol.Volume.Define(fx, "/cloud")
    fx.SetDefaultPrim(v.GetPrim())
    r = UsdGeom.Xformable(v).AddRotateZOp()
    r.Set(0.0, 1)
    r.Set(40.0, 2)
    a = UsdVol.OpenVDBAsset.Define(fx, "/cloud/density")
    for f in (1, 2):
        a.GetFilePathAttr().Set(Sdf.AssetPath(f"./cloud.{f:04d}.vdb"), f)
    a.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", a.GetPath())
    fx.Save()
    lights = Usd.Stage.CreateNew(str(tmp_path / "lights.usda"))
    sun = UsdLux.DistantLight.Define(lights, "/World/sun")
    sun.CreateAngleAttr(0.0)  # a point sun (extents: test_lights_usd.py)
    so = UsdGeom.Xformable(sun).AddRotateXOp()
    so.Set(-90.0, 1)
    so.Set(-30.0, 2)
    lights.Save()
    st = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    UsdGeom.SetStageUpAxis(st, "Y")
    st.GetRootLayer().subLayerPaths.append("./lights.usda")
    st.GetRootLayer().subLayerOffsets[0] = Sdf.LayerOffset(offset=4)
    prim = st.DefinePrim("/World/cloud")
    prim.GetReferences().AddReference("./fx.usda", Sdf.LayerOffset(offset=10, scale=2))
    st.Save()
    st = Usd.Stage.Open(str(tmp_path / "shot.usda"))
    # Stage time 12 is the cache's frame 1, 14 its frame 2; the sun's frame 1 is at stage 5.
    for t in (5.5, 12, 12.5, 13, 14):
        cli("bake", tmp_path / "shot.usda", "--frame", t, "--light", "sun",
            "-o", tmp_path / "u.exr", *COMMON)
        _explicit(cli, st, t, tmp_path / "v.exr")
        _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")


def _clip_stage(tmp_path, *, manifest=True):
    """A cache written as one clip layer per frame (usd-core's ClipsAPI), each holding the
    density asset and a turning xform, stitched onto /World/cloud over stage frames 1-3."""
    clips = tmp_path / "clips"
    clips.mkdir(exist_ok=True)
    for f in (1, 2, 3):
        shutil.copy(CLOUD, clips / f"cloud.{f:04d}.vdb")
        c = Usd.Stage.CreateNew(str(clips / f"clip.{f}.usda"))
        v = UsdVol.Volume.Define(c, "/cloud")
        UsdGeom.Xformable(v).AddRotateYOp().Set(20.0 * f, f)
        a = UsdVol.OpenVDBAsset.Define(c, "/cloud/density")
        a.GetFilePathAttr().Set(Sdf.AssetPath(f"./cloud.{f:04d}.vdb"), f)
        a.GetFieldNameAttr().Set("density")
        v.CreateFieldRelationship("density", a.GetPath())
        c.Save()
    st = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    UsdGeom.SetStageUpAxis(st, "Y")
    st.SetStartTimeCode(1)
    st.SetEndTimeCode(3)
    root = st.DefinePrim("/World/cloud", "Volume")
    # The prim's structure in the shot (the clip layers hold only values).
    a = UsdVol.OpenVDBAsset.Define(st, "/World/cloud/density")
    a.GetFieldNameAttr().Set("density")
    UsdVol.Volume(root).CreateFieldRelationship("density", a.GetPath())
    UsdGeom.Xformable(root).AddRotateYOp()
    clipsapi = Usd.ClipsAPI(root)
    clipsapi.SetClipAssetPaths([Sdf.AssetPath(f"./clips/clip.{f}.usda") for f in (1, 2, 3)])
    clipsapi.SetClipPrimPath("/cloud")
    clipsapi.SetClipActive([(1, 0), (2, 1), (3, 2)])
    clipsapi.SetClipTimes([(1, 1), (2, 2), (3, 3)])
    if manifest:
        clipsapi.GenerateClipManifest().Export(str(tmp_path / "manifest.usda"))
        clipsapi.SetClipManifestAssetPath(Sdf.AssetPath("./manifest.usda"))
    sun = UsdLux.DistantLight.Define(st, "/World/sun")
    sun.CreateAngleAttr(0.0)  # a point sun (extents: test_lights_usd.py)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-70, 20, 0))
    st.Save()
    return Usd.Stage.Open(str(tmp_path / "shot.usda"))


@pytest.mark.parametrize("manifest", [True, False], ids=["manifest", "no-manifest"])
def test_value_clips_frame_by_frame_equal_the_explicit_bake(cli, tmp_path, manifest):
    st = _clip_stage(tmp_path, manifest=manifest)
    for t in (1, 1.5, 2, 3):
        fp = st.GetPrimAtPath("/World/cloud/density").GetAttribute("filePath").Get(t)
        assert fp is not None and fp.resolvedPath, (t, fp)
        cli("bake", tmp_path / "shot.usda", "--frame", t, "--light", "sun",
            "-o", tmp_path / "u.exr", *COMMON)
        _explicit(cli, st, t, tmp_path / "v.exr")
        _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")


def test_bad_clip_sets_get_one_clear_error(cli, tmp_path):
    def case(name):
        d = tmp_path / name
        d.mkdir()
        return d, _clip_stage(d)

    def refused(d, frame, *words):
        out = d / "x.exr"
        e = _err(cli, "bake", d / "shot.usda", "--frame", frame, "--light", "sun", "-o", out,
                 "--res", "16")
        assert all(w in e for w in words), (words, e)
        assert not out.exists()

    # A clip layer that is missing: the clip, as authored and resolved.
    d, _ = case("layer")
    (d / "clips" / "clip.2.usda").unlink()
    refused(d, 2, "clip.2.usda", "shot.usda", "/World/cloud", "does not exist")
    # A clip's asset that is missing: the asset, anchored to its clip layer.
    d, _ = case("asset")
    (d / "clips" / "cloud.0003.vdb").unlink()
    refused(d, 3, str(d / "clips" / "cloud.0003.vdb"), "/World/cloud/density")
    # Clip times or active clips out of order.
    d, st = case("times")
    Usd.ClipsAPI(st.GetPrimAtPath("/World/cloud")).SetClipTimes([(2, 2), (1, 1), (3, 3)])
    st.Save()
    refused(d, 2, "clipTimes", "/World/cloud", "out of order")
    d, st = case("active")
    Usd.ClipsAPI(st.GetPrimAtPath("/World/cloud")).SetClipActive([(1, 0), (3, 2), (2, 1)])
    st.Save()
    refused(d, 2, "clipActive", "/World/cloud", "out of order")


def test_visibility_is_usds_at_the_time(cli, tmp_path):
    """Which volumes a frame traces is usd-core's ComputeVisibility at that time: animated
    visibility is read at the time; an invisible opinion on a prim that is not Imageable (an
    untyped prim) hides nothing."""
    shutil.copy(CLOUD, tmp_path / "cloud.vdb")
    st = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    untyped = st.DefinePrim("/Group")
    untyped.CreateAttribute("visibility", Sdf.ValueTypeNames.Token).Set("invisible")
    for path in ("/Group/steady", "/World/blinks", "/World/hidden/cloud"):
        v = UsdVol.Volume.Define(st, path)
        a = UsdVol.OpenVDBAsset.Define(st, path + "/density")
        a.GetFilePathAttr().Set(Sdf.AssetPath("./cloud.vdb"))
        v.CreateFieldRelationship("density", a.GetPath())
    vis = UsdGeom.Imageable(st.GetPrimAtPath("/World/blinks")).CreateVisibilityAttr()
    vis.Set("inherited", 1)
    vis.Set("invisible", 2)
    UsdGeom.Imageable(UsdGeom.Xform.Define(st, "/World/hidden")).CreateVisibilityAttr().Set(
        "invisible")
    UsdLux.DistantLight.Define(st, "/World/sun").CreateAngleAttr(0.0)  # a point sun
    st.Save()
    for t in (1, 1.5, 2):
        want = [p for p in ("/Group/steady", "/World/blinks", "/World/hidden/cloud")
                if UsdGeom.Imageable(st.GetPrimAtPath(p)).ComputeVisibility(t) != "invisible"]
        _, js, _ = cli("info", tmp_path / "shot.usda", "--frame", t, "--json")
        got = [v["prim"] for v in json.loads(js)["volumes"]]
        assert got == want, (t, got, want)
