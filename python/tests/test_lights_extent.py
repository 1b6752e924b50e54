"""Lights with extent from Python (issue 60; docs/lights.md): the keywords ``light_angle``,
``light_radius`` and ``light_samples`` of ``Volume.transmittance_to_light``,
``usd_point_transmittance`` and the transmittance volumes are the CLI's flags. A soft answer is
``umbra query --at`` at the same point with the same seed and ray id, bit for bit; zero extent
is the point light's answer exactly; bad values raise ``ValueError`` naming the keyword."""

import json
import math

import numpy as np
import pytest

import umbra
from conftest import DATA

CLOUD = DATA / "cloud.vdb"
POINTS = np.array([[1.9, -1.0, 0.3], [-2.0, 1.5, 0.3], [0.0, 0.0, 0.0], [9.0, 9.0, 9.0]])
SUN = {"light_dir": (0.0, -1.0, 0.0), "light_angle": 8.0}
LAMP = {"light_pos": (0.0, 6.0, 0.0), "light_radius": 1.0}


def _flags(light):
    out = []
    for k, v in light.items():
        flag = "--" + k.replace("_", "-")
        out.append(f"{flag}=" + (",".join(repr(float(x)) for x in v) if isinstance(v, tuple) else repr(v)))
    return out


def _at(cli, p, light, *extra):
    _, out, _ = cli("query", CLOUD, "--at=" + ",".join(repr(float(x)) for x in p), *_flags(light),
                    "--density-scale=4", "--json", *extra)
    return json.loads(out)


@pytest.mark.parametrize("light", [SUN, LAMP], ids=["sun", "sphere"])
@pytest.mark.parametrize("estimator", ["regular", "ratio"])
def test_each_point_is_the_cli_bit_for_bit(cli, light, estimator):
    vol = umbra.Volume(CLOUD, density_scale=4)
    t, err = vol.transmittance_to_light(POINTS, **light, light_samples=64, estimator=estimator,
                                        samples=2, seed=3, ray_id=10, return_stderr=True)
    assert t.shape == (len(POINTS),)
    for i, p in enumerate(POINTS):
        one = _at(cli, p, light, "--light-samples=64", f"--estimator={estimator}", "--samples=2",
                  "--seed=3", f"--ray-id={10 + i}")
        assert one["T"] == t[i] and one["std_err"] == err[i], (i, one, t[i], err[i])
    # The penumbra point is soft, with an error bar; the same for one thread and two.
    assert 0 < t[0] < 1 and err[0] > 0
    again = vol.transmittance_to_light(POINTS, **light, light_samples=64, estimator=estimator,
                                       samples=2, seed=3, ray_id=10, threads=1)
    assert np.array_equal(again, t)


def test_zero_extent_is_the_point_light_exactly():
    vol = umbra.Volume(CLOUD, density_scale=4)
    for hard, zero in [
        ({"light_dir": (0, -1, 0)}, {"light_dir": (0, -1, 0), "light_angle": 0, "light_samples": 64}),
        ({"light_pos": (0, 6, 0)}, {"light_pos": (0, 6, 0), "light_radius": 0.0}),
    ]:
        a, ea = vol.transmittance_to_light(POINTS, **hard, return_stderr=True)
        b, eb = vol.transmittance_to_light(POINTS, **zero, return_stderr=True)
        assert np.array_equal(a, b) and np.array_equal(ea, eb)


