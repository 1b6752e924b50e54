"""Shadow links and shadow enable: stages written by Pixar's usd-core (`pxr`). A light's
`collection:shadowLink` picks the volumes its maps, queries, transmittance volumes and batch
tasks see, with the membership usd-core's `CollectionAPI.ComputeMembershipQuery` computes; a
light with `inputs:shadow:enable = false` is refused when asked for, skipped in jobs."""

import json
import shutil

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core (pip install usd-core) writes the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdVol  # noqa: E402

from test_usd import (  # noqa: E402
    CLOUD, _err, _light_meta, _pixels, _same_pixels, _stage, _sun, _up, _xform,
)


def _volume(st, path, vdb, translate):
    v = UsdVol.Volume.Define(st, path)
    UsdGeom.Xformable(v).AddTranslateOp().Set(Gf.Vec3d(*translate))
    a = UsdVol.OpenVDBAsset.Define(st, path + "/density")
    a.GetFilePathAttr().Set(Sdf.AssetPath(vdb))
    a.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", a.GetPath())
    return v


def _linked(tmp_path, name="shot.usdc"):
    """test_usd's shot (the animated /World/cloud, the sun, the lamp) and a second volume
    /World/puff; the key (a DistantLight) excludes the puff, the sun includes only the puff
    (includeRoot false), the lamp's shadows are off."""
    stage = tmp_path / name
    st = _stage(stage)
    _volume(st, "/World/puff", "./cloud.0001.vdb", (3, 0, 0))
    key = UsdLux.DistantLight.Define(st, "/Lights/key")
    key.CreateAngleAttr(0.0)  # a point sun, as test_usd's (extents: test_lights_usd.py)
    UsdGeom.Xformable(key).AddRotateXYZOp().Set(Gf.Vec3f(-50, 20, 0))
    Usd.CollectionAPI(key.GetPrim(), "shadowLink").GetExcludesRel().AddTarget("/World/puff")
    sun = Usd.CollectionAPI(st.GetPrimAtPath("/Lights/sun"), "shadowLink")
    sun.GetIncludeRootAttr().Set(False)
    sun.GetIncludesRel().AddTarget("/World/puff")
    UsdLux.ShadowAPI.Apply(st.GetPrimAtPath("/Lights/lamp")).CreateShadowEnableAttr(False)
    st.Save()
    return st, stage


COMMON = ["--res", "64", "--quiet", "--force"]


def test_excludes_bake_only_the_linked_volumes(cli, tmp_path):
    """The key excludes the puff: its map (and query) through the stage is the .vdb bake of
    the cloud alone, with usd-core's matrix and light frame, pixel for pixel."""
    st, stage = _linked(tmp_path)
    for t in (1, 2):
        vdb = tmp_path / f"cloud.{t:04d}.vdb"
        cli("bake", stage, "--frame", t, "--light", "key", "-o", tmp_path / "u.exr", *COMMON)
        cli("bake", vdb, f"--xform={_xform(st, '/World/cloud', t)}",
            f"--light-dir={_sun(st, '/Lights/key', t)}", f"--up={_up(st)}",
            "-o", tmp_path / "v.exr", *COMMON)
        _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")
        # Without the link (an explicit light-dir) the puff shadows too: a different map.
        cli("bake", stage, "--frame", t, f"--light-dir={_sun(st, '/Lights/key', t)}",
            "-o", tmp_path / "all.exr", *COMMON)
        assert _pixels(tmp_path / "all.exr")["T"].shape != _pixels(tmp_path / "u.exr")["T"].shape \
            or not np.array_equal(_pixels(tmp_path / "all.exr")["T"],
                                  _pixels(tmp_path / "u.exr")["T"])
        at = "1.4,2.6,3.2"
        _, a, _ = cli("query", stage, "--frame", t, "--light", "key", "--at", at, "--json")
        _, b, _ = cli("query", vdb, f"--xform={_xform(st, '/World/cloud', t)}",
                      f"--light-dir={_sun(st, '/Lights/key', t)}", "--at", at, "--json")
        ja, jb = json.loads(a), json.loads(b)
        assert ja["tau"] == pytest.approx(jb["tau"], rel=1e-12, abs=0), (ja, jb)
        assert 0.0 < ja["T"] < 1.0


