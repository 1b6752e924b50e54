"""Motion blur from Python: the motion keywords (``velocity``, ``shutter``, ``fps``,
``velocity_scale``, ``time_samples``) answer as ``umbra query --velocity ...`` does, bit for
bit, and bad ones fail with the CLI's message. The caches are written by OpenVDB
(``tests/motion/make_reference.py`` under Debian's python3 with pyopenvdb)."""

import pathlib
import subprocess

import numpy as np
import pytest

import umbra
from conftest import REPO, cli_error, json_lines

SCRIPT = REPO / "tests" / "motion" / "make_reference.py"


@pytest.fixture(scope="module")
def caches(tmp_path_factory):
    d = tmp_path_factory.mktemp("motion")
    p = subprocess.run(["/usr/bin/python3", str(SCRIPT), str(d)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return d


def rays(n=40, seed=3):
    rng = np.random.default_rng(seed)
    centre = np.array([13.3, 8.9, 10.7])
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    a = centre + rng.uniform(-3, 3, (n, 3)) - 20 * d
    return a, a + 40 * d


@pytest.mark.parametrize(
    "kw,flags",
    [
        (dict(estimator="riemann", step=0.5, time_samples=16, shutter=(-1.0, 1.0)),
         ["--estimator", "riemann", "--step", "0.5", "--time-samples", "16", "--shutter", "-1,1"]),
        (dict(estimator="ratio", samples=32, seed=5, fps=30.0, velocity_scale=0.5),
         ["--estimator", "ratio", "--samples", "32", "--seed", "5", "--fps", "30",
          "--velocity-scale", "0.5"]),
    ],
)
def test_blurred_transmittance_equals_the_cli(caches, cli, tmp_path, kw, flags):
    path = caches / "staggered.vdb"
    vol = umbra.Volume(path, density_scale=0.06)
    a, b = rays()
    with open(tmp_path / "rays.csv", "w") as f:
        f.write("ox,oy,oz,ex,ey,ez\n")
        for p, q in zip(a, b):
            f.write(",".join(repr(float(v)) for v in (*p, *q)) + "\n")
    _, out, _ = cli("query", path, "--density-scale", "0.06", "--rays", tmp_path / "rays.csv",
                    "--json", "--velocity", "vel", *flags)
    want = np.array([r["T"] for r in json_lines(out)])
    got, err = vol.transmittance(a, b, velocity="vel", return_stderr=True, **kw)
    assert np.array_equal(got, want), np.abs(got - want).max()
    still = vol.transmittance(a, b, **{k: v for k, v in kw.items()
                                       if k not in ("shutter", "fps", "velocity_scale", "time_samples")})
    assert np.abs(got - still).max() > 0.01, "the rays must cross moving density"


@pytest.mark.parametrize(
    "kw,flags",
    [
        (dict(velocity="vel"), ["--velocity", "vel"]),
        (dict(velocity="vel", estimator="ratio", shutter=(1, 0)),
         ["--velocity", "vel", "--estimator", "ratio", "--shutter", "1,0"]),
        (dict(estimator="ratio", time_samples=4), ["--estimator", "ratio", "--time-samples", "4"]),
        (dict(velocity="density", estimator="ratio"),
         ["--velocity", "density", "--estimator", "ratio"]),
        # Reaches from extreme numbers (issue 58): refused with the reach, never a panic.
        (dict(velocity="vel", estimator="riemann", velocity_scale=1e30),
         ["--velocity", "vel", "--estimator", "riemann", "--velocity-scale", "1e30"]),
        (dict(velocity="vel", estimator="ratio", fps=1e-300),
         ["--velocity", "vel", "--estimator", "ratio", "--fps", "1e-300"]),
    ],
)
def test_bad_motion_keywords_fail_as_the_cli(caches, cli, kw, flags):
    path = caches / "swirl.vdb"
    vol = umbra.Volume(path)
    a, b = rays(2)
    code, _, stderr = cli("query", path, "--from", "1,2,3", "--to", "4,5,6", *flags, check=False)
    assert code == 1
    with pytest.raises(umbra.Error) as e:
        vol.transmittance(a, b, **kw)
    assert str(e.value) == cli_error(stderr)


def test_a_usd_volumes_velocity_field_and_the_stages_rate(caches, cli, tmp_path):
    """A stage written by usd-core: the Volume's ``field:velocity`` (an OpenVDBAsset naming
    the grid ``vel``) and the stage's ``timeCodesPerSecond`` (48) blur it as ``--velocity vel
    --fps 48`` blurs the file itself; an explicit ``--fps`` wins."""
    from pxr import Sdf, Usd, UsdVol

    stage = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    stage.SetTimeCodesPerSecond(48)
    vol = UsdVol.Volume.Define(stage, "/World/Smoke")
    for field, grid in (("density", "density"), ("velocity", "vel")):
        asset = UsdVol.OpenVDBAsset.Define(stage, f"/World/Smoke/{field}")
        asset.CreateFilePathAttr().Set(Sdf.AssetPath(str(caches / "swirl.vdb")))
        asset.CreateFieldNameAttr().Set(grid)
        vol.CreateFieldRelationship(field, asset.GetPath())
    stage.GetRootLayer().Save()
    ray = ["--from", "13.3,-20,10.7", "--to", "13.3,30,10.7", "--density-scale", "0.06",
           "--estimator", "ratio", "--samples", "64", "--json", "--shutter", "-1,1"]

    def t(path, *flags):
        _, out, _ = cli("query", path, *ray, *flags)
        return json_lines(out)[0]["T"]

    on_stage = t(tmp_path / "shot.usda", "--velocity", "velocity")
    assert on_stage == t(caches / "swirl.vdb", "--velocity", "vel", "--fps", "48")
    assert on_stage != t(caches / "swirl.vdb", "--velocity", "vel")
    assert t(tmp_path / "shot.usda", "--velocity", "velocity", "--fps", "24") == t(
        caches / "swirl.vdb", "--velocity", "vel")
    code, _, err = cli("query", tmp_path / "shot.usda", *ray, "--velocity", "vel", check=False)
    assert code == 1 and "vel" in err, err