@pytest.mark.parametrize("kw, name", [
    ({"light_dir": (0, -1, 0), "light_angle": -1}, "light_angle"),
    ({"light_dir": (0, -1, 0), "light_angle": math.nan}, "light_angle"),
    ({"light_dir": (0, -1, 0), "light_angle": 180}, "light_angle"),
    ({"light_dir": (0, -1, 0), "light_angle": "8"}, "light_angle"),
    ({"light_pos": (0, 6, 0), "light_radius": -1}, "light_radius"),
    ({"light_pos": (0, 6, 0), "light_radius": math.inf}, "light_radius"),
    ({"light_pos": (0, 6, 0), "light_angle": 2}, "light_angle"),
    ({"light_dir": (0, -1, 0), "light_radius": 2}, "light_radius"),
    ({"light_dir": (0, -1, 0), "light_angle": 2, "light_samples": 0}, "light_samples"),
    ({"light_dir": (0, -1, 0), "light_angle": 2, "light_samples": 2**32}, "light_samples"),
    ({"light_dir": (0, -1, 0), "light_samples": 8}, "light_samples"),
])
def test_bad_values_name_the_keyword(kw, name):
    vol = umbra.Volume(CLOUD)
    with pytest.raises(ValueError, match=f"'{name}'"):
        vol.transmittance_to_light(POINTS, **kw)
    if "light_samples" not in kw or kw.get("light_samples") != 2**32:
        with pytest.raises(ValueError, match=f"'{name}'"):
            vol.transmittance_volume(**kw)


def test_extreme_lights_never_fail():
    vol = umbra.Volume(CLOUD, density_scale=4)
    for kw in [
        {"light_dir": (0, -1, 0), "light_angle": 179.9, "light_samples": 64},
        {"light_dir": (0, -1, 0), "light_angle": 8, "light_samples": 64},
        {"light_pos": (0, 6, 0), "light_radius": 1e300, "light_samples": 64},
        {"light_pos": (0.5, 1, 0), "light_radius": 1.5, "light_samples": 64},
        {"light_pos": (1e300, 0, 0), "light_radius": 1e299},
    ]:
        t, err = vol.transmittance_to_light(POINTS, **kw, return_stderr=True)
        assert np.all((t >= 0) & (t <= 1)) and np.all(np.isfinite(err)), (kw, t, err)


def test_a_voxel_holds_query_at_its_centre(cli, tmp_path):
    vol = umbra.Volume(CLOUD, density_scale=4)
    light = {"light_dir": (0.3, -1.0, 0.2), "light_angle": 8.0}
    ijk, t, stats = vol.transmittance_volume(**light, light_samples=64, seed=2)
    assert stats["light_samples"] == 64 and stats["sampled_fraction"] == 1.0
    assert stats["std_err_max"] > 0
    m = vol.world_from_index
    for k in range(0, len(t), 20011):
        c = m[:3, :3] @ ijk[k].astype(np.float64) + m[:3, 3]
        one = _at(cli, c, light, "--light-samples=64", "--seed=2", f"--ray-id={k}")
        assert np.float32(one["T"]) == t[k], (k, one, t[k])
    # The file Python writes is the CLI's, byte for byte (the extent in its metadata).
    stats = vol.write_transmittance_volume(tmp_path / "py.vdb", **light, light_samples=64, seed=2)
    cli("bake", CLOUD, *_flags(light), "--light-samples=64", "--seed=2", "--density-scale=4",
        "-o", tmp_path / "cli.vdb")
    py, cl = (tmp_path / "py.vdb").read_bytes(), (tmp_path / "cli.vdb").read_bytes()
    assert b"umbra:light_extent" in py
    assert py == cl


