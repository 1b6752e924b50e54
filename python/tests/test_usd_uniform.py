"""Uniform attributes: the attributes a schema declares `uniform` are read as usd-core's own
readers read them, at the default time with their time samples ignored
(`UsdCollectionAPI::ComputeMembershipQuery`, `UsdGeomXformable::GetOrderedXformOps`); every
other attribute umbra reads is varying and read at the time code. Stages written by usd-core
(`.usda`), held to usd-core's membership and transforms."""

import json
import shutil

import pytest

pxr = pytest.importorskip("pxr", reason="usd-core (pip install usd-core) writes the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdVol  # noqa: E402

from test_usd import CLOUD, _stage, _sun, _xform  # noqa: E402
from test_usd_links import _volume  # noqa: E402

# (prim type, attribute) for every attribute umbra reads from a stage (src/usd/read*):
# the uniform ones it reads at the default time, the varying ones at the time code.
UNIFORM = [
    ("Volume", "xformOpOrder"),
    ("DistantLight", "xformOpOrder"),
    ("Xform", "xformOpOrder"),
    ("SphereLight", "collection:shadowLink:includeRoot"),
    ("SphereLight", "collection:shadowLink:expansionRule"),
    ("SphereLight", "collection:shadowLink:mode"),
    ("SphereLight", "collection:shadowLink:membershipExpression"),
    # A collection a link includes, on any prim.
    ("Xform", "collection:set:includeRoot"),
    ("Xform", "collection:set:expansionRule"),
    ("Xform", "collection:set:mode"),
    ("Xform", "collection:set:membershipExpression"),
]
VARYING = [
    ("Volume", "visibility"),
    ("SphereLight", "visibility"),
    ("Volume", "xformOp:translate"),
    ("SphereLight", "inputs:shadow:enable"),
    ("OpenVDBAsset", "filePath"),
    ("OpenVDBAsset", "fieldName"),
    ("OpenVDBAsset", "fieldIndex"),
    ("Points", "points"),
    ("PointInstancer", "positions"),
]


def _schema_prims():
    st = Usd.Stage.CreateInMemory()
    prims = {}
    for ty in ("Volume", "DistantLight", "Xform", "SphereLight", "OpenVDBAsset", "Points",
               "PointInstancer"):
        prims[ty] = st.DefinePrim(f"/{ty}", ty)
    UsdGeom.Xformable(prims["Volume"]).AddTranslateOp()
    UsdLux.ShadowAPI.Apply(prims["SphereLight"])
    Usd.CollectionAPI.Apply(prims["SphereLight"], "shadowLink")
    Usd.CollectionAPI.Apply(prims["Xform"], "set")
    return st, prims


@pytest.mark.parametrize("ty,name", UNIFORM)
def test_the_attributes_read_at_the_default_time_are_the_uniform_ones(ty, name):
    st, prims = _schema_prims()
    attr = prims[ty].GetAttribute(name)
    assert attr.IsDefined(), (ty, name)
    assert attr.GetVariability() == Sdf.VariabilityUniform, (ty, name)


@pytest.mark.parametrize("ty,name", VARYING)
def test_the_attributes_read_at_the_time_code_are_varying(ty, name):
    st, prims = _schema_prims()
    attr = prims[ty].GetAttribute(name)
    assert attr.IsDefined(), (ty, name)
    assert attr.GetVariability() == Sdf.VariabilityVarying, (ty, name)


def _links_stage(path, *, samples_as_default=False):
    """Volumes under /A and /C; one DistantLight per uniform collection attribute, each
    authoring that attribute with time samples (1 and 2) that would change the membership were
    they read. With `samples_as_default` the sampled values are authored as defaults instead
    (what the membership would be if the samples counted)."""
    shutil.copy(CLOUD, path.parent / "c.vdb")
    st = Usd.Stage.CreateNew(str(path))
    st.SetStartTimeCode(1)
    st.SetEndTimeCode(2)
    paths = ["/A/v1", "/A/B/v2", "/C/v3"]
    for i, p in enumerate(paths):
        _volume(st, p, "./c.vdb", (3 * i, 0, 0))
    lights = {}

    def light(name, attr, sampled, default=None, root=None, inc=()):
        l = UsdLux.DistantLight.Define(st, f"/L/{name}")
        c = Usd.CollectionAPI.Apply(l.GetPrim(), "shadowLink")
        if root is not None:
            c.GetIncludeRootAttr().Set(root)
        for p in inc:
            c.GetIncludesRel().AddTarget(p)
        a = l.GetPrim().GetAttribute(f"collection:shadowLink:{attr}")
        if default is not None:
            a.Set(default)
        if samples_as_default:
            a.Set(sampled)
        else:
            for t in (1, 2):
                a.Set(sampled, t)
            assert a.GetTimeSamples() == [1.0, 2.0]
        lights[f"/L/{name}"] = c

    # The case: includeRoot false only in samples; the fallback (true) holds.
    light("root", "includeRoot", False, inc=["/A/B"])
    light("rootdefault", "includeRoot", True, default=False, inc=["/C"])
    light("rule", "expansionRule", "explicitOnly", root=False, inc=["/A"])
    light("ruledefault", "expansionRule", "expandPrims", default="explicitOnly", root=False,
          inc=["/A", "/A/v1"])
    light("mode", "mode", "expression", root=False, inc=["/A/B/v2"])
    light("expression", "membershipExpression", Sdf.PathExpression("/A//"), root=False)
    st.Save()
    return st, paths, lights


def test_time_sampled_collection_attributes_are_read_at_the_default_time(cli, tmp_path):
    """Every light's link, at frames 1 and 2, holds the volumes usd-core's
    ComputeMembershipQuery says; each differs from what its time samples would give."""
    st, paths, lights = _links_stage(tmp_path / "m.usda")
    (tmp_path / "s").mkdir()
    st_s, _, lights_s = _links_stage(tmp_path / "s" / "m.usda", samples_as_default=True)
    for t in (1, 2):
        _, out, _ = cli("info", tmp_path / "m.usda", "--frame", t, "--json")
        got = {l["prim"]: l["shadow"] for l in json.loads(out)["lights"]}
        assert set(got) == set(lights)
        for prim, c in lights.items():
            q = c.ComputeMembershipQuery()
            want = [p for p in paths if q.IsPathIncluded(Sdf.Path(p))]
            assert got[prim].get("error") is None, (prim, got[prim])
            assert got[prim]["linked"] == want, (t, prim, got[prim], want)
            qs = lights_s[prim].ComputeMembershipQuery()
            sampled = [p for p in paths if qs.IsPathIncluded(Sdf.Path(p))]
            assert sampled != want, (prim, want)


def test_a_sampled_include_root_shadows_as_usd_cores_membership(cli, tmp_path):
    """The issue's stage: the sun's shadowLink includes the puff, with includeRoot false only
    as time samples. usd-core's membership holds both volumes (the fallback, true), so the
    transmittance toward the sun is the one through both volumes (the stage queried with the
    sun's direction and no link), not the puff's alone."""
    st = _stage(tmp_path / "shot.usda")
    _volume(st, "/World/puff", "./cloud.0001.vdb", (0.2, 0.1, 0))
    sun = Usd.CollectionAPI.Apply(st.GetPrimAtPath("/Lights/sun"), "shadowLink")
    for t in (1, 2):
        sun.GetIncludeRootAttr().Set(False, t)
    sun.GetIncludesRel().AddTarget("/World/puff")
    st.Save()
    q = sun.ComputeMembershipQuery()
    assert q.IsPathIncluded("/World/cloud") and q.IsPathIncluded("/World/puff")
    stage = tmp_path / "shot.usda"
    at = "1.4,2.6,3.2"
    for t in (1, 2):
        _, a, _ = cli("query", stage, "--frame", t, "--light", "sun", "--at", at, "--json")
        _, b, _ = cli("query", stage, "--frame", t, f"--light-dir={_sun(st, '/Lights/sun', t)}",
                      "--at", at, "--json")
        _, c, _ = cli("query", stage, "--frame", t, f"--light-dir={_sun(st, '/Lights/sun', t)}",
                      "--volume", "/World/puff", "--at", at, "--json")
        ja, jb, jc = json.loads(a), json.loads(b), json.loads(c)
        assert ja["T"] == jb["T"], (t, ja, jb)
        # The puff alone lets more light through: the samples, read, would have changed T.
        assert ja["T"] < jc["T"], (t, ja, jc)


def test_a_sampled_xform_op_order_is_ignored_as_usd_core_ignores_it(cli, tmp_path):
    """xformOpOrder authored only as time samples: usd-core's transform ignores the ops (the
    order is read at the default time, where there is none); umbra's is usd-core's."""
    st = _stage(tmp_path / "shot.usda")
    order = st.GetPrimAtPath("/World/cloud").GetAttribute("xformOpOrder")
    ops = order.Get()
    order.Clear()
    for t in (1, 2):
        order.Set(ops, t)
    st.Save()
    stage = tmp_path / "shot.usda"
    for t in (1, 2):
        m = UsdGeom.XformCache(t).GetLocalToWorldTransform(st.GetPrimAtPath("/World/cloud"))
        parent = UsdGeom.XformCache(t).GetLocalToWorldTransform(st.GetPrimAtPath("/World"))
        assert m == parent
        _, out, _ = cli("info", stage, "--frame", t, "--json")
        (v,) = [v for v in json.loads(out)["volumes"] if v["prim"] == "/World/cloud"]
        want = [float(c) for c in _xform(st, "/World/cloud", t).split(",")]
        assert v["xform"] == pytest.approx(want, rel=1e-12, abs=1e-12), (t, v["xform"], want)


def test_umbras_own_attributes_are_read_at_the_time_code_as_usd_core_gets_them(cli, tmp_path):
    """`umbra:densityScale` declared uniform by a layer, with time samples: no schema reads it,
    so it is what `UsdAttribute::Get(time)` answers, the sample at the frame."""
    st = _stage(tmp_path / "shot.usda")
    a = st.GetPrimAtPath("/World/cloud").CreateAttribute(
        "umbra:densityScale", Sdf.ValueTypeNames.Float, variability=Sdf.VariabilityUniform)
    a.Set(2.0, 1)
    a.Set(3.0, 2)
    st.Save()
    assert "uniform float umbra:densityScale.timeSamples" in (tmp_path / "shot.usda").read_text()
    for t in (1, 2):
        _, out, _ = cli("info", tmp_path / "shot.usda", "--frame", t, "--json")
        (v,) = json.loads(out)["volumes"]
        assert v["density_scale"] == a.Get(t) == 1.0 + t, (t, v)
