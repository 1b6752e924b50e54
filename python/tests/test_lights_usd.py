"""Lights with extent read from stages usd-core writes (issue 60 (c)): every UsdLux kind umbra
traces, with authored and fallback sizes, answered by `umbra query STAGE --light NAME --at P`
and checked against an independent quadrature over the light.

The quadrature is built here from usd-core alone: the light's surface points and their area
elements come from `ComputeLocalToWorldTransform` applied to a fine midpoint grid of the shape
in the light's own space (tangents by finite differences, no inverse-transpose formula), each
weighted by `cos(theta_light) dA / d^2` (uniform in solid angle); each segment's exact `T` is
`umbra.Volume.from_usd(...).transmittance` (regular tracking, checked against OpenVDB
elsewhere). A sun is a grid in (cos theta, phi) over its cone; a sphere light the cone of its
visible cap, each segment ending on the sphere.

umbra's `std_err` comes from 8 replicates: it is a t-statistic's scale with 7 degrees of freedom
(docs/lights.md), so the criteria are t7's, as in test_lights_cycles.py: every receiver within
6 std_err plus twice the quadrature's own error (the change from halving its grid; |t7| > 6 has
probability 5e-4), and the mean z^2 over the receivers of a light at most 4 (t7's is 1.4).
Measured over 120 seeds at one penumbra receiver of the cylinder light: rms z 1.36, 3% beyond 3,
2% beyond 4, max 5.0."""

import json
import math
import pathlib

import numpy as np
import pytest

from conftest import DATA

Usd = pytest.importorskip("pxr.Usd")
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdVol  # noqa: E402

import umbra  # noqa: E402

# Receivers under data/cloud.vdb (world box about x -2.15..2.05, y -0.7..2.25, z -2..1.95).
RECEIVERS = [(-1.2, -1.0, 0.3), (0.4, -1.0, -0.5), (1.5, -0.9, 0.8)]


