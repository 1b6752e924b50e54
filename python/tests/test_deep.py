"""Volume.write_deep_map against `umbra bake ... --deep -o OUT.exr`: the file byte for byte, the
camera dict and the `deep` object of `--json`; its refusals with the CLI's messages; its
camera reused by Volume.bake and by the CLI."""

import json

import numpy as np
import pytest

import umbra
from conftest import cli_error

CLOUD = "data/cloud.vdb"  # as the CLI is given it (the EXR records the path as given)
SHOT = "examples/scene/shot.toml"  # RGB fog (sigma_t) with a solid sphere

CASES = [
    # (input, call kwargs, CLI flags)
    (CLOUD, dict(light_dir=(-1, -1, 0), res=(48, 32)), ["--light-dir=-1,-1,0", "--res", "48x32"]),
    (CLOUD, dict(light_pos=(4, 10, 3), res=(40, 40)), ["--light-pos", "4,10,3", "--res", "40x40"]),
    (CLOUD, dict(light_pos=(4, 10, 3), res=32, fov=40.0, up=(1, 0, 0)),
     ["--light-pos", "4,10,3", "--res", "32", "--fov", "40", "--up", "1,0,0"]),
    (CLOUD, dict(light_dir=(-1, -1, 0), res=(32, 32), estimator="ratio", spp=4, seed=3),
     ["--light-dir=-1,-1,0", "--res", "32x32", "--estimator", "ratio", "--spp", "4", "--seed", "3"]),
    (SHOT, dict(light_dir=(-1, -1, 0.3), res=(40, 32)), ["--light-dir=-1,-1,0.3", "--res", "40x32"]),
    (CLOUD, dict(light_dir=(0.2, -1, 0.3), res=(32, 24), deep_error=0.02),
     ["--light-dir=0.2,-1,0.3", "--res", "32x24", "--deep-error", "0.02"]),
]


def load(path):
    return umbra.Volume.from_scene(path) if path.endswith(".toml") else umbra.Volume(path)


def cli_deep(cli, src, out, *flags):
    _, stdout, _ = cli("bake", src, *flags, "--deep", "-o", out, "--json", "--quiet")
    return json.loads(stdout)


def same_deep(stats, cli_deep_obj):
    assert set(stats) == set(cli_deep_obj)
    for k, v in cli_deep_obj.items():
        if k != "seconds":
            assert stats[k] == v, k
    assert stats["seconds"] >= 0


@pytest.mark.parametrize("src,kw,flags", CASES)
def test_deep_map_equals_cli(cli, tmp_path, src, kw, flags):
    out = tmp_path / "cli.exr"
    report = cli_deep(cli, src, out, *flags)
    camera, deep = load(src).write_deep_map(tmp_path / "py.exr", **kw)
    assert (tmp_path / "py.exr").read_bytes() == out.read_bytes()
    # The camera dict is the map part of `bake --json`, the stats its `deep` object.
    for k, v in camera.items():
        assert report[k] == v, k
    same_deep(deep, report["deep"])
    assert deep["max_error"] == kw.get("deep_error", 0.002)
    assert deep["samples"] > 0 and deep["empty_pixels"] < camera["width"] * camera["height"]
    if src == SHOT:
        assert camera["channels"][:3] == ["R", "G", "B"]


