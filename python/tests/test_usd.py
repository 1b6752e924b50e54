"""USD shots in: stages written by Pixar's usd-core (`pxr`), read by umbra's own reader, held
to what usd-core says the stage means (XformCache matrices, light frames, resolved asset
paths, the up axis): a USD bake equals the `.vdb` bake with that --xform / --light-dir /
--light-pos / --up, pixel for pixel."""

import json
import math
import pathlib
import shutil
import zipfile

import numpy as np
import OpenEXR
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core (pip install usd-core) writes the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdUtils, UsdVol  # noqa: E402

from conftest import DATA  # noqa: E402

CLOUD = DATA / "cloud.vdb"


def _stage(path, *, frames=(1, 2), animated_file=True, up="Z", lights=True):
    """A small shot: /World (moved) / cloud (Volume, animated translate, rotate, scale), its
    density an OpenVDBAsset per frame; a sun (DistantLight, rotated) and a lamp (SphereLight)
    far off; copies of the sample cloud beside the stage."""
    path = pathlib.Path(path)
    for f in frames:
        shutil.copy(CLOUD, path.parent / f"cloud.{f:04d}.vdb")
    st = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(st, up)
    st.SetStartTimeCode(frames[0])
    st.SetEndTimeCode(frames[-1])
    w = UsdGeom.Xform.Define(st, "/World")
    w.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    w.AddRotateYOp().Set(25.0)
    w.AddScaleOp().Set(Gf.Vec3f(1.2, 1.2, 1.2))
    v = UsdVol.Volume.Define(st, "/World/cloud")
    x = UsdGeom.Xformable(v)
    t = x.AddTranslateOp()
    r = x.AddRotateXYZOp()
    s = x.AddScaleOp()
    for i, f in enumerate(frames):
        t.Set(Gf.Vec3d(0.5 * i, 0.25 * i, 0), f)
        r.Set(Gf.Vec3f(10 + 5 * i, 20, 30 - 7 * i), f)
        s.Set(Gf.Vec3f(1, 1.5 + 0.25 * i, 1), f)
    a = UsdVol.OpenVDBAsset.Define(st, "/World/cloud/density")
    if animated_file:
        for f in frames:
            a.GetFilePathAttr().Set(Sdf.AssetPath(f"./cloud.{f:04d}.vdb"), f)
    else:
        a.GetFilePathAttr().Set(Sdf.AssetPath(f"./cloud.{frames[0]:04d}.vdb"))
    a.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", a.GetPath())
    if lights:
        UsdGeom.Xform.Define(st, "/Lights").AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
        sun = UsdLux.DistantLight.Define(st, "/Lights/sun")
        # Point lights (angle 0, treatAsPoint): these tests compare stage answers with
        # --light-dir / --light-pos ones; lights with extent: test_lights_usd.py.
        sun.CreateAngleAttr(0.0)
        so = UsdGeom.Xformable(sun).AddRotateXYZOp()
        for i, f in enumerate(frames):
            so.Set(Gf.Vec3f(-60 + 10 * i, 10, 0), f)
        lamp = UsdLux.SphereLight.Define(st, "/Lights/lamp")
        lamp.CreateTreatAsPointAttr(True)
        UsdGeom.Xformable(lamp).AddTranslateOp().Set(Gf.Vec3d(2, 40, -3))
    st.Save()
    return st


def _xform(st, prim, t):
    """umbra's --xform (column vectors, row-major) from usd-core's local-to-world (rows)."""
    m = UsdGeom.XformCache(t).GetLocalToWorldTransform(st.GetPrimAtPath(prim))
    return ",".join(repr(m[c][r]) for r in range(4) for c in range(4))


def _sun(st, prim, t):
    m = UsdGeom.XformCache(t).GetLocalToWorldTransform(st.GetPrimAtPath(prim))
    d = m.TransformDir(Gf.Vec3d(0, 0, -1)).GetNormalized()
    return ",".join(repr(c) for c in d)


def _origin(st, prim, t):
    m = UsdGeom.XformCache(t).GetLocalToWorldTransform(st.GetPrimAtPath(prim))
    return ",".join(repr(c) for c in m.ExtractTranslation())


def _up(st):
    return "0,0,1" if UsdGeom.GetStageUpAxis(st) == "Z" else "0,1,0"


def _pixels(path):
    with OpenEXR.File(str(path)) as f:
        part = f.parts[0]
        return {k: np.array(c.pixels) for k, c in part.channels.items()}


def _same_pixels(a, b):
    pa, pb = _pixels(a), _pixels(b)
    assert pa.keys() == pb.keys()
    for k in pa:
        assert pa[k].shape == pb[k].shape, k
        assert np.array_equal(pa[k], pb[k]), (k, float(np.abs(pa[k] - pb[k]).max()))


