"""Volume.bake against `umbra bake` (the EXR read back by OpenEXR's own Python bindings), and
write_exr against the CLI's file, byte for byte."""

import json

import numpy as np
import OpenEXR
import pytest

import umbra
from conftest import DATA, json_lines

CLOUD = "data/cloud.vdb"  # as the CLI is given it (the EXR records the path as given)


def read_exr(path):
    f = OpenEXR.File(str(path), separate_channels=True)
    return {k: np.array(v.pixels) for k, v in f.channels().items()}, f.header()


CASES = [
    (dict(light_dir=(-1, -1, 0), res=(96, 64)), ["--light-dir=-1,-1,0", "--res", "96x64"]),
    (dict(light_dir=(0.2, -1, 0.3), res=80, up=(1, 0, 0)), ["--light-dir=0.2,-1,0.3", "--res", "80", "--up", "1,0,0"]),
    (dict(light_pos=(3, 6, 1), res=(64, 64)), ["--light-pos", "3,6,1", "--res", "64x64"]),
    (dict(light_pos=(3, 6, 1), res=(64, 48), fov=30.0), ["--light-pos", "3,6,1", "--res", "64x48", "--fov", "30"]),
    (dict(light_pos=(0, 1.5, 0), light_dir=(0, -1, 0), fov=60.0, res=(40, 40)),
     ["--light-pos", "0,1.5,0", "--light-dir=0,-1,0", "--fov", "60", "--res", "40x40"]),  # inside
    (dict(light_dir=(-1, -1, 0), res=(64, 64), estimator="ratio", spp=4, seed=3),
     ["--light-dir=-1,-1,0", "--res", "64x64", "--estimator", "ratio", "--spp", "4", "--seed", "3"]),
    (dict(light_dir=(0, -1, 0), res=(48, 48), estimator="riemann", step=0.5, frame_box=[[-1, 0, -1], [1, 3, 1]]),
     ["--light-dir=0,-1,0", "--res", "48x48", "--estimator", "riemann", "--step", "0.5", "--frame-box=-1,0,-1,1,3,1"]),
]


@pytest.mark.parametrize("kw,flags", CASES)
def test_bake_equals_cli_exr(cli, tmp_path, kw, flags):
    out = tmp_path / "cli.exr"
    _, stdout, _ = cli("bake", CLOUD, "--grid", "density", "-o", out, "--json", "--quiet", *flags)
    summary = json.loads(stdout)
    vol = umbra.Volume(CLOUD)
    image, camera = vol.bake(**kw)
    chans, _ = read_exr(out)
    assert image.dtype == np.float32 and image.shape == chans["T"].shape
    assert image.shape == (camera["height"], camera["width"])
    assert np.array_equal(image, chans["T"])
    # The camera dict is the map part of `bake --json`.
    for k, v in camera.items():
        assert summary[k] == v, k
    # Written back, it is the CLI's file, byte for byte.
    umbra.write_exr(tmp_path / "py.exr", image, camera)
    assert (tmp_path / "py.exr").read_bytes() == out.read_bytes()
    assert image.min() < 0.5


def test_stderr_channel(cli, tmp_path):
    out = tmp_path / "cli.exr"
    cli("bake", CLOUD, "--light-dir=-1,-1,0", "--res", "32x32", "--estimator", "track-length",
        "--spp", "8", "--seed", "9", "--stderr", "-o", out, "--quiet")
    image, err, camera = umbra.Volume(CLOUD).bake(light_dir=(-1, -1, 0), res=(32, 32), estimator="track-length",
                                                  spp=8, seed=9, return_stderr=True)
    chans, _ = read_exr(out)
    assert np.array_equal(image, chans["T"]) and np.array_equal(err, chans["T.stderr"])
    assert err.max() > 0
    umbra.write_exr(tmp_path / "py.exr", image, camera, stderr=err)
    assert (tmp_path / "py.exr").read_bytes() == out.read_bytes()
    with pytest.raises(umbra.InvalidArgument, match="stderr"):
        umbra.write_exr(tmp_path / "no.exr", image, camera)