def _stage(path):
    st = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(st, "Y")
    v = UsdVol.Volume.Define(st, "/cloud")
    a = UsdVol.OpenVDBAsset.Define(st, "/cloud/density")
    a.GetFilePathAttr().Set(Sdf.AssetPath(str(DATA / "cloud.vdb")))
    a.GetFieldNameAttr().Set("density")
    v.CreateFieldRelationship("density", a.GetPath())
    down = Gf.Vec3f(-90, 0, 0)  # the light's -Z toward world -Y
    sun = UsdLux.DistantLight.Define(st, "/sun")  # inputs:angle unauthored: 0.53
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-80, 10, 0))
    big = UsdLux.DistantLight.Define(st, "/bigsun")
    big.CreateAngleAttr(12.0)
    UsdGeom.Xformable(big).AddRotateXYZOp().Set(Gf.Vec3f(-75, 20, 0))
    ball = UsdLux.SphereLight.Define(st, "/ball")
    ball.CreateRadiusAttr(0.9)
    UsdGeom.Xformable(ball).AddTranslateOp().Set(Gf.Vec3d(0.3, 4.0, 0.2))
    lamp = UsdLux.SphereLight.Define(st, "/lamp")  # inputs:radius unauthored: 0.5
    UsdGeom.Xformable(lamp).AddTranslateOp().Set(Gf.Vec3d(-0.5, 3.5, 0.0))
    egg = UsdLux.SphereLight.Define(st, "/egg")  # scaled unevenly: an ellipsoid
    egg.CreateRadiusAttr(0.6)
    x = UsdGeom.Xformable(egg)
    x.AddTranslateOp().Set(Gf.Vec3d(0.0, 3.8, 0.0))
    x.AddScaleOp().Set(Gf.Vec3f(2.0, 0.5, 1.0))
    point = UsdLux.SphereLight.Define(st, "/point")
    point.CreateRadiusAttr(0.9)
    point.CreateTreatAsPointAttr(True)
    UsdGeom.Xformable(point).AddTranslateOp().Set(Gf.Vec3d(0.3, 4.0, 0.2))
    disk = UsdLux.DiskLight.Define(st, "/disk")
    disk.CreateRadiusAttr(1.2)
    x = UsdGeom.Xformable(disk)
    x.AddTranslateOp().Set(Gf.Vec3d(0.2, 4.0, 0.0))
    x.AddRotateXYZOp().Set(down)
    rect = UsdLux.RectLight.Define(st, "/rect")
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(0.8)
    x = UsdGeom.Xformable(rect)
    x.AddTranslateOp().Set(Gf.Vec3d(-0.3, 3.6, 0.4))
    x.AddRotateXYZOp().Set(Gf.Vec3f(-90, 0, 30))
    x.AddScaleOp().Set(Gf.Vec3f(1.0, 1.5, 1.0))
    tube = UsdLux.CylinderLight.Define(st, "/tube")
    tube.CreateLengthAttr(3.0)
    tube.CreateRadiusAttr(0.3)
    x = UsdGeom.Xformable(tube)
    x.AddTranslateOp().Set(Gf.Vec3d(0.0, 3.5, 0.3))
    x.AddRotateXYZOp().Set(Gf.Vec3f(0, 40, 0))
    line = UsdLux.CylinderLight.Define(st, "/line")
    line.CreateLengthAttr(3.0)
    line.CreateRadiusAttr(0.3)
    line.CreateTreatAsLineAttr(True)
    UsdGeom.Xformable(line).AddTranslateOp().Set(Gf.Vec3d(0.0, 3.5, 0.3))
    spot = UsdLux.SphereLight.Define(st, "/spot")
    UsdLux.ShapingAPI.Apply(spot.GetPrim()).CreateShapingConeAngleAttr(30.0)
    UsdGeom.Xformable(spot).AddTranslateOp().Set(Gf.Vec3d(0, 4, 0))
    tex = UsdLux.RectLight.Define(st, "/tex")
    tex.CreateTextureFileAttr(Sdf.AssetPath("window.exr"))
    neg = UsdLux.DiskLight.Define(st, "/neg")
    neg.CreateRadiusAttr(-1.0)
    wide = UsdLux.DistantLight.Define(st, "/wide")
    wide.CreateAngleAttr(190.0)
    st.Save()
    return st


def _world(st, prim):
    return UsdGeom.Xformable(st.GetPrimAtPath(prim)).ComputeLocalToWorldTransform(
        Usd.TimeCode.Default())


def _query(cli, stage, light, at, *extra):
    _, out, _ = cli("query", stage, "--light", light, "--at", ",".join(map(repr, at)),
                    "--json", *extra)
    return json.loads(out)


def _mapped(m, q):
    """Local points q (n x 3) to world points by usd-core's matrix (row vectors)."""
    return np.array([list(m.Transform(Gf.Vec3d(*map(float, p)))) for p in q])