def test_a_usd_bake_is_the_vdb_bake_usd_core_describes(cli, tmp_path):
    st = _stage(tmp_path / "shot.usdc")
    stage = tmp_path / "shot.usdc"
    for t in (1, 1.5, 2):
        fp = st.GetPrimAtPath("/World/cloud/density").GetAttribute("filePath").Get(t)
        vdb = fp.resolvedPath
        assert vdb.endswith("cloud.0001.vdb" if t < 2 else "cloud.0002.vdb")
        common = ["--res", "96", "--quiet", "--force"]
        # The sun: ortho map; up from the stage's upAxis.
        cli("bake", stage, "--frame", t, "--light", "sun", "-o", tmp_path / "u.exr", *common)
        cli("bake", vdb, f"--xform={_xform(st, '/World/cloud', t)}",
            f"--light-dir={_sun(st, '/Lights/sun', t)}", f"--up={_up(st)}",
            "-o", tmp_path / "v.exr", *common)
        _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")
        # The lamp: a perspective map from its world origin.
        cli("bake", stage, "--frame", t, "--light", "/Lights/lamp", "-o", tmp_path / "u.exr",
            *common)
        cli("bake", vdb, f"--xform={_xform(st, '/World/cloud', t)}",
            f"--light-pos={_origin(st, '/Lights/lamp', t)}", f"--up={_up(st)}",
            "-o", tmp_path / "v.exr", *common)
        _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")


def _light_meta(b):
    """A transmittance volume's bytes split around its light metadata string (a 4-byte length,
    then `directional [x, y, z]` or `point [x, y, z]`), and the light's numbers."""
    i = max(b.find(b"directional ["), b.find(b"point ["))
    j = b.index(b"]", i) + 1
    nums = [float(x) for x in b[b.index(b"[", i) + 1:j - 1].split(b",")]
    return b[:i - 4], nums, b[j:]


def test_a_transmittance_volume_from_a_stage_is_the_vdb_one(cli, tmp_path):
    """-o X.vdb from a stage: its one volume's grid, placed and lit as usd-core says, equals the
    transmittance volume of the .vdb with that --xform and --light-dir / --light-pos."""
    st = _stage(tmp_path / "shot.usdc")
    stage = tmp_path / "shot.usdc"
    vdb = tmp_path / "cloud.0002.vdb"
    for light, flag in (("sun", f"--light-dir={_sun(st, '/Lights/sun', 2)}"),
                        ("lamp", f"--light-pos={_origin(st, '/Lights/lamp', 2)}")):
        cli("bake", stage, "--frame", 2, "--light", light, "-o", tmp_path / "u.vdb", "--force")
        cli("bake", vdb, f"--xform={_xform(st, '/World/cloud', 2)}", flag,
            "-o", tmp_path / "v.vdb", "--force")
        u, v = (tmp_path / "u.vdb").read_bytes(), (tmp_path / "v.vdb").read_bytes()
        # Every voxel (all that follows the light's metadata and the grid's transform) byte for
        # byte. usd-core and openusd compose the rotations to within an ulp, so the light's
        # metadata string may differ in its last digit and the transform's doubles in their
        # last bits; the file's UUID and the grid's offsets differ too.
        (u0, lu, u1), (v0, lv, v1) = _light_meta(u), _light_meta(v)
        assert len(u1) == len(v1) > 600_000 and len(u0) == len(v0), light
        at = u1.index(b"AffineMap") + 9 + 4 * 8 * 4
        assert u1[at:] == v1[at:], light
        ma = np.frombuffer(u1[at - 128:at], dtype="<f8")
        mb = np.frombuffer(v1[at - 128:at], dtype="<f8")
        assert np.allclose(ma, mb, rtol=1e-14, atol=1e-15), (ma, mb)
        assert np.allclose(lu, lv, rtol=1e-15, atol=1e-15), (lu, lv)
    # The stage places the volume: --xform is refused; a map option too.
    e = _err(cli, "bake", stage, "--light", "sun", "-o", tmp_path / "w.vdb",
             f"--xform={_xform(st, '/World/cloud', 2)}")
    assert "'--xform'" in e and "stage places" in e, e
    assert not (tmp_path / "w.vdb").exists()