def test_camera_reuse_lines_maps_up(cli, tmp_path):
    vol = umbra.Volume(CLOUD)
    image, camera = vol.bake(light_dir=(-1, -1, 0), res=(64, 64))
    # The same camera, from the dict, from the EXR and from JSON: the same pixels.
    again, cam2 = vol.bake(camera=camera)
    assert np.array_equal(again, image) and cam2["camera"] == camera["camera"]
    umbra.write_exr(tmp_path / "m.exr", image, camera)
    from_exr, _ = vol.bake(camera=tmp_path / "m.exr")
    assert np.array_equal(from_exr, image)
    (tmp_path / "c.json").write_text(json.dumps(camera))
    from_json, _ = vol.bake(camera=str(tmp_path / "c.json"))
    assert np.array_equal(from_json, image)
    # The CLI takes the dict as a camera file too.
    cli("bake", CLOUD, "--camera", tmp_path / "c.json", "-o", tmp_path / "cli.exr", "--quiet")
    chans, _ = read_exr(tmp_path / "cli.exr")
    assert np.array_equal(chans["T"], image)
    # A denser scale through the same camera: the same window, darker.
    dense = umbra.Volume(CLOUD, density_scale=2.0)
    d, dc = dense.bake(camera=camera)
    assert dc["camera"] == camera["camera"] and (d <= image).all() and (d < image).any()


def test_write_exr_checks(tmp_path):
    image, camera = umbra.Volume(CLOUD).bake(light_dir=(-1, -1, 0), res=(16, 8))
    p = tmp_path / "m.exr"
    umbra.write_exr(p, image, camera)
    with pytest.raises(umbra.FileError) as e:
        umbra.write_exr(p, image, camera)
    assert isinstance(e.value, OSError) and "exists" in str(e.value)
    umbra.write_exr(p, image * 0.5, camera, overwrite=True)
    chans, header = read_exr(p)
    assert np.array_equal(chans["T"], image * 0.5)
    assert header["umbra:camera_kind"] == "ortho"
    with pytest.raises(umbra.InvalidArgument, match=r"shape \(8, 16\)"):
        umbra.write_exr(tmp_path / "x.exr", image.T, camera)
    with pytest.raises(umbra.InvalidArgument):
        umbra.write_exr(tmp_path / "x.exr", image, {"width": 16, "height": 8})
    bad = dict(camera, estimator="nope", estimator_params={"name": "nope"})
    with pytest.raises(umbra.InvalidArgument, match="nope"):
        umbra.write_exr(tmp_path / "x.exr", image, bad)
    with pytest.raises(umbra.FileError):
        umbra.write_exr(tmp_path / "no" / "dir" / "x.exr", image, camera)
    assert not (tmp_path / "x.exr").exists()


