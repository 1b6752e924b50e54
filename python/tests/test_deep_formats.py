"""Fixed-size deep maps (`umbra bake --deep-format`) read back by OpenImageIO and looked up with
`umbra.deep_lookup` (the numpy reconstruction, written apart from the Rust one) at 49 depths of
every texel: within the error the header reports (`umbra:deep_max_error`) of the exact T, which
an exact map with 49 `--depths` slices on the same camera gives; T in [0, 1] and never growing
with depth."""

import json
import subprocess

import numpy as np
import OpenEXR
import pytest

import umbra
from conftest import DATA, cli_error

SYSTEM_PYTHON = "/usr/bin/python3"
FORMATS = ["fourier:3", "fourier:15", "moments:4", "moments:6", "avsm:4", "avsm:8"]

OIIO_READ = (
    "import json, sys, OpenImageIO as oiio\n"
    "inp = oiio.ImageInput.open(sys.argv[1]); spec = inp.spec()\n"
    "px = inp.read_image(0, 0, 0, spec.nchannels, 'float')\n"
    "h = {a.name: (list(a.value) if isinstance(a.value, tuple) else a.value)"
    " for a in spec.extra_attribs}\n"
    "h['channelnames'] = list(spec.channelnames)\n"
    "print(json.dumps({'pixels': px.tolist(), 'header': h}))\n"
)


def oiio_read(path):
    """The map as OpenImageIO reads it: pixels (H, W, C) and header (extra_attribs and
    channelnames)."""
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import OpenImageIO"], capture_output=True)
    if probe.returncode != 0:
        pytest.fail("python3-openimageio is missing (.ci/run installs it)")
    p = subprocess.run([SYSTEM_PYTHON, "-c", OIIO_READ, str(path)], capture_output=True,
                       text=True, check=True)
    d = json.loads(p.stdout)
    return np.asarray(d["pixels"], dtype=np.float32), d["header"]


def slices(path, names):
    f = OpenEXR.File(str(path), separate_channels=True)
    ch = f.channels()
    return np.stack([np.asarray(ch[n].pixels, dtype=np.float64) for n in names], -1)


def check(cli, tmp_path, view, medium, fmt, colour=False):
    tmp_path = tmp_path / fmt.replace(":", "_")
    tmp_path.mkdir()
    fixed = tmp_path / "fixed.exr"
    _, out, _ = cli("bake", DATA / "cloud.vdb", *view, *medium, "--deep-format", fmt, "-o", fixed,
                    "--json", "--quiet")
    stats = json.loads(out)["deep_format"]
    img, header = oiio_read(fixed)
    assert header["umbra:deep_format"] == fmt
    bound = float(header["umbra:deep_max_error"])
    assert bound >= stats["max_error"] - 1e-7 and bound < 1
    assert stats["channels"] == img.shape[2] - (3 if colour else 1)
    near, far = float(header["umbra:deep_near"]), float(header["umbra:deep_far"])
    depths = near + (far - near) * (np.arange(49) + 0.5) / 49
    flat = tmp_path / "flat.exr"
    cli("bake", DATA / "cloud.vdb", *medium, "--camera", fixed, "-o", flat, "--depths",
        ",".join(f"{z:.17g}" for z in depths), "--quiet")
    names = [f"slice{k:02}.{c}" for k in range(49) for c in (("R", "G", "B") if colour else "T")]
    exact = slices(flat, names).reshape(img.shape[0], img.shape[1], 49, -1)
    h, w = img.shape[:2]
    v = lambda k: np.asarray(header[f"umbra:camera_{k}"], dtype=np.float64)
    o, sx, sy, d = v("origin"), v("step_x"), v("step_y"), v("direction")
    j, i = np.mgrid[0:h, 0:w]
    if header["umbra:camera_kind"] == "ortho":
        start = o + i[..., None] * sx + j[..., None] * sy
        dirs = np.broadcast_to(d / np.linalg.norm(d), start.shape)
    else:
        start = np.broadcast_to(o, (h, w, 3))
        dirs = d + i[..., None] * sx + j[..., None] * sy
        dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    pts = start[:, :, None, :] + dirs[:, :, None, :] * depths[None, None, :, None]
    got = umbra.deep_lookup(img, header, pts.reshape(-1, 3)).reshape(h, w, 49, -1)
    err = np.abs(got - exact).max()
    assert err <= bound + 1e-6, (fmt, err, bound)
    assert np.all((got >= 0) & (got <= 1))
    assert np.all(np.diff(got, axis=2) <= 1e-9), fmt
    return stats, err