def test_compare_on_a_stage_traces_its_volume(cli, tmp_path):
    """compare on a stage: the one volume, placed as usd-core places it, gives the report of
    the .vdb with that --xform (same rays, same exact answers)."""
    st = _stage(tmp_path / "shot.usdc")
    args = ["--estimators", "regular", "--rays", "24", "--repeats", "1", "--quiet"]
    cli("compare", tmp_path / "shot.usdc", "--frame", 2, "-o", tmp_path / "u", *args)
    cli("compare", tmp_path / "cloud.0002.vdb", f"--xform={_xform(st, '/World/cloud', 2)}",
        "-o", tmp_path / "v", *args)
    u = json.loads((tmp_path / "u" / "report.json").read_text())
    v = json.loads((tmp_path / "v" / "report.json").read_text())
    assert u["meta"]["reference"] == v["meta"]["reference"]
    # The two USD implementations place the volume to within an ulp: a ray that grazes a
    # voxel face may take one lookup more or less.
    assert abs(u["rows"][0]["lookups"] - v["rows"][0]["lookups"]) <= 0.01 * v["rows"][0]["lookups"]
    assert "/World/cloud" in u["meta"]["source"]
    e = _err(cli, "compare", tmp_path / "shot.usdc", "--light", "sun", "-o", tmp_path / "w")
    assert "'--light'" in e, e


def test_info_on_a_stage_says_what_umbra_reads(cli, tmp_path):
    """info on a stage: each volume's asset, grid, placement (usd-core's) and the grid's own
    report; each light and how umbra traces it (usd-core's frames)."""
    st = _stage(tmp_path / "shot.usdc")
    _, out, _ = cli("info", tmp_path / "shot.usdc", "--frame", 2, "--json")
    r = json.loads(out)
    assert r["time"] == 2 and r["up"] == [0, 0, 1]
    [v] = r["volumes"]
    assert v["prim"] == "/World/cloud" and v["asset"] == str(tmp_path / "cloud.0002.vdb")
    want = [float(x) for x in _xform(st, "/World/cloud", 2).split(",")]
    assert np.allclose(v["xform"], want, rtol=1e-12, atol=1e-12)
    _, grid, _ = cli("info", tmp_path / "cloud.0002.vdb", "--grid", "density", "--json")
    assert v["info"]["active_voxels"] == json.loads(grid)["grids"][0]["active_voxels"]
    lights = {l["prim"]: l for l in r["lights"]}
    sun = [float(x) for x in _sun(st, "/Lights/sun", 2).split(",")]
    assert np.allclose(lights["/Lights/sun"]["traced"]["dir"], sun, atol=1e-12)
    lamp = [float(x) for x in _origin(st, "/Lights/lamp", 2).split(",")]
    assert np.allclose(lights["/Lights/lamp"]["traced"]["pos"], lamp, atol=1e-12)
    _, text, _ = cli("info", tmp_path / "shot.usdc", "--frame", 2)
    assert "/World/cloud" in text and "DistantLight" in text and "up +Z" in text, text
    e = _err(cli, "info", tmp_path / "shot.usdc", "--light", "sun")
    assert "'--light'" in e, e


def test_usda_usdc_and_usdz_give_the_same_map(cli, tmp_path):
    # A static asset path here; time-sampled ones, subframes and byte-identical maps:
    # test_usd_time.py.
    (tmp_path / "a").mkdir()
    _stage(tmp_path / "a" / "shot.usda", animated_file=False)
    st = Usd.Stage.Open(str(tmp_path / "a" / "shot.usda"))
    st.Export(str(tmp_path / "a" / "shot.usdc"))
    pkg = tmp_path / "shot.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(tmp_path / "a" / "shot.usdc")), str(pkg))
    with zipfile.ZipFile(pkg) as z:
        assert any(n.endswith("cloud.0001.vdb") for n in z.namelist()), z.namelist()
    outs = []
    for src in (tmp_path / "a" / "shot.usda", tmp_path / "a" / "shot.usdc", pkg):
        out = tmp_path / f"{src.suffix[1:]}.exr"
        _, js, _ = cli("bake", src, "--frame", 2, "--light", "sun", "--res", "80", "-o", out,
                       "--quiet", "--json")
        outs.append((out, json.loads(js)))
    for out, js in outs[1:]:
        _same_pixels(outs[0][0], out)
        assert js["camera"] == outs[0][1]["camera"]