def test_include_root_false_and_includes_bake_only_the_included(cli, tmp_path):
    """The sun's link: includeRoot false, includes /World/puff: its map is the puff's alone."""
    st, stage = _linked(tmp_path)
    t = 2
    cli("bake", stage, "--frame", t, "--light", "/Lights/sun", "-o", tmp_path / "u.exr",
        *COMMON)
    cli("bake", tmp_path / "cloud.0001.vdb", f"--xform={_xform(st, '/World/puff', t)}",
        f"--light-dir={_sun(st, '/Lights/sun', t)}", f"--up={_up(st)}",
        "-o", tmp_path / "v.exr", *COMMON)
    _same_pixels(tmp_path / "u.exr", tmp_path / "v.exr")
    # A transmittance volume toward the sun: the stage's two volumes are one toward it.
    cli("bake", stage, "--frame", t, "--light", "sun", "-o", tmp_path / "u.vdb", "--force")
    cli("bake", tmp_path / "cloud.0001.vdb", f"--xform={_xform(st, '/World/puff', t)}",
        f"--light-dir={_sun(st, '/Lights/sun', t)}", "-o", tmp_path / "v.vdb", "--force")
    # Every voxel byte for byte (the file's UUID differs; the transform and the light's
    # metadata to within an ulp, as test_usd.py's transmittance volume test says).
    u, v = (tmp_path / "u.vdb").read_bytes(), (tmp_path / "v.vdb").read_bytes()
    (u0, lu, u1), (v0, lv, v1) = _light_meta(u), _light_meta(v)
    assert len(u1) == len(v1) > 600_000 and len(u0) == len(v0)
    at = u1.index(b"AffineMap") + 9 + 4 * 8 * 4
    assert u1[at:] == v1[at:]
    assert np.allclose(lu, lv, rtol=1e-15, atol=1e-15), (lu, lv)
    # Toward a light that links both, one grid cannot be chosen.
    line = _err(cli, "bake", stage, "--frame", t, "--light-dir=0,0,-1", "-o", tmp_path / "w.vdb")
    assert "2 volumes" in line, line


def test_python_reads_toward_a_light(cli, tmp_path):
    import umbra

    st, stage = _linked(tmp_path)
    vol = umbra.Volume.from_usd(stage, time=1, light="key")
    at = np.array([[1.4, 2.6, 3.2]])
    d = np.array([[float(c) for c in _sun(st, "/Lights/key", 1).split(",")]])
    one = umbra.Volume.from_usd(stage, time=1, volumes=["/World/cloud"])
    assert np.array_equal(vol.transmittance_to_light(at, light_dir=d[0]),
                          one.transmittance_to_light(at, light_dir=d[0]))
    with pytest.raises(umbra.Error, match="inputs:shadow:enable"):
        umbra.Volume.from_usd(stage, time=1, light="lamp")
    with pytest.raises(umbra.Error, match="inputs:shadow:enable"):
        umbra.bake(stage, tmp_path / "lamp.exr", frame=1, light="lamp", res=32)
    assert not (tmp_path / "lamp.exr").exists()
    lights = {l["name"]: l for l in umbra.usd_lights(stage, time=1)["lights"]}
    assert lights["key"]["linked"] == ["/World/cloud"] and lights["key"]["shadow_enable"]
    assert lights["sun"]["linked"] == ["/World/puff"]
    assert lights["lamp"]["shadow_enable"] is False


def _membership_stage(tmp_path):
    """Volumes at several depths and lights with every kind of link."""
    shutil.copy(CLOUD, tmp_path / "c.vdb")
    st = Usd.Stage.CreateNew(str(tmp_path / "m.usda"))
    paths = ["/A/v1", "/A/B/v2", "/A/B/v3", "/A/B/v3/v4", "/C/v5", "/C/D/v6", "/E"]
    for i, p in enumerate(paths):
        _volume(st, p, "./c.vdb", (3 * i, 0, 0))
    lights = {}

    def light(name, **k):
        l = UsdLux.DistantLight.Define(st, f"/L/{name}")
        c = Usd.CollectionAPI(l.GetPrim(), "shadowLink")
        if "root" in k:
            c.GetIncludeRootAttr().Set(k["root"])
        for p in k.get("inc", []):
            c.GetIncludesRel().AddTarget(p)
        for p in k.get("exc", []):
            c.GetExcludesRel().AddTarget(p)
        if "rule" in k:
            c.GetExpansionRuleAttr().Set(k["rule"])
        lights[f"/L/{name}"] = c

    light("all")
    light("exc", exc=["/A/B", "/C/D/v6"])
    light("inc", root=False, inc=["/A/B", "/C"], exc=["/A/B/v3"])
    light("reinc", root=False, inc=["/A", "/A/B/v3/v4"], exc=["/A/B"])
    light("explicit", root=False, inc=["/A/B", "/A/B/v2", "/C/v5"], rule="explicitOnly")
    light("props", root=False, inc=["/C"], rule="expandPrimsAndProperties")
    light("nested", root=False, inc=["/L/inc.collection:shadowLink", "/E"], exc=["/C/v5"])
    light("none", root=False)
    st.Save()
    return st, paths, lights


