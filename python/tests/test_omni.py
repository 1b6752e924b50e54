"""Omnidirectional maps (`--omni cube|latlong`) read back by real readers: OpenImageIO calls
them environment maps of the right layout, its `environment()` lookup in any direction agrees
with the latlong map, `umbra.sample_omni` finds every texel's value again from world points
along its direction, and agrees with exact transmittance beyond the volume there; the Python
keyword writes the CLI's bytes."""

import json
import math
import pathlib
import shutil
import subprocess

import numpy as np
import OpenEXR
import pytest

import umbra
from conftest import DATA

SYSTEM_PYTHON = "/usr/bin/python3"
LIGHT = (0.0, 1.5, 0.0)  # inside the sample cloud's box


def _read(path):
    f = OpenEXR.File(str(path), separate_channels=True)
    return np.array(f.channels()["T"].pixels, dtype=np.float64), f.header()


def _texel_dirs(kind, w, h):
    """Each texel's direction, as OpenEXR's ImfEnvmap gives it (integer positions)."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    if kind == "latlong":
        lat = np.pi * (0.5 - ys / (h - 1))
        lon = 2 * np.pi * (0.5 - xs / (w - 1))
        return np.stack([np.sin(lon) * np.cos(lat), np.sin(lat), np.cos(lon) * np.cos(lat)], -1)
    n, m = w, w - 1.0
    face, u, v = ys // n, xs, ys % n
    pif = {0: (m - v, u), 1: (m - v, m - u), 2: (u, m - v), 3: (u, v), 4: (m - u, m - v),
           5: (u, m - v)}
    out = np.zeros((h, w, 3))
    for f in range(6):
        sel = face == f
        a, b = (c[sel] / m * 2 - 1 for c in pif[f])
        one = np.ones_like(a)
        out[sel] = np.stack({0: (one, a, b), 1: (-one, a, b), 2: (a, one, b), 3: (a, -one, b),
                             4: (a, b, one), 5: (a, b, -one)}[f], -1)
    return out


@pytest.mark.parametrize("kind", ["cube", "latlong"])
def test_sample_omni_finds_every_texel_and_matches_exact_beyond_the_volume(cli, tmp_path, kind):
    out = tmp_path / f"{kind}.exr"
    summary = umbra.bake(DATA / "cloud.vdb", out, light_pos=LIGHT, omni=kind, res=16)
    cli("bake", DATA / "cloud.vdb", "--light-pos", "0,1.5,0", "--omni", kind, "--res", "16",
        "-o", tmp_path / "cli.exr", "--quiet")
    assert out.read_bytes() == (tmp_path / "cli.exr").read_bytes()
    t, header = _read(out)
    h, w = t.shape
    assert (w, h) == ((16, 96) if kind == "cube" else (32, 16))
    assert header["umbra:camera_kind"] == kind
    dirs = _texel_dirs(kind, w, h).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    # Points beyond the volume along each texel's direction: the ray from the light through
    # them is the texel's whole ray.
    far = np.asarray(LIGHT) + dirs * (summary["camera"]["t_max"] + 1.0)
    got = umbra.sample_omni(t, header, far)
    assert np.abs(got - t.reshape(-1)).max() < 1e-6
    # The same through the dict bake returned.
    assert np.abs(umbra.sample_omni(t, summary, far) - got).max() == 0
    vol = umbra.Volume(DATA / "cloud.vdb")
    exact = vol.transmittance(np.tile(LIGHT, (len(far[::7]), 1)), far[::7])
    assert np.abs(exact - got[::7]).max() < 1e-6


def test_openimageio_reads_both_layouts_as_environment_maps(cli, tmp_path):
    if shutil.which("oiiotool") is None:
        pytest.fail("oiiotool is missing (.ci/run installs openimageio-tools)")
    for kind, fmt in (("cube", "CubeFace Environment"), ("latlong", "LatLong Environment")):
        out = tmp_path / f"{kind}.exr"
        cli("bake", DATA / "cloud.vdb", "--light-pos", "0,1.5,0", "--omni", kind, "--res", "24",
            "-o", out, "--quiet")
        info = subprocess.run(["oiiotool", "--info", "-v", str(out)], capture_output=True,
                              text=True, check=True).stdout
        assert f'textureformat: "{fmt}"' in info, info


def test_openimageio_environment_lookup_agrees_with_the_latlong_map(cli, tmp_path):
    """OpenImageIO's own environment() (bilinear, no MIP) in 400 random directions against
    umbra.sample_omni on the same map: OpenImageIO assumes latlong there, and places texels
    as OpenEXR does."""
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import OpenImageIO"], capture_output=True)
    if probe.returncode != 0:
        pytest.fail("python3-openimageio is missing (.ci/run installs it)")
    out = tmp_path / "ll.exr"
    cli("bake", DATA / "cloud.vdb", "--light-pos", "0,1.5,0", "--omni", "latlong", "--res",
        "48", "-o", out, "--quiet")
    rng = np.random.default_rng(5)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    script = (
        "import json, sys, OpenImageIO as oiio\n"
        "ts = oiio.TextureSystem(); opt = oiio.TextureOpt()\n"
        "opt.interpmode = oiio.InterpMode.Bilinear; opt.mipmode = oiio.MipMode.NoMIP\n"
        "dirs = json.load(sys.stdin)\n"
        "print(json.dumps([ts.environment(sys.argv[1], opt, tuple(r), (0, 0, 0), (0, 0, 0),"
        " 1)[0] for r in dirs]))\n"
    )
    p = subprocess.run([SYSTEM_PYTHON, "-c", script, str(out)], input=json.dumps(d.tolist()),
                       capture_output=True, text=True, check=True)
    theirs = np.array(json.loads(p.stdout))
    t, header = _read(out)
    ours = umbra.sample_omni(t, header, np.asarray(LIGHT) + d)
    assert np.abs(theirs - ours).max() < 1e-6, np.abs(theirs - ours).max()


def test_omni_options_are_refused_where_they_do_not_apply(cli, tmp_path):
    out = tmp_path / "x.exr"
    for extra, flag in ((["--light-dir", "0,-1,0"], "--light-dir"), (["--fov", "40"], "--fov"),
                        (["--up", "0,0,1"], "--up"), (["--mipmap", "--tile", "16"], "--mipmap")):
        code, _, err = cli("bake", DATA / "cloud.vdb", "--light-pos", "0,1.5,0", "--omni",
                           "cube", *extra, "-o", out, check=False)
        assert code == 1 and f"'{flag}'" in err, err
    code, _, err = cli("bake", DATA / "cloud.vdb", "--light-dir", "0,-1,0", "--omni", "cube",
                       "-o", out, check=False)
    assert code == 1 and "'--omni'" in err and "light-pos" in err, err
    assert not out.exists()
    # Inside the box without --omni the error says what to do.
    code, _, err = cli("bake", DATA / "cloud.vdb", "--light-pos", "0,1.5,0", "-o", out,
                       check=False)
    assert code == 1 and "--omni" in err, err