def test_rgb_scene_equals_cli(cli, tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(
        f'[[volume]]\nfile = "{DATA / "cloud.vdb"}"\ngrid = "density"\nsigma_t = [1.0, 2.0, 0.5]\n'
    )
    out = tmp_path / "cli.exr"
    cli("bake", scene, "--light-dir=-1,-1,0", "--res", "48x32", "-o", out, "--quiet")
    vol = umbra.Volume.from_scene(scene)
    assert vol.channels == 3
    image, camera = vol.bake(light_dir=(-1, -1, 0), res=(48, 32))
    assert image.shape == (32, 48, 3)
    chans, _ = read_exr(out)
    for c, name in enumerate("RGB"):
        assert np.array_equal(image[:, :, c], chans[name])
    umbra.write_exr(tmp_path / "py.exr", image, camera)
    assert (tmp_path / "py.exr").read_bytes() == out.read_bytes()
    # Segments give (N, 3).
    t = vol.transmittance(np.array([[0, 1.5, 0]]), np.array([[3, 4.5, 0]]))
    assert t.shape == (1, 3) and t[0, 1] < t[0, 0] < t[0, 2]


def test_bake_argument_errors():
    vol = umbra.Volume(CLOUD)
    with pytest.raises(umbra.InvalidArgument, match="light_dir"):
        vol.bake()
    with pytest.raises(umbra.InvalidArgument, match="fov"):
        vol.bake(light_dir=(0, -1, 0), fov=20)
    with pytest.raises(umbra.InvalidArgument, match="res"):
        vol.bake(light_dir=(0, -1, 0), res=(0, 10))
    with pytest.raises(umbra.InvalidArgument, match="res"):
        vol.bake(light_dir=(0, -1, 0), res="big")
    with pytest.raises(umbra.InvalidArgument, match="light_dir"):
        vol.bake(light_dir=(0, float("nan"), 0))
    with pytest.raises(umbra.InvalidArgument, match="'spp'|'samples'"):
        vol.bake(light_dir=(0, -1, 0), spp=0, estimator="ratio")
    with pytest.raises(umbra.InvalidArgument, match="camera"):
        vol.bake(camera={"kind": "ortho"})


def test_write_exr_tiled_and_mipmapped(cli, tmp_path):
    out = tmp_path / "cli.exr"
    cli("bake", CLOUD, "--light-dir=-1,-1,0", "--res", "50x30", "--tile", "16",
        "--mipmap", "-o", out, "--quiet")
    image, camera = umbra.Volume(CLOUD).bake(light_dir=(-1, -1, 0), res=(50, 30))
    umbra.write_exr(tmp_path / "py.exr", image, camera, tile=16, mipmap=True)
    assert (tmp_path / "py.exr").read_bytes() == out.read_bytes()
    with pytest.raises(umbra.InvalidArgument, match="'mipmap'.*tile size"):
        umbra.write_exr(tmp_path / "x.exr", image, camera, mipmap=True)
    assert not (tmp_path / "x.exr").exists()


def test_umbra_bake_reports_progress(cli, tmp_path):
    """`umbra.bake(..., progress=)` hears the library's progress: the total up front (pixels;
    a deep map's passes by cost; voxels), `done` rising to it; the file is the CLI's, byte for
    byte, with or without the callback."""
    cli("bake", CLOUD, "--light-dir=-1,-1,0", "--res", "40x30", "-o", tmp_path / "cli.exr",
        "--quiet")
    calls = []
    umbra.bake(CLOUD, tmp_path / "py.exr", light_dir=(-1, -1, 0), res=(40, 30),
               progress=lambda d, t: calls.append((d, t)))
    assert (tmp_path / "py.exr").read_bytes() == (tmp_path / "cli.exr").read_bytes()
    assert calls[0] == (0, 40 * 30) and calls[-1] == (40 * 30, 40 * 30)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))
    deep = []
    umbra.bake(CLOUD, tmp_path / "deep.exr", light_dir=(-1, -1, 0), res=(24, 20), deep=True,
               progress=lambda d, t: deep.append((d, t)))
    assert deep[-1][0] == deep[-1][1] > 0
    vox = []
    umbra.bake(CLOUD, tmp_path / "t.vdb", light_dir=(0, -1, 0),
               progress=lambda d, t: vox.append((d, t)))
    assert vox[-1][0] == vox[-1][1] > 0
    with pytest.raises(umbra.InvalidArgument, match="progress"):
        umbra.bake(CLOUD, tmp_path / "x.exr", light_dir=(0, -1, 0), progress=3)


def test_a_soft_map_says_its_light(tmp_path):
    """Toward a light with extent (docs/lights.md), the returned dict says the light, the
    receiver and the receivers sampled, as `umbra bake --json` does, and so does the header; a
    point light's dict has no `light`."""
    out = tmp_path / "soft.exr"
    d = umbra.bake(DATA / "cloud.vdb", out, light_dir=(0, -1, 0), light_angle=4,
                   light_samples=64, res=8, receiver_depth=3, stderr=True)
    light = d["light"]
    assert light["receiver"] == "depth 3" and light["samples"] == 64
    assert 0 < light["sampled"] <= light["receivers"] == 8 * d["height"]
    assert light["sampled_fraction"] == light["sampled"] / light["receivers"]
    channels, header = read_exr(out)
    assert header["umbra:receiver"] == "depth 3"
    hard = umbra.bake(DATA / "cloud.vdb", tmp_path / "hard.exr", light_dir=(0, -1, 0), res=8)
    assert "light" not in hard