def _surface(st, prim, kind, size, n):
    """A midpoint grid of n x n cells over the light's surface: world points, their world area
    elements (finite differences of usd-core's mapping) and unit normals on the emitting side."""
    m = _world(st, prim)
    u = (np.arange(n) + 0.5) / n
    uu, vv = [a.ravel() for a in np.meshgrid(u, u, indexing="ij")]

    def local(a, b):
        if kind == "disk":
            r, ph = size["radius"] * np.sqrt(a), 2 * np.pi * b
            return np.stack([r * np.cos(ph), r * np.sin(ph), 0 * a], 1)
        if kind == "rect":
            return np.stack([(a - 0.5) * size["width"], (b - 0.5) * size["height"], 0 * a], 1)
        if kind == "cylinder":
            ph = 2 * np.pi * b
            r = size["radius"]
            return np.stack([(a - 0.5) * size["length"], r * np.cos(ph), r * np.sin(ph)], 1)
        z = 1 - 2 * a  # the sphere, uniform in area
        ph, s = 2 * np.pi * b, np.sqrt(np.maximum(0, 1 - z * z))
        return size["radius"] * np.stack([s * np.cos(ph), s * np.sin(ph), z], 1)

    h = 1e-6
    p = _mapped(m, local(uu, vv))
    da = (_mapped(m, local(uu + h, vv)) - p) / h
    db = (_mapped(m, local(uu, vv + h)) - p) / h
    cross = np.cross(da, db)
    area = np.linalg.norm(cross, axis=1) / (n * n)
    normal = cross / np.linalg.norm(cross, axis=1)[:, None]
    if kind in ("disk", "rect"):
        # The emitting side: toward the world image of the local -Z.
        below = np.array(list(m.Transform(Gf.Vec3d(0, 0, -1)))) - np.array(
            list(m.Transform(Gf.Vec3d(0, 0, 0))))
        normal *= np.sign(normal @ below)[:, None]
    else:
        centre = np.array(list(m.Transform(Gf.Vec3d(0, 0, 0))))
        if kind == "cylinder":
            ax = np.array(list(m.TransformDir(Gf.Vec3d(1, 0, 0))))
            ax /= np.linalg.norm(ax)
            radial = (p - centre) - np.outer((p - centre) @ ax, ax)
        else:
            radial = p - centre
        normal *= np.sign(np.sum(normal * radial, 1))[:, None]
    return p, area, normal


def _area_quadrature(vol, st, prim, kind, size, x, n):
    p, area, normal = _surface(st, prim, kind, size, n)
    s = np.asarray(x)[None, :] - p
    d = np.linalg.norm(s, axis=1)
    w = np.maximum(0, np.sum(normal * s, 1) / d) * area / d**2
    keep = w > 0
    t = vol.transmittance(np.repeat([x], keep.sum(), 0), p[keep])
    return float(np.sum(w[keep] * t) / np.sum(w[keep]))


def _cone(axis, one_minus_cos, n):
    """Midpoint grid of directions uniform in solid angle within a cone about `axis`."""
    axis = np.asarray(axis) / np.linalg.norm(axis)
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    b1 = np.cross(axis, helper)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(axis, b1)
    u = (np.arange(n) + 0.5) / n
    uu, vv = [a.ravel() for a in np.meshgrid(u, u, indexing="ij")]
    c = 1 - uu * one_minus_cos
    s = np.sqrt(np.maximum(0, 1 - c * c))
    ph = 2 * np.pi * vv
    return (np.outer(s * np.cos(ph), b1) + np.outer(s * np.sin(ph), b2) + np.outer(c, axis))


def _sun_quadrature(vol, st, prim, angle, x, n):
    m = _world(st, prim)
    toward = np.array(list(m.TransformDir(Gf.Vec3d(0, 0, 1))))
    half = math.radians(angle) / 2
    dirs = _cone(toward, 1 - math.cos(half), n)
    t = vol.transmittance(np.repeat([x], len(dirs), 0), np.asarray(x) + 30 * dirs)
    return float(np.mean(t))


def _sphere_quadrature(vol, st, prim, radius, x, n):
    c = np.array(list(_world(st, prim).Transform(Gf.Vec3d(0, 0, 0))))
    v = c - np.asarray(x)
    dist = np.linalg.norm(v)
    sin = radius / dist
    dirs = _cone(v, 1 - math.sqrt(1 - sin * sin), n)
    b = dirs @ v
    t_hit = b - np.sqrt(np.maximum(0, b * b - (dist * dist - radius * radius)))
    ends = np.asarray(x) + dirs * t_hit[:, None]
    return float(np.mean(vol.transmittance(np.repeat([x], len(dirs), 0), ends)))