def test_camera_is_reused(cli, tmp_path):
    vol = umbra.Volume(CLOUD)
    camera, _ = vol.write_deep_map(tmp_path / "d.exr", light_dir=(-1, -1, 0), res=(48, 32))
    # Volume.bake through the deep map's camera: the flat map of the same view.
    image, cam2 = vol.bake(camera=camera)
    ref, ref_cam = vol.bake(light_dir=(-1, -1, 0), res=(48, 32))
    assert np.array_equal(image, ref)
    assert cam2["camera"] == camera["camera"] == ref_cam["camera"]
    # The dict (and the flat map's EXR) back into write_deep_map: the CLI's `--camera` file.
    (tmp_path / "c.json").write_text(json.dumps(camera))
    report = cli_deep(cli, CLOUD, tmp_path / "cli.exr", "--camera", tmp_path / "c.json")
    again, deep = vol.write_deep_map(tmp_path / "again.exr", camera=camera)
    assert (tmp_path / "again.exr").read_bytes() == (tmp_path / "cli.exr").read_bytes()
    assert again["camera"] == camera["camera"]
    same_deep(deep, report["deep"])
    umbra.write_exr(tmp_path / "flat.exr", ref, ref_cam)
    vol.write_deep_map(tmp_path / "from_exr.exr", camera=tmp_path / "flat.exr")
    assert (tmp_path / "from_exr.exr").read_bytes() == (tmp_path / "cli.exr").read_bytes()
    # A denser scale through the same camera: the same window.
    dense, _ = umbra.Volume(CLOUD, density_scale=2.0).write_deep_map(
        tmp_path / "dense.exr", camera=camera)
    assert dense["camera"] == camera["camera"] and dense["density_scale"] == 2.0


def test_refusals(cli, tmp_path):
    vol = umbra.Volume(CLOUD)
    # An existing file: the CLI's message, the file untouched; overwrite replaces it.
    p = tmp_path / "d.exr"
    p.write_bytes(b"keep")
    with pytest.raises(umbra.FileError) as e:
        vol.write_deep_map(p, light_dir=(0, -1, 0), res=16)
    assert isinstance(e.value, OSError) and p.read_bytes() == b"keep"
    code, _, stderr = cli("bake", CLOUD, "--light-dir=0,-1,0", "--res", "16", "--deep", "-o", p,
                          "--quiet", check=False)
    assert code == 1 and str(e.value) == cli_error(stderr)
    assert p.read_bytes() == b"keep"
    vol.write_deep_map(p, light_dir=(0, -1, 0), res=16, overwrite=True)
    assert p.read_bytes()[:4] != b"keep"
    # An error bound outside (0, 1): `--deep-error`, as the CLI says it.
    x = tmp_path / "x.exr"
    for bad in (0, 1.5, 0.0, -0.1, float("nan")):
        with pytest.raises(umbra.InvalidArgument, match="'deep_error'") as e:
            vol.write_deep_map(x, light_dir=(0, -1, 0), res=16, deep_error=bad)
        if bad in (0, 1.5):
            code, _, stderr = cli("bake", CLOUD, "--light-dir=0,-1,0", "--res", "16", "--deep",
                                  "--deep-error", bad, "-o", x, "--quiet", check=False)
            assert code == 1 and str(e.value) == cli_error(stderr)
    with pytest.raises(umbra.InvalidArgument, match="deep_error"):
        vol.write_deep_map(x, light_dir=(0, -1, 0), deep_error="small")  # type: ignore[arg-type]
    # A directory that does not exist.
    missing = tmp_path / "no" / "dir" / "d.exr"
    with pytest.raises(umbra.FileError) as e:
        vol.write_deep_map(missing, light_dir=(0, -1, 0), res=16)
    code, _, stderr = cli("bake", CLOUD, "--light-dir=0,-1,0", "--res", "16", "--deep", "-o",
                          missing, "--quiet", check=False)
    assert code == 1 and str(e.value) == cli_error(stderr)
    # The camera arguments are bake's.
    with pytest.raises(umbra.InvalidArgument, match="light_dir"):
        vol.write_deep_map(x)
    with pytest.raises(umbra.InvalidArgument, match="fov"):
        vol.write_deep_map(x, light_dir=(0, -1, 0), fov=20)
    with pytest.raises(umbra.InvalidArgument, match="'spp'|'samples'"):
        vol.write_deep_map(x, light_dir=(0, -1, 0), estimator="ratio", spp=0)
    with pytest.raises(umbra.InvalidArgument, match="camera"):
        vol.write_deep_map(x, camera={"kind": "ortho"})
    with pytest.raises(umbra.InvalidArgument, match="exr"):
        vol.write_deep_map(tmp_path / "x.png", light_dir=(0, -1, 0), res=16)
    assert not x.exists() and not missing.parent.exists()
    assert sorted(f.name for f in tmp_path.iterdir()) == ["d.exr"]