@pytest.mark.parametrize("fmt", FORMATS)
def test_formats_hold_their_reported_error_at_49_depths(cli, tmp_path, fmt):
    view = ["--res", "40x36", "--light-dir", "0.3,-1,0.2"]
    stats, err = check(cli, tmp_path, view, ["--density-scale", "4"], fmt)
    # The bound is a bound, and not a loose one: within a factor 3 of what 49 depths see.
    assert err <= stats["max_error"] <= 3 * err + 2e-3, (fmt, err, stats["max_error"])


def test_perspective_and_colour_maps(cli, tmp_path):
    check(cli, tmp_path, ["--res", "32", "--light-pos", "4,10,3"], ["--density-scale", "4"],
          "avsm:8")
    check(cli, tmp_path, ["--res", "24", "--light-dir", "0.3,-1,0.2"], ["--sigma-t", "4,2,1"],
          "fourier:7", colour=True)


def test_the_sample_cloud_fits_in_16_channels(cli, tmp_path):
    """At least one format reaches an RMS error of 0.01 in T or less in 16 channels."""
    best = []
    for fmt in ("avsm:8", "fourier:15", "moments:6"):
        _, out, _ = cli("bake", DATA / "cloud.vdb", "--light-dir", "0.3,-1,0.2", "--res", "64",
                        "--deep-format", fmt, "-o", tmp_path / "m.exr", "--json", "--quiet",
                        "--force")
        best.append(json.loads(out)["deep_format"]["rms_error"])
    assert min(best) <= 0.01, best


def test_python_bake_and_write_deep_map_equal_the_cli(cli, tmp_path):
    out = tmp_path / "cli.exr"
    _, rep, _ = cli("bake", DATA / "cloud.vdb", "--light-dir", "0.3,-1,0.2", "--res", "24",
                    "--deep-format", "moments:6", "-o", out, "--json", "--quiet")
    py = umbra.bake(DATA / "cloud.vdb", tmp_path / "py.exr", light_dir=(0.3, -1, 0.2), res=24,
                    deep_format="moments:6")
    assert (tmp_path / "py.exr").read_bytes() == out.read_bytes()
    cam, stats = umbra.Volume(str(DATA / "cloud.vdb")).write_deep_map(
        tmp_path / "vol.exr", light_dir=(0.3, -1, 0.2), res=24, deep_format="moments:6")
    want = json.loads(rep)["deep_format"]
    for k, v in want.items():
        if k != "seconds":
            assert py["deep_format"][k] == v and stats[k] == v, k


def test_refusals_name_the_option(cli, tmp_path):
    for fmt in ("fourier:4", "moments:5", "avsm:1", "wavelet:8"):
        code, _, err = cli("bake", DATA / "cloud.vdb", "--light-dir", "0,-1,0", "--deep-format",
                           fmt, "-o", tmp_path / "x.exr", check=False)
        assert code == 1 and "--deep-format" in err, err
        with pytest.raises(umbra.InvalidArgument) as e:
            umbra.bake(DATA / "cloud.vdb", tmp_path / "y.exr", light_dir=(0, -1, 0),
                       deep_format=fmt)
        assert str(e.value) == cli_error(err)
    code, _, err = cli("bake", DATA / "cloud.vdb", "--light-dir", "0,-1,0", "--deep-format",
                       "avsm:8", "--deep-error", "0.01", "-o", tmp_path / "x.exr", check=False)
    assert code == 1 and "--deep-error" in err, err
    assert not (tmp_path / "x.exr").exists()


GLSL_MAIN = """
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Coef { float coef[]; };
layout(std430, binding = 1) readonly buffer Depth { float depth[]; };
layout(std430, binding = 2) writeonly buffer Out { float result[]; };
uniform int C;
uniform int K;
uniform int kind;
uniform int nq;
void main() {
    int g = int(gl_GlobalInvocationID.x);
    if (g >= nq) {
        return;
    }
    float u = depth[g];
    if (kind == 0) {
        float c[UMBRA_FOURIER_MAX];
        for (int i = 0; i < C; ++i) c[i] = coef[g * C + i];
        result[g] = umbraFourierT(c, K, u);
    } else if (kind == 1) {
        float c[7];
        for (int i = 0; i < 7; ++i) c[i] = i < C ? coef[g * C + i] : 0.0;
        result[g] = umbraMomentsT(c, K, u);
    } else {
        float c[2 * UMBRA_AVSM_MAX];
        for (int i = 0; i < C; ++i) c[i] = coef[g * C + i];
        result[g] = umbraAvsmT(c, K, u);
    }
}
"""