CASES = [
    ("sun", lambda vol, st, x, n: _sun_quadrature(vol, st, "/sun", 0.53, x, n)),
    ("bigsun", lambda vol, st, x, n: _sun_quadrature(vol, st, "/bigsun", 12.0, x, n)),
    ("ball", lambda vol, st, x, n: _sphere_quadrature(vol, st, "/ball", 0.9, x, n)),
    ("lamp", lambda vol, st, x, n: _sphere_quadrature(vol, st, "/lamp", 0.5, x, n)),
    ("egg", lambda vol, st, x, n: _area_quadrature(vol, st, "/egg", "sphere",
                                                   {"radius": 0.6}, x, n)),
    ("disk", lambda vol, st, x, n: _area_quadrature(vol, st, "/disk", "disk",
                                                    {"radius": 1.2}, x, n)),
    ("rect", lambda vol, st, x, n: _area_quadrature(vol, st, "/rect", "rect",
                                                    {"width": 2.0, "height": 0.8}, x, n)),
    ("tube", lambda vol, st, x, n: _area_quadrature(vol, st, "/tube", "cylinder",
                                                    {"radius": 0.3, "length": 3.0}, x, n)),
    # treatAsLine: the cylinder of radius -> 0, its limit the quadrature takes at 1e-4.
    ("line", lambda vol, st, x, n: _area_quadrature(vol, st, "/line", "cylinder",
                                                    {"radius": 1e-4, "length": 3.0}, x, n)),
]


@pytest.mark.parametrize("name,quad", CASES, ids=[c[0] for c in CASES])
def test_each_light_kind_agrees_with_a_quadrature_over_it(cli, tmp_path, name, quad):
    stage = tmp_path / "lights.usda"
    st = _stage(stage)
    vol = umbra.Volume.from_usd(stage, time=0, light=name)
    soft_vs_hard, z2 = [], []
    for x in RECEIVERS:
        # At the default target (Stein's rule, docs/lights.md): what a user gets. (Under the
        # first count model, fresh replicates after a pilot, the egg's error bar was too small
        # at one receiver, z 3.9 at seed 0; with the pilot kept it is within its bar.)
        got = _query(cli, stage, name, x)
        q1, q2 = quad(vol, st, x, 48), quad(vol, st, x, 96)
        if got["light_samples"] == 0:
            # Answered without sampling (docs/lights.md): the whole cone provably misses every
            # voxel's reach (T = 1, error bar 0), only grazes it (T = 1 within its bound), or
            # is proven deep in umbra (T = U / 2 within U / 2). Each is a bound, not a sigma.
            assert got["tau"] is None and 0.0 <= got["T"] <= 1.0, got
            assert got["T"] == 1.0 or got["T"] == got["std_err"], got
            bar = got["std_err"] + 2 * abs(q2 - q1) + 1e-9
            assert abs(got["T"] - q2) <= bar, (name, x, got, q1, q2)
            continue
        assert got["tau"] is None and got["light_samples"] >= 64, got
        tol = 6 * got["std_err"] + 2 * abs(q2 - q1) + 1e-9
        assert abs(got["T"] - q2) <= tol, (name, x, got["T"], got["std_err"], q1, q2)
        assert 0 < got["std_err"] < 0.02, got
        z2.append(max(0.0, abs(got["T"] - q2) - 2 * abs(q2 - q1)) ** 2 / got["std_err"] ** 2)
        # The same light traced as its centre (the answer before issue 60).
        m = _world(st, "/" + name)
        if name in ("sun", "bigsun"):
            d = -np.array(list(m.TransformDir(Gf.Vec3d(0, 0, 1))))
            flag = "--light-dir=" + ",".join(repr(float(c)) for c in d / np.linalg.norm(d))
        else:
            flag = "--light-pos=" + ",".join(map(repr, list(m.Transform(Gf.Vec3d(0, 0, 0)))))
        _, out, _ = cli("query", DATA / "cloud.vdb", "--at", ",".join(map(repr, x)), flag,
                        "--json")
        # Against a fixed 1024 directions (the reference a user can ask for): a bar small
        # enough to tell the light from its centre.
        fixed = _query(cli, stage, name, x, "--light-samples", "1024")
        soft_vs_hard.append(abs(fixed["T"] - json.loads(out)["T"])
                            / max(fixed["std_err"], 1e-12))
    assert np.mean(z2) <= 4, (name, z2)
    if name != "sun":
        # The extent matters at some receiver (the check can tell a point from the light).
        assert max(soft_vs_hard) > 10, (name, soft_vs_hard)