def test_a_two_volume_stage_is_the_same_scene_file(cli, tmp_path):
    """One volume defined in the stage, one brought in by a reference to a layer in another
    directory whose asset path is relative to that layer."""
    (tmp_path / "fx").mkdir()
    shutil.copy(CLOUD, tmp_path / "fx" / "puff.vdb")
    shutil.copy(CLOUD, tmp_path / "main.vdb")
    fx = Usd.Stage.CreateNew(str(tmp_path / "fx" / "puff.usda"))
    v = UsdVol.Volume.Define(fx, "/Puff")
    UsdGeom.Xformable(v).AddTranslateOp().Set(Gf.Vec3d(3, 0, 0))
    a = UsdVol.OpenVDBAsset.Define(fx, "/Puff/density")
    a.GetFilePathAttr().Set(Sdf.AssetPath("./puff.vdb"))
    a.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", a.GetPath())
    fx.SetDefaultPrim(v.GetPrim())
    fx.Save()
    st = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    m = UsdVol.Volume.Define(st, "/World/main")
    UsdGeom.Xformable(m).AddScaleOp().Set(Gf.Vec3f(1, 2, 1))
    a = UsdVol.OpenVDBAsset.Define(st, "/World/main/density")
    a.GetFilePathAttr().Set(Sdf.AssetPath("main.vdb"))
    a.GetFieldNameAttr().Set("density")
    m.CreateFieldRelationship("density", a.GetPath())
    m.GetPrim().CreateAttribute("umbra:densityScale", Sdf.ValueTypeNames.Float).Set(2.0)
    p = st.DefinePrim("/World/puff")
    p.GetReferences().AddReference("./fx/puff.usda")
    UsdGeom.Xformable(p).AddTranslateOp(opSuffix="shot").Set(Gf.Vec3d(0, 0, 1))
    st.Save()
    scene = tmp_path / "scene.toml"
    lines = []
    for prim, vdb, scale in (("/World/main", "main.vdb", 2.0), ("/World/puff", "fx/puff.vdb", 1.0)):
        x = _xform(st, prim, Usd.TimeCode.Default())
        lines += ["[[volume]]", f'file = "{vdb}"', f"density_scale = {scale}",
                  f"xform = [{x}]", ""]
    scene.write_text("\n".join(lines))
    flags = ["--light-dir=0.3,-1,0.2", "--res", "72", "--quiet"]
    cli("bake", tmp_path / "shot.usda", "-o", tmp_path / "u.exr", *flags)
    cli("bake", scene, "-o", tmp_path / "s.exr", *flags)
    _same_pixels(tmp_path / "u.exr", tmp_path / "s.exr")
    # Only one of them, by prim path.
    cli("bake", tmp_path / "shot.usda", "--volume", "/World/puff", "-o", tmp_path / "one.exr",
        *flags)
    assert not np.array_equal(_pixels(tmp_path / "one.exr")["T"], _pixels(tmp_path / "u.exr")["T"])


def test_a_query_toward_a_sphere_light_is_the_explicit_query(cli, tmp_path):
    # The lamp's inputs:radius is unauthored: without treatAsPoint its schema fallback, 0.5,
    # applies (a sphere light, as renderers draw it); treatAsPoint makes it the point light.
    st = _stage(tmp_path / "shot.usdc")
    UsdLux.SphereLight(st.GetPrimAtPath("/Lights/lamp")).GetTreatAsPointAttr().Set(False)
    st.Save()
    at = "1.4,2.6,3.2"
    for t in (1, 2):
        vdb = st.GetPrimAtPath("/World/cloud/density").GetAttribute("filePath").Get(t).resolvedPath
        _, a, _ = cli("query", tmp_path / "shot.usdc", "--frame", t, "--light", "lamp",
                      "--at", at, "--json")
        flags = (vdb, f"--xform={_xform(st, '/World/cloud', t)}",
                 f"--light-pos={_origin(st, '/Lights/lamp', t)}", "--at", at, "--json")
        _, b, _ = cli("query", *flags, "--light-radius", "0.5")
        ja, jb = json.loads(a), json.loads(b)
        # usd-core and umbra's reader compose the same xformOps to within an ulp or two (the
        # rotation's float angles are widened in a different order), so f64 answers agree to
        # round-off, not bit for bit; the float maps above are bit for bit.
        assert ja["tau"] is None and jb["tau"] is None
        assert ja["T"] == pytest.approx(jb["T"], rel=1e-9, abs=0), (ja, jb)
        assert ja["std_err"] == pytest.approx(jb["std_err"], rel=1e-6), (ja, jb)
        assert ja["length"] == pytest.approx(jb["length"], rel=1e-12), (ja, jb)
        assert 0.0 < ja["T"] < 1.0
    UsdLux.SphereLight(st.GetPrimAtPath("/Lights/lamp")).CreateTreatAsPointAttr(True)
    st.Save()
    for t in (1, 2):
        vdb = st.GetPrimAtPath("/World/cloud/density").GetAttribute("filePath").Get(t).resolvedPath
        _, a, _ = cli("query", tmp_path / "shot.usdc", "--frame", t, "--light", "lamp",
                      "--at", at, "--json")
        _, b, _ = cli("query", vdb, f"--xform={_xform(st, '/World/cloud', t)}",
                      f"--light-pos={_origin(st, '/Lights/lamp', t)}", "--at", at, "--json")
        ja, jb = json.loads(a), json.loads(b)
        assert ja["tau"] == pytest.approx(jb["tau"], rel=1e-12, abs=0), (ja, jb)