def test_usd_points_toward_a_stage_light_with_extent(cli, tmp_path):
    pytest.importorskip("pxr", reason="usd-core (pip install usd-core) writes the test stages")
    from test_usd_points import _with_points

    stage = tmp_path / "shot.usdc"
    _with_points(stage)
    # test_usd's shot authors point lights; here they keep their schema fallbacks (a sun 0.53
    # degrees across, a sphere of radius 0.5).
    from pxr import Usd as _Usd

    st = _Usd.Stage.Open(str(stage))
    st.GetPrimAtPath("/Lights/sun").GetAttribute("inputs:angle").Clear()
    st.GetPrimAtPath("/Lights/lamp").GetAttribute("treatAsPoint").Clear()
    st.Save()
    prim = "/World/forest/trees"
    for light, kw, flag in [("sun", {"light_angle": 4.0}, "--light-angle=4"),
                            ("lamp", {"light_radius": 5.0}, "--light-radius=5")]:
        got = umbra.usd_point_transmittance(stage, prim, light, [1], light_samples=64, seed=4,
                                            return_stderr=True, **kw)
        t, err = got[1.0]
        _, out, _ = cli("query", stage, "--positions", prim, "--light", light, "--frames", "1-1",
                        flag, "--light-samples=64", "--seed=4", "--json")
        doc = json.loads(out)
        assert doc["light_samples"] == 64
        f = doc["frames"][0]
        assert np.array_equal(t, f["T"]) and np.array_equal(err, f["std_err"])
        # Each point is query --at toward the stage light at that point with ray id i.
        for i in (0, 17):
            p = f["positions"][i]
            _, out, _ = cli("query", stage, "--light", light, "--frame=1",
                            "--at=" + ",".join(repr(float(x)) for x in p), flag,
                            "--light-samples=64", "--seed=4", f"--ray-id={i}", "--json")
            assert json.loads(out)["T"] == t[i]
        # The layer holds T and the error bars as vertex primvars usd-core reads back.
        if light == "sun":
            from pxr import Usd, UsdGeom

            layer = tmp_path / "pts.usda"
            cli("query", stage, "--positions", prim, "--light", light, "--frames", "1-1", flag,
                "--light-samples=64", "--seed=4", "--usd-out", layer)
            shot = Usd.Stage.Open(str(stage))
            shot.GetRootLayer().subLayerPaths.append(str(layer))
            pv = UsdGeom.PrimvarsAPI(shot.GetPrimAtPath(prim))
            e = pv.GetPrimvar("umbra:transmittance_std_err:sun")
            assert e.GetInterpolation() == "vertex"
            assert np.array_equal(np.asarray(e.Get(1), dtype=np.float32), err.astype(np.float32))
            v = pv.GetPrimvar("umbra:transmittance:sun").Get(1)
            assert np.array_equal(np.asarray(v, dtype=np.float32), t.astype(np.float32))
        # Zero extent: the light as a point, each point the query toward it at that point.
        zero = {k: 0.0 for k in kw}
        hard = umbra.usd_point_transmittance(stage, prim, light, [1], **zero)[1.0]
        # Without a keyword, the stage light's own extent (the fallbacks: a sun 0.53 degrees
        # across, a sphere of radius 0.5), as `query --at` toward it.
        own, own_err = umbra.usd_point_transmittance(stage, prim, light, [1],
                                                     return_stderr=True)[1.0]
        assert own_err.max() > 0 and not np.array_equal(own, hard)
        for i in (0, 17):
            p = f["positions"][i]
            at = "--at=" + ",".join(repr(float(x)) for x in p)
            zflag = flag.split("=")[0] + "=0"
            _, out, _ = cli("query", stage, "--light", light, "--frame=1", at, zflag, "--json")
            assert json.loads(out)["T"] == hard[i]
            _, out, _ = cli("query", stage, "--light", light, "--frame=1", at, f"--ray-id={i}",
                            "--json")
            assert json.loads(out)["T"] == own[i]
    # The other kind of light's key, or a bad value: named.
    with pytest.raises(ValueError, match="'light_radius'"):
        umbra.usd_point_transmittance(stage, prim, "sun", [1], light_radius=1.0)
    with pytest.raises(ValueError, match="'light_angle'"):
        umbra.usd_point_transmittance(stage, prim, "lamp", [1], light_angle=1.0)
    for bad in (-1.0, math.nan, 180.0):
        with pytest.raises(ValueError, match="'light_angle'"):
            umbra.usd_point_transmittance(stage, prim, "sun", [1], light_angle=bad)