def test_treat_as_point_is_the_point_light_bit_for_bit(cli, tmp_path):
    stage = tmp_path / "lights.usda"
    st = _stage(stage)
    pos = ",".join(map(repr, list(_world(st, "/point").Transform(Gf.Vec3d(0, 0, 0)))))
    for x in RECEIVERS:
        at = ",".join(map(repr, x))
        got = _query(cli, stage, "point", x)
        _, out, _ = cli("query", DATA / "cloud.vdb", "--at", at, f"--light-pos={pos}", "--json")
        want = json.loads(out)
        assert got["T"] == want["T"] and got["tau"] == want["tau"], (got, want)
        assert "light_samples" not in got or got["light_samples"] is None, got


def test_a_rect_light_emits_on_one_side(cli, tmp_path):
    stage = tmp_path / "lights.usda"
    _stage(stage)
    # Above the rect (it faces down): no light reaches the receiver; by convention T = 1
    # exactly, with no direction traced (docs/lights.md).
    got = _query(cli, stage, "rect", (-0.3, 5.0, 0.4))
    assert got["T"] == 1.0 and got["std_err"] == 0.0 and got["light_samples"] == 0, got
    # Below it, through the cloud: lit, and shadowed.
    got = _query(cli, stage, "rect", (-0.3, -1.0, 0.4))
    assert got["light_samples"] > 0 and got["T"] < 0.9, got
    # A receiver inside the cylinder light's radius sees only its back.
    got = _query(cli, stage, "tube", (0.0, 3.5, 0.3))
    assert got["T"] == 1.0 and got["light_samples"] == 0, got


def test_the_sun_fallback_angle_and_authored_sizes_are_what_info_shows(cli, tmp_path):
    stage = tmp_path / "lights.usda"
    _stage(stage)
    _, out, _ = cli("info", stage, "--json")
    by = {l["prim"]: l for l in json.loads(out)["lights"]}
    assert by["/sun"]["traced"]["kind"] == "directional"
    assert by["/sun"]["traced"]["angle"] == pytest.approx(0.53, abs=1e-7)
    assert by["/bigsun"]["traced"]["angle"] == 12.0
    assert by["/lamp"]["traced"]["kind"] == "sphere" and by["/lamp"]["traced"]["radius"] == 0.5
    assert by["/point"]["traced"]["kind"] == "point"
    assert by["/disk"]["traced"]["kind"] == "disk" and by["/disk"]["traced"]["radius"] == pytest.approx(1.2)
    r = by["/rect"]["traced"]
    assert r["kind"] == "rect" and (r["width"], r["height"]) == (2.0, pytest.approx(0.8))
    assert by["/line"]["traced"]["radius"] == 0.0 and by["/tube"]["traced"]["radius"] == \
        pytest.approx(0.3)
    assert "inputs:shaping:cone:angle" in by["/spot"]["refused"]
    assert "inputs:texture:file" in by["/tex"]["refused"]
    _, text, _ = cli("info", stage)
    assert "0.53 degrees across" in text and "a disk of radius 1.2" in text, text


@pytest.mark.parametrize("light,attr", [("spot", "inputs:shaping:cone:angle"),
                                        ("tex", "inputs:texture:file"),
                                        ("neg", "inputs:radius"),
                                        ("wide", "inputs:angle")])
def test_lights_umbra_cannot_average_are_refused_by_attribute(cli, tmp_path, light, attr):
    stage = tmp_path / "lights.usda"
    _stage(stage)
    code, _, err = cli("query", stage, "--light", light, "--at", "0,-1,0", check=False)
    assert code == 1 and attr in err and f"/{light}" in err, err
    # The stage's other lights still read.
    assert _query(cli, stage, "disk", (0.2, -1.0, 0.0))["light_samples"] > 0