def test_membership_is_usd_cores(cli, tmp_path):
    """For every light, the volumes `umbra info` says its link includes are those usd-core's
    ComputeMembershipQuery().IsPathIncluded says, path by path."""
    st, paths, lights = _membership_stage(tmp_path)
    _, out, _ = cli("info", tmp_path / "m.usda", "--json")
    got = {l["prim"]: l["shadow"] for l in json.loads(out)["lights"]}
    assert set(got) == set(lights)
    kinds = set()
    for prim, c in lights.items():
        q = c.ComputeMembershipQuery()
        want = [p for p in paths if q.IsPathIncluded(Sdf.Path(p))]
        assert got[prim]["linked"] == want, (prim, got[prim], want)
        assert got[prim]["unlinked"] == [p for p in paths if p not in want]
        assert got[prim]["enable"] is True
        rules = {str(p): r for p, r in q.GetAsPathExpansionRuleMap().items()}
        assert got[prim]["link"] == rules, (prim, got[prim]["link"], rules)
        kinds.add(tuple(want))
    assert len(kinds) >= 6, kinds
    # The text form names them too.
    _, text, _ = cli("info", tmp_path / "m.usda")
    assert "    shadow link: no volume (leaves out /A/v1" in text, text


def test_a_light_linking_no_volume_is_refused(cli, tmp_path):
    _membership_stage(tmp_path)
    line = _err(cli, "bake", tmp_path / "m.usda", "--light", "/L/none", "-o", tmp_path / "n.exr")
    assert "/L/none" in line and "shadowLink" in line and "none of the volumes" in line, line
    assert not (tmp_path / "n.exr").exists()


def test_a_light_without_shadows_is_refused(cli, tmp_path):
    """inputs:shadow:enable = false: an explicit bake, transmittance volume or query toward
    the lamp fails with one line naming the light and the attribute; nothing is written."""
    _, stage = _linked(tmp_path)
    for out in ("lamp.exr", "lamp.vdb"):
        line = _err(cli, "bake", stage, "--light", "lamp", "-o", tmp_path / out)
        assert "/Lights/lamp" in line and "inputs:shadow:enable" in line, line
        assert not (tmp_path / out).exists()
    line = _err(cli, "bake", stage, "--light", "lamp", "-o", tmp_path / "lamp.exr",
                "--usd-out", tmp_path / "s.usda")
    assert "inputs:shadow:enable" in line and not (tmp_path / "s.usda").exists()
    line = _err(cli, "query", stage, "--light", "/Lights/lamp", "--at", "1,2,3")
    assert "/Lights/lamp" in line and "inputs:shadow:enable" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "cloud.0001.vdb", "cloud.0002.vdb", "shot.usdc"]