SHADER_FORMATS = FORMATS + ["fourier:31", "avsm:16"]


def baked_texels(cli, tmp_path, fmt):
    """Every texel's channels of a 24^2 map of the sample cloud in `fmt`, in the format's
    order: (texels, channels) float32, as the EXR holds them."""
    out = tmp_path / f"{fmt.replace(':', '_')}.exr"
    cli("bake", DATA / "cloud.vdb", "--res", "24", "--light-dir", "0.3,-1,0.2",
        "--density-scale", "4", "--deep-format", fmt, "-o", out, "--quiet", "--force")
    ch = OpenEXR.File(str(out), separate_channels=True).channels()
    return np.stack([np.asarray(ch[f"deep.{n}"].pixels, dtype=np.float32).ravel()
                     for n in umbra._channel_order(fmt)], -1)


def test_glsl_reconstructions_agree_with_python(cli, tmp_path):
    """examples/deep_formats.glsl run on a GPU (Mesa's llvmpipe through EGL where there is no
    other) against umbra.deep_transmittance, on every texel of baked maps at 49 depths."""
    import moderngl

    ctx = moderngl.create_standalone_context(backend="egl")
    glsl = (DATA.parent / "examples" / "deep_formats.glsl").read_text()
    prog = ctx.compute_shader("#version 450\n" + glsl + GLSL_MAIN)
    worst = {}
    for fmt in SHADER_FORMATS:
        coef = baked_texels(cli, tmp_path, fmt)
        u = np.linspace(-0.05, 1.05, 49)
        c = np.repeat(coef, len(u), axis=0)
        uu = np.tile(u, len(coef))
        want = umbra.deep_transmittance(fmt, c, uu)
        name, _, k = fmt.partition(":")
        bufs = [ctx.buffer(c.astype(np.float32).tobytes()),
                ctx.buffer(uu.astype(np.float32).tobytes()),
                ctx.buffer(reserve=4 * len(uu))]
        for i, b in enumerate(bufs):
            b.bind_to_storage_buffer(i)
        prog["C"], prog["K"], prog["nq"] = c.shape[1], int(k), len(uu)
        prog["kind"] = {"fourier": 0, "moments": 1, "avsm": 2}[name]
        prog.run(group_x=(len(uu) + 63) // 64)
        got = np.frombuffer(bufs[2].read(), dtype=np.float32).astype(np.float64)
        worst[fmt] = np.abs(got - want).max()
    # f32 arithmetic against f64: the smooth bases and the nodes to a few ulps of T; the moment
    # bound (a 4x4 solve and a cubic in f32) to 1e-4.
    for fmt, e in worst.items():
        assert e <= (1e-4 if fmt.startswith("moments") else 2e-5), worst


def bpy_python():
    """The Python that has Blender's `bpy` (python/run_tests.sh makes it: a venv of its own,
    since bpy pins its own numpy), from UMBRA_BPY_PYTHON."""
    import os

    path = os.environ.get("UMBRA_BPY_PYTHON", "")
    if path and os.path.exists(path):
        return path
    if os.environ.get("UMBRA_SKIP_OSL") == "1":
        pytest.skip("UMBRA_SKIP_OSL=1: no Blender with OSL")
    pytest.fail("UMBRA_BPY_PYTHON names no Python with bpy (python/run_tests.sh installs it); "
                "set UMBRA_SKIP_OSL=1 to skip")


def test_osl_reconstructions_agree_with_python_through_cycles(cli, tmp_path):
    """examples/deep_formats.osl compiled and run by Blender's Cycles (OSL on the CPU) against
    umbra.deep_transmittance: 24 texels of baked maps (the lit ones spread over the map) at 49
    depths, every format."""
    cases, wants = [], []
    for fmt in SHADER_FORMATS:
        coef = baked_texels(cli, tmp_path, fmt)
        lit = np.flatnonzero(np.abs(coef).sum(-1) > 0)
        pick = lit[np.linspace(0, len(lit) - 1, 24).astype(int)]
        u = np.linspace(-0.05, 1.05, 49)
        name, _, k = fmt.partition(":")
        cases.append({"format": name, "size": int(k), "texels": coef[pick].tolist(),
                      "u": u.tolist()})
        c = np.repeat(coef[pick], len(u), axis=0)
        wants.append(umbra.deep_transmittance(fmt, c, np.tile(u, len(pick)))
                     .reshape(len(pick), len(u)))
    job = {"osl": str(DATA.parent / "examples" / "deep_formats.osl"), "work": str(tmp_path),
           "cases": cases}
    p = subprocess.run([bpy_python(), str(DATA.parent / "python" / "tests" / "osl_cycles.py")],
                       input=json.dumps(job), capture_output=True, text=True)
    assert p.returncode == 0, p.stderr[-3000:]
    got = json.loads(p.stdout[p.stdout.rindex('{"T"'):])["T"]
    worst = {}
    for fmt, g, want in zip(SHADER_FORMATS, got, wants):
        worst[fmt] = float(np.abs(np.asarray(g, dtype=np.float64) - want).max())
    # As the GLSL: float arithmetic against f64.
    for fmt, e in worst.items():
        assert e <= (1e-4 if fmt.startswith("moments") else 2e-5), worst


def test_compare_deep_reports_every_encoding(cli, tmp_path):
    """`umbra compare --deep`: one row per encoding, each row what its map's header and
    `bake --json` say (bytes per texel, errors), the maps kept, the plot with its legend."""
    out = tmp_path / "cmp"
    cli("compare", DATA / "cloud.vdb", "--deep", "--density-scale", "4", "--light-dir",
        "0.3,-1,0.2", "--res", "24", "-o", out, "-q")
    report = json.loads((out / "deep.json").read_text())
    rows = report["rows"]
    assert [r["encoding"] for r in rows] == [
        "--deep-error 0.02", "--deep-error 0.005", "--deep-error 0.002", "fourier:3",
        "fourier:7", "fourier:15", "fourier:31", "moments:4", "moments:6", "avsm:2", "avsm:4",
        "avsm:8", "avsm:16"]
    for r in rows:
        assert 0 < r["rms_error"] <= r["max_error"] < 1 and r["seconds"] > 0, r
        if r["family"] == "lokovic-veach":
            assert r["max_error"] == float(r["encoding"].split()[-1])
            assert r["max_bytes_per_texel"] >= r["bytes_per_texel"] > 4
            continue
        img, header = oiio_read(out / "maps" / (r["encoding"].replace(":", "_") + ".exr"))
        assert float(header["umbra:deep_max_error"]) == pytest.approx(r["max_error"], rel=1e-6)
        assert r["bytes_per_texel"] == r["max_bytes_per_texel"] == 4 * (img.shape[2] - 1)
    # More channels of one family never do worse on RMS here.
    for fam in ("fourier", "avsm"):
        rms = [r["rms_error"] for r in rows if r["family"] == fam]
        assert rms == sorted(rms, reverse=True), (fam, rms)
    md = (out / "deep.md").read_text()
    assert "| avsm:8 |" in md and "Smallest on average" in md
    svg = (out / "deep_error_vs_bytes.svg").read_text()
    assert "lokovic-veach" in svg and "avsm" in svg and "RMS error" in svg


@pytest.mark.parametrize("kind", ["cube", "latlong"])
def test_omni_maps_hold_their_error_along_every_texel(cli, tmp_path, kind):
    """A light inside the cloud: a cube or latlong fixed-size map looked up along every texel's
    direction (as OpenEXR's ImfEnvmap places texels) at 12 depths, within the header's bound
    of the exact T of the segment from the light."""
    from test_omni import _texel_dirs

    out = tmp_path / "omni.exr"
    cli("bake", DATA / "cloud.vdb", "--light-pos", "0,1.5,0", "--omni", kind, "--res", "12",
        "--density-scale", "4", "--deep-format", "avsm:8", "-o", out, "--quiet")
    img, header = oiio_read(out)
    h, w = img.shape[:2]
    axes = np.stack([np.asarray(header[f"umbra:omni_{a}"], dtype=np.float64) for a in "xyz"])
    dirs = _texel_dirs(kind, w, h).reshape(-1, 3) @ axes
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    near, far = float(header["umbra:deep_near"]), float(header["umbra:deep_far"])
    depths = near + (far - near) * (np.arange(12) + 0.5) / 12
    light = np.asarray(header["umbra:camera_origin"], dtype=np.float64)
    pts = (light + dirs[:, None, :] * depths[None, :, None]).reshape(-1, 3)
    got = umbra.deep_lookup(img, header, pts)
    vol = umbra.Volume(str(DATA / "cloud.vdb"), density_scale=4)
    exact = vol.transmittance(np.broadcast_to(light, pts.shape), pts)
    bound = float(header["umbra:deep_max_error"])
    assert np.abs(got - exact).max() <= bound + 1e-6, (np.abs(got - exact).max(), bound)
    assert np.abs(got - exact).max() > 0