def _err(cli, *args):
    code, _, err = cli(*args, check=False)
    assert code == 1, (code, err)
    lines = [l for l in err.splitlines() if l.startswith("umbra: error: ")]
    assert len(lines) == 1, err
    return lines[0]


def test_bad_stages_get_one_clear_error(cli, tmp_path):
    st = _stage(tmp_path / "shot.usdc")
    out = ["-o", tmp_path / "x.exr", "--res", "32", "--light", "sun", "--force"]
    # A missing asset at one frame: the prim, the time, the file.
    (tmp_path / "cloud.0002.vdb").unlink()
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--frame", 2, *out)
    assert "at time 2" in e and "/World/cloud/density" in e and "cloud.0002.vdb" in e, e
    cli("bake", tmp_path / "shot.usdc", "--frame", 1, *out, "--quiet")
    assert (tmp_path / "x.exr").exists()
    # Several lights and none named.
    e = _err(cli, "bake", tmp_path / "shot.usdc", "-o", tmp_path / "y.exr")
    assert "--light" in e and "/Lights/sun (DistantLight)" in e and "/Lights/lamp" in e, e
    # A light type umbra does not trace, by name.
    UsdLux.DomeLight.Define(st, "/World/dome")
    st.Save()
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--frame", 1, "--light", "dome",
             "-o", tmp_path / "y.exr")
    assert "DomeLight" in e and "/World/dome" in e, e
    # No such light.
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--frame", 1, "--light", "moon",
             "-o", tmp_path / "y.exr")
    assert "'--light'" in e and "moon" in e, e
    # A Field3DAsset, and a volume without a density field.
    f3d = UsdVol.Field3DAsset.Define(st, "/World/cloud/f3d")
    f3d.GetFilePathAttr().Set(Sdf.AssetPath("./cloud.0001.vdb"))
    UsdVol.Volume(st.GetPrimAtPath("/World/cloud")).CreateFieldRelationship("heat", f3d.GetPath())
    st.Save()
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--frame", 1, "--field", "heat", *out)
    assert "Field3DAsset" in e and "/World/cloud/f3d" in e, e
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--frame", 1, "--field", "flame", *out)
    assert "no field 'flame'" in e and "density" in e and "heat" in e, e
    # No volume by that name.
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--frame", 1, "--volume", "/World/nope", *out)
    assert "/World/nope" in e and "/World/cloud" in e, e
    # Stage options on a .vdb input.
    e = _err(cli, "bake", CLOUD, "--frame", 1, "--light-dir=0,-1,0", "-o", tmp_path / "z.exr")
    assert "'--frame'" in e and "USD" in e, e
    assert not (tmp_path / "y.exr").exists() and not (tmp_path / "z.exr").exists()