def test_a_job_over_every_light_skips_the_one_without_shadows(cli, tmp_path):
    """A job over every stage light: the lamp (shadows off) bakes nothing; the run exits 0,
    --plan and --status list its tasks as skipped, not missing; each other light's map is the
    explicit bake toward it (its link honoured, its shared camera framing its own volumes)."""
    _linked(tmp_path)
    job = tmp_path / "job.toml"
    job.write_text('output = "out/{light}.{frame:04}.exr"\n'
                   '[[inputs]]\nusd = "shot.usdc"\nframes = [1, 2]\n'
                   '[bake]\nres = 40\nframing = "per-frame"\n')
    code, out, err = cli("batch", job, "--plan", check=False)
    assert code == 0, err
    skipped = [l for l in out.splitlines() if l.startswith("# skipped task")]
    runs = [l for l in out.splitlines() if "--task" in l]
    assert len(skipped) == 2 and len(runs) == 4, out
    assert all("light lamp" in l and "inputs:shadow:enable" in l for l in skipped), out
    code, out, err = cli("batch", job, check=False)
    assert code == 0, err
    assert "4 baked" in out and "2 skipped (no shadows)" in out and "0 failed" in out, out
    names = sorted(p.name for p in (tmp_path / "out").glob("*.exr"))
    assert names == ["key.0001.exr", "key.0002.exr", "sun.0001.exr", "sun.0002.exr"], names
    for light in ("key", "sun"):
        for f in (1, 2):
            cli("bake", tmp_path / "shot.usdc", "--frame", f, "--light", light, "--res", 40,
                "-o", tmp_path / "want.exr", "--quiet", "--force")
            _same_pixels(tmp_path / "out" / f"{light}.{f:04d}.exr", tmp_path / "want.exr")
    code, out, err = cli("batch", job, "--status", check=False)
    assert code == 0, (out, err)
    assert "4 done, 0 failed, 0 stale, 0 not yet run, 2 skipped (no shadows)" in out, out
    assert sum(l.startswith("skipped task") and "light lamp" in l for l in out.splitlines()) == 2
    _, js, _ = cli("batch", job, "--status", "--json")
    s = json.loads(js)
    assert [t["light"] for t in s["skipped"]] == ["lamp", "lamp"] and s["missing"] == []
    assert all("inputs:shadow:enable" in t["error"] for t in s["skipped"])
    # The log says why.
    log = [json.loads(l) for l in (tmp_path / "out" / "umbra_batch.jsonl").read_text().splitlines()]
    assert any(r["status"] == "skipped" and "inputs:shadow:enable" in r.get("reason", "")
               for r in log if r["light"] == "lamp"), log


def test_a_shared_camera_frames_the_lights_own_volumes(cli, tmp_path):
    """framing = "shared": the key's camera frames the cloud only, the sun's the puff only,
    so one frame's map equals the explicit bake of that light's volume with the same camera
    (framing one frame is exactly its box)."""
    st, stage = _linked(tmp_path)
    job = tmp_path / "job.toml"
    job.write_text('output = "sh/{light}.exr"\n'
                   '[[inputs]]\nusd = "shot.usdc"\n'
                   '[bake]\nres = 40\n'
                   '[[lights]]\nusd = "/Lights/key"\n')
    cli("batch", job)
    cli("bake", tmp_path / "cloud.0001.vdb", f"--xform={_xform(st, '/World/cloud', 1)}",
        f"--light-dir={_sun(st, '/Lights/key', 1)}", f"--up={_up(st)}", "--res", 40,
        "-o", tmp_path / "v.exr", "--quiet", "--force")
    _same_pixels(tmp_path / "sh" / "key.exr", tmp_path / "v.exr")


def test_a_link_umbra_cannot_read_fails_only_its_light(cli, tmp_path):
    """A path-expression link (usd-core's expression mode) and an unknown expansionRule: the
    light is refused naming the attribute; the stage's other lights still bake."""
    st = _stage(tmp_path / "shot.usda")
    c = Usd.CollectionAPI(st.GetPrimAtPath("/Lights/sun"), "shadowLink")
    c.GetIncludeRootAttr().Set(False)
    c.GetMembershipExpressionAttr().Set(Sdf.PathExpression("/World//"))
    assert c.IsInExpressionMode()
    Usd.CollectionAPI(st.GetPrimAtPath("/Lights/lamp"), "shadowLink") \
        .GetExpansionRuleAttr().Set("bogus")
    st.Save()
    stage = tmp_path / "shot.usda"
    line = _err(cli, "bake", stage, "--light", "sun", "-o", tmp_path / "s.exr")
    assert "/Lights/sun" in line and "membershipExpression" in line, line
    line = _err(cli, "query", stage, "--light", "lamp", "--at", "1,2,3")
    assert "/Lights/lamp" in line and "expansionRule" in line and "bogus" in line, line
    cli("bake", stage, "--light-dir=0,0,-1", "-o", tmp_path / "d.exr", *COMMON)
    _, out, _ = cli("info", stage, "--json")
    errs = {l["prim"]: l["shadow"]["error"] for l in json.loads(out)["lights"]}
    assert "membershipExpression" in errs["/Lights/sun"] and "bogus" in errs["/Lights/lamp"]