def test_broken_stage_files_are_errors_not_crashes(cli, umbra_bin, tmp_path):
    _stage(tmp_path / "shot.usdc")
    data = (tmp_path / "shot.usdc").read_bytes()
    flags = ["--light-dir=0,-1,0", "--res", "16", "-o", tmp_path / "x.exr"]
    for n in (0, 8, 64, len(data) // 2, len(data) - 1):
        (tmp_path / "cut.usdc").write_bytes(data[:n])
        e = _err(cli, "bake", tmp_path / "cut.usdc", *flags)
        assert "cut.usdc" in e, e
    # A size field inside a compressed section that asks for terabytes (openusd 0.6 would
    # allocate it and abort; 0.8 refuses it): the error names the file. Every value type,
    # every byte: tests/library/usd_corrupt.rs.
    toc = int.from_bytes(data[16:24], "little")
    sections = {data[toc + 8 + 32 * i: toc + 24 + 32 * i].rstrip(b"\0").decode():
                int.from_bytes(data[toc + 24 + 32 * i: toc + 32 + 32 * i], "little")
                for i in range(int.from_bytes(data[toc:toc + 8], "little"))}
    lying = bytearray(data)
    lying[sections["TOKENS"] + 8: sections["TOKENS"] + 16] = (1 << 42).to_bytes(8, "little")
    (tmp_path / "lying.usdc").write_bytes(bytes(lying))
    e = _err(cli, "bake", tmp_path / "lying.usdc", *flags)
    assert "lying.usdc" in e and "TOKENS" in e, e
    (tmp_path / "bad.usdz").write_bytes(b"PK\x03\x04" + b"\x00" * 40)
    e = _err(cli, "bake", tmp_path / "bad.usdz", *flags)
    assert "bad.usdz" in e, e
    # A cycle of references ends with an error or a stage, never a hang (pytest's run has no
    # timeout, so a hang would stall the suite: the subprocess gets one).
    (tmp_path / "a.usda").write_text('#usda 1.0\n(defaultPrim = "A")\n'
                                     'def Volume "A" (references = @./b.usda@) {}\n')
    (tmp_path / "b.usda").write_text('#usda 1.0\n(defaultPrim = "B")\n'
                                     'def Volume "B" (references = @./a.usda@) {}\n')
    import subprocess
    p = subprocess.run([str(umbra_bin), "bake", str(tmp_path / "a.usda"), *map(str, flags)],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and "panicked" not in p.stderr, p.stderr
    assert not (tmp_path / "x.exr").exists()


def test_a_stage_with_every_value_type_reads(cli, tmp_path):
    """The .usdc reader refuses nothing usd-core writes: a layer with a
    value of every crate type, in every encoding (tests/usd/make_every_value.py), written by
    the usd-core installed today, reads and traces."""
    import importlib.util
    src = pathlib.Path(__file__).resolve().parents[2] / "tests" / "usd" / "make_every_value.py"
    spec = importlib.util.spec_from_file_location("make_every_value", src)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.main(str(tmp_path / "every.usdc"))
    shutil.copy(CLOUD, tmp_path / "cloud.vdb")
    _, out, _ = cli("query", tmp_path / "every.usdc", "--frame", 2, "--light", "sun",
                    "--at", "0,0,0", "--json")
    assert 0.0 < json.loads(out)["T"] <= 1.0


def test_python_reads_the_stage_as_the_cli_does(cli, tmp_path):
    import umbra

    st = _stage(tmp_path / "shot.usdc")
    got = umbra.usd_lights(tmp_path / "shot.usdc", time=2)
    assert got["time"] == 2 and got["up"] == [0, 0, 1]
    by = {l["name"]: l for l in got["lights"]}
    # The shot's lights are points (angle 0, treatAsPoint); the fallbacks: test_lights_usd.py.
    assert by["sun"]["kind"] == "directional" and by["lamp"]["kind"] == "point"
    assert by["sun"]["angle"] == 0
    want = [float(c) for c in _sun(st, "/Lights/sun", 2).split(",")]
    assert by["sun"]["dir"] == pytest.approx(want, abs=1e-12)
    assert by["lamp"]["pos"] == pytest.approx(
        [float(c) for c in _origin(st, "/Lights/lamp", 2).split(",")], abs=1e-12)
    # The same scene the CLI traces: a query through the loaded stage equals `umbra query`.
    v = umbra.Volume.from_usd(tmp_path / "shot.usdc", time=2)
    a, b = np.array([[1.4, 2.6, 3.2]]), np.array([[2.0, 41.0, -3.0]])
    t = v.transmittance(a, b)
    _, js, _ = cli("query", tmp_path / "shot.usdc", "--frame", 2, "--from", "1.4,2.6,3.2",
                   "--to", "2,41,-3", "--json")
    assert t[0] == json.loads(js)["T"]
    # Pickled as what it was loaded from.
    import pickle
    assert pickle.loads(pickle.dumps(v)).transmittance(a, b)[0] == t[0]
    # umbra.bake on a stage writes what `umbra bake` writes.
    umbra.bake(tmp_path / "shot.usdc", tmp_path / "p.exr", frame=2, light="sun", res=48,
               usd_out=tmp_path / "p.usda")
    cli("bake", tmp_path / "shot.usdc", "--frame", 2, "--light", "sun", "--res", 48,
        "-o", tmp_path / "c.exr", "--quiet", "--usd-out", tmp_path / "c.usda")
    assert (tmp_path / "p.exr").read_bytes() == (tmp_path / "c.exr").read_bytes()
    assert (tmp_path / "p.usda").read_text().replace("p.exr", "c.exr") == \
        (tmp_path / "c.usda").read_text()
    with pytest.raises(umbra.InvalidArgument, match="'light'.*moon"):
        umbra.bake(tmp_path / "shot.usdc", tmp_path / "q.exr", light="moon")
    with pytest.raises(umbra.InvalidArgument, match="'frame'.*USD"):
        umbra.bake(DATA / "cloud.vdb", tmp_path / "q.exr", frame=1, light_dir=(0, -1, 0))


def test_a_batch_job_reads_frames_and_lights_from_the_stage(cli, tmp_path):
    _stage(tmp_path / "shot.usdc")
    job = tmp_path / "job.toml"
    body = ('output = "out/{light}.{frame:04}.exr"\n'
            '[[inputs]]\nusd = "shot.usdc"\nframes = [1, 2]\n'
            '[bake]\nres = 40\n')
    # The sun turns between the frames: one shared camera cannot follow it.
    job.write_text(body + '[[lights]]\nusd = "/Lights/sun"\n')
    code, _, err = cli("batch", job, check=False)
    assert code == 1 and "moves" in err and "per-frame" in err, err
    assert not (tmp_path / "out").exists()
    job.write_text(body + 'framing = "per-frame"\n[[lights]]\nusd = "/Lights/sun"\n')
    cli("batch", job)
    for f in (1, 2):
        cli("bake", tmp_path / "shot.usdc", "--frame", f, "--light", "sun", "--res", 40,
            "-o", tmp_path / "want.exr", "--quiet", "--force")
        _same_pixels(tmp_path / "out" / f"sun.{f:04d}.exr", tmp_path / "want.exr")
    # No [[lights]]: every light of the stage; the lamp does not move, so it shares a camera.
    job.write_text(body.replace("out/", "all/") + 'framing = "per-frame"\n')
    cli("batch", job)
    names = sorted(p.name for p in (tmp_path / "all").glob("*.exr"))
    assert names == ["lamp.0001.exr", "lamp.0002.exr", "sun.0001.exr", "sun.0002.exr"], names
    # Resume: nothing changed, nothing baked; a cache only touched is no change (its content
    # hash is the key's); a re-simulated cache behind the unchanged stage makes its frame
    # stale (the stage's assets are the tasks' sources), and the log line says which file.
    _, out, _ = cli("batch", job)
    assert "0 baked, 4 skipped" in out, out
    import os, time
    later = time.time() + 5
    os.utime(tmp_path / "cloud.0002.vdb", (later, later))
    _, out, _ = cli("batch", job)
    assert "0 baked, 4 skipped" in out, out
    shutil.copy(DATA / "cloud_half.vdb", tmp_path / "cloud.0002.vdb")
    _, out, _ = cli("batch", job)
    assert "2 baked, 2 skipped" in out, out
    recs = [json.loads(l) for l in (tmp_path / "all" / "umbra_batch.jsonl").read_text()
            .splitlines()][-4:]
    why = sorted(r["reason"] for r in recs if r["status"] == "ok")
    assert why == ["input changed: cloud.0002.vdb"] * 2, recs
    # A frame whose asset is missing fails alone (exit 3); the other frame is baked.
    (tmp_path / "cloud.0002.vdb").unlink()
    job.write_text(body.replace("out/", "miss/") + 'framing = "per-frame"\n'
                   '[[lights]]\nusd = "/Lights/lamp"\n')
    code, _, err = cli("batch", job, check=False)
    assert code == 3, err
    assert (tmp_path / "miss" / "lamp.0001.exr").exists()
    assert not (tmp_path / "miss" / "lamp.0002.exr").exists()


def test_a_job_puts_every_map_on_its_light(cli, tmp_path):
    """bake.usd_out in a job: one layer with every stage light's maps, time-sampled by frame,
    built from the maps on disk, so shards run one after the other end with all of them."""
    _stage(tmp_path / "shot.usdc")
    job = tmp_path / "job.toml"
    job.write_text('output = "out/{light}.{frame:04}.exr"\n'
                   '[[inputs]]\nusd = "shot.usdc"\nframes = [1, 2]\n'
                   '[bake]\nres = 24\nframing = "per-frame"\nusd_out = "shadows.usda"\n')
    cli("batch", job, "--shard", "1/2", "--quiet")
    first = Sdf.Layer.OpenAsAnonymous(str(tmp_path / "shadows.usda"))
    held = lambda layer: sum(len(layer.ListTimeSamplesForPath(
        f"/Lights/{l}.umbra:shadowMap")) for l in ("sun", "lamp"))
    assert 0 < held(first) < 4
    # Without --quiet the run's summary says what the layer holds (--quiet prints nothing).
    _, out, _ = cli("batch", job, "--shard", "2/2")
    assert "4 maps on their stage lights" in out, out
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths = [str(tmp_path / "shadows.usda"), str(tmp_path / "shot.usdc")]
    st = Usd.Stage.Open(root)
    for light in ("sun", "lamp"):
        prim = st.GetPrimAtPath(f"/Lights/{light}")
        for f in (1, 2):
            m = prim.GetAttribute("umbra:shadowMap").Get(f)
            want = tmp_path / "out" / f"{light}.{f:04d}.exr"
            assert pathlib.Path(m.resolvedPath) == want, m
            w2s = np.array(prim.GetAttribute("umbra:worldToShadow").Get(f))
            with OpenEXR.File(str(want)) as x:
                header = np.array(x.header()["worldToNDC"], dtype=np.float64)
            assert np.allclose(w2s, header, rtol=1e-6, atol=1e-7), (light, f)
    # Refused when the job is read, before any work.
    for bad, word in (('usd_out = "s.usdc"', ".usda"),
                      ('usd_out = "s.usda"\n[[lights]]\nname = "top"\ndir = [0, -1, 0]', "none")):
        job.write_text('output = "bad/{light}.{frame:04}.exr"\n'
                       '[[inputs]]\nusd = "shot.usdc"\nframes = [1, 2]\n'
                       f'[bake]\nres = 24\nframing = "per-frame"\n{bad}\n')
        code, _, err = cli("batch", job, check=False)
        assert code == 1 and "bake.usd_out" in err and word in err, err
        assert not (tmp_path / "bad").exists()


def test_usd_out_puts_the_map_and_its_camera_on_the_light(cli, tmp_path):
    _stage(tmp_path / "shot.usdc")
    (tmp_path / "maps").mkdir()
    for light in ("sun", "lamp"):
        out = tmp_path / "maps" / f"{light}.0002.exr"
        layer = tmp_path / f"shadows_{light}.usda"
        cli("bake", tmp_path / "shot.usdc", "--frame", 2, "--light", light, "--res", 40,
            "-o", out, "--usd-out", layer, "--quiet", "--force")
        # usd-core reads the layer back, sublayered over the shot.
        root = Sdf.Layer.CreateAnonymous(".usda")
        root.subLayerPaths = [str(layer), str(tmp_path / "shot.usdc")]
        st = Usd.Stage.Open(root)
        prim = st.GetPrimAtPath(f"/Lights/{light}")
        assert prim.IsA(UsdLux.DistantLight if light == "sun" else UsdLux.SphereLight)
        m = prim.GetAttribute("umbra:shadowMap").Get(2)
        assert pathlib.Path(m.resolvedPath) == out, m
        w2s = np.array(prim.GetAttribute("umbra:worldToShadow").Get(2))
        with OpenEXR.File(str(out)) as f:
            header = np.array(f.header()["worldToNDC"], dtype=np.float64)
        # The EXR header keeps it as floats: the same matrix, rounded.
        assert np.allclose(w2s, header, rtol=1e-6, atol=1e-7), (w2s, header)
    # A reused camera (frame 2's sun map) for frame 1: the view is the camera's, the light
    # names the prim the layer puts the map on.
    cam = tmp_path / "maps" / "sun.0002.exr"
    out = tmp_path / "maps" / "sun.0001.exr"
    cli("bake", tmp_path / "shot.usdc", "--frame", 1, "--light", "sun", "--camera", cam,
        "-o", out, "--usd-out", tmp_path / "reused.usda", "--quiet")
    lay = Sdf.Layer.OpenAsAnonymous(str(tmp_path / "reused.usda"))
    w2s = np.array(lay.QueryTimeSample("/Lights/sun.umbra:worldToShadow", 1))
    with OpenEXR.File(str(out)) as f:
        header = np.array(f.header()["worldToNDC"], dtype=np.float64)
    assert np.allclose(w2s, header, rtol=1e-6, atol=1e-7)
    # The camera's view (x, y); its depth range follows the frame's volume.
    with OpenEXR.File(str(cam)) as f:
        reused = np.array(f.header()["worldToNDC"], dtype=np.float64)
    assert np.allclose(w2s[:, [0, 1, 3]], reused[:, [0, 1, 3]], rtol=1e-6, atol=1e-7)
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--light", "sun", "--camera", cam,
             "-o", tmp_path / "x.exr")
    assert "'--light'" in e and "usd-out" in e, e
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--camera", cam, "-o", tmp_path / "x.exr",
             "--usd-out", tmp_path / "r2.usda")
    assert "'--light'" in e and "which light" in e, e
    # Refused before any work: a layer that is not .usda, or a light not from the stage.
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--light", "sun", "-o", tmp_path / "x.exr",
             "--usd-out", tmp_path / "s.usdc")
    assert "'--usd-out'" in e and ".usda" in e, e
    e = _err(cli, "bake", tmp_path / "shot.usdc", "--light-dir=0,-1,0", "-o", tmp_path / "x.exr",
             "--usd-out", layer)
    assert "'--usd-out'" in e, e
    assert not (tmp_path / "x.exr").exists()
