"""Volume.transmittance / optical_depth / transmittance_to_light against `umbra query`, bit for
bit: the same rays, ray ids, estimators and seeds give the same float64."""

import numpy as np
import pytest

import umbra
from conftest import DATA, json_lines

# (file under the corpus, grid)
FILES = [
    ("gen/cloud_fbm.vdb", "density"),
    ("gen/puff_blosc.vdb", "density"),
    ("gen/xform_affine_rotated.vdb", "density"),
    ("gen/tiles_mixed.vdb", "density"),
    ("gen/fog_nonzero_background.vdb", "density"),
    ("real/openvdb_smoke1_houdini_v222.vdb", "density"),
]


def segments(vol: umbra.Volume, n: int, seed: int):
    """n segments between random points of the volume's world box grown by 20%, some of them
    inside, some crossing, some outside."""
    lo, hi = vol.world_bbox
    pad = 0.2 * (hi - lo)
    rng = np.random.default_rng(seed)
    a = rng.uniform(lo - pad, hi + pad, (n, 3))
    b = rng.uniform(lo - pad, hi + pad, (n, 3))
    b[0] = a[0]  # a zero-length segment: T = 1
    return a, b


def write_rays(path, a, b):
    with open(path, "w") as f:
        f.write("ox,oy,oz,ex,ey,ez\n")
        for p, q in zip(a, b):
            f.write(",".join(repr(float(v)) for v in (*p, *q)) + "\n")


def cli_rows(cli, file, grid, rays, *flags):
    _, out, _ = cli("query", file, "--grid", grid, "--rays", rays, "--json", *flags)
    rows = json_lines(out)
    return (
        np.array([r["T"] for r in rows]),
        np.array([r["std_err"] for r in rows]),
        [r["tau"] for r in rows],
    )


@pytest.mark.parametrize("name,grid", FILES)
def test_regular_equals_query_rays(corpus, cli, tmp_path, name, grid):
    path = corpus / name
    vol = umbra.Volume(path, grid=grid)
    a, b = segments(vol, 300, 1)
    write_rays(tmp_path / "rays.csv", a, b)
    t_cli, e_cli, tau_cli = cli_rows(cli, path, grid, tmp_path / "rays.csv")
    t, e = vol.transmittance(a, b, return_stderr=True)
    assert t.dtype == np.float64 and t.shape == (300,)
    assert np.array_equal(t, t_cli), np.abs(t - t_cli).max()
    assert np.array_equal(e, e_cli)
    tau = vol.optical_depth(a, b)
    assert np.array_equal(tau, np.array(tau_cli, dtype=np.float64))
    assert t[0] == 1.0 and tau[0] == 0.0
    # Something was in the way: the test is not all ones.
    assert (t < 0.999).sum() > 10


@pytest.mark.parametrize(
    "estimator,flags,kw",
    [
        ("ratio", ["--samples", "16", "--seed", "7"], dict(samples=16, seed=7)),
        ("track-length", ["--samples", "8", "--seed", "3"], dict(samples=8, seed=3)),
        ("riemann", ["--step", "0.5"], dict(step=0.5)),
        ("jittered", ["--samples", "4", "--seed", "11", "--step", "2"], dict(samples=4, seed=11, step=2.0)),
        ("residual-ratio", ["--samples", "4", "--seed", "1", "--ray-id", "1000"], dict(samples=4, seed=1, ray_id=1000)),
        ("jackknife", ["--samples", "4", "--seed", "2", "--points", "6"], dict(samples=4, seed=2, points=6)),
        ("ratio", ["--samples", "8", "--seed", "5", "--granularity", "upper"], dict(samples=8, seed=5, granularity="upper")),
        ("track-length", ["--samples", "8", "--global-majorant"], dict(samples=8, global_majorant=True)),
    ],
)
def test_estimators_equal_query_rays(corpus, cli, tmp_path, estimator, flags, kw):
    path = corpus / "gen/cloud_fbm.vdb"
    vol = umbra.Volume(path)
    a, b = segments(vol, 200, 2)
    write_rays(tmp_path / "rays.csv", a, b)
    t_cli, e_cli, _ = cli_rows(cli, path, "density", tmp_path / "rays.csv", "--estimator", estimator, *flags)
    jk = kw.pop("points", None)
    t, e = vol.transmittance(a, b, estimator=estimator, return_stderr=True, points=jk, **kw)
    assert np.array_equal(t, t_cli)
    assert np.array_equal(e, e_cli)


def test_seed_and_ray_id_change_the_answer(corpus):
    vol = umbra.Volume(corpus / "gen/cloud_fbm.vdb")
    a, b = segments(vol, 50, 3)
    t0 = vol.transmittance(a, b, estimator="ratio", samples=4, seed=0)
    assert np.array_equal(t0, vol.transmittance(a, b, estimator="ratio", samples=4, seed=0))
    assert not np.array_equal(t0, vol.transmittance(a, b, estimator="ratio", samples=4, seed=1))
    # Row n is ray id ray_id + n: shifting the rows by one and the ray id by one gives the same.
    t1 = vol.transmittance(a[1:], b[1:], estimator="ratio", samples=4, seed=0, ray_id=1)
    assert np.array_equal(t0[1:], t1)


def test_thread_count_does_not_change_results(corpus):
    vol = umbra.Volume(corpus / "gen/cloud_fbm.vdb")
    a, b = segments(vol, 2000, 4)
    one = vol.transmittance(a, b, estimator="ratio", samples=4, threads=1)
    two = vol.transmittance(a, b, estimator="ratio", samples=4, threads=2)
    assert np.array_equal(one, two)


def test_nearest_density_scale_and_xform_equal_query(corpus, cli, tmp_path):
    path = corpus / "gen/puff_zip.vdb"
    m = np.array([[0.0, -2.0, 0.0, 1.5], [2.0, 0.0, 0.0, -0.25], [0.0, 0.0, 2.0, 3.0], [0, 0, 0, 1]])
    vol = umbra.Volume(path, density_scale=2.5, interp="nearest", xform=m)
    a, b = segments(vol, 200, 5)
    write_rays(tmp_path / "rays.csv", a, b)
    flags = ["--density-scale", "2.5", "--interp", "nearest", "--xform", ",".join(repr(float(v)) for v in m.reshape(16))]
    t_cli, _, _ = cli_rows(cli, path, "density", tmp_path / "rays.csv", *flags)
    assert np.array_equal(vol.transmittance(a, b), t_cli)
    # The placed volume's index-to-world map is the xform after the file's own.
    plain = umbra.Volume(path)
    assert np.allclose(vol.world_from_index, m @ plain.world_from_index, rtol=0, atol=1e-12)
    assert np.allclose(vol.voxel_size, 2 * plain.voxel_size)


@pytest.mark.parametrize("light", [("--light-dir", (-1.0, -1.0, 0.0)), ("--light-pos", (3.0, 6.0, 1.0))])
def test_transmittance_to_light_equals_query_at(cli, light):
    path = DATA / "cloud.vdb"
    vol = umbra.Volume(path)
    pts = np.array([[0.0, 1.5, 0.0], [0.3, 1.0, -0.2], [-1.0, 2.0, 0.5], [5.0, 5.0, 5.0]])
    flag, v = light
    kw = {"light_dir": v} if flag == "--light-dir" else {"light_pos": v}
    t = vol.transmittance_to_light(pts, estimator="ratio", samples=8, seed=5, **kw)
    exact = vol.transmittance_to_light(pts, **kw)
    for n, p in enumerate(pts):
        at = ",".join(repr(float(c)) for c in p)
        lv = ",".join(repr(float(c)) for c in v)
        _, out, _ = cli("query", path, "--at", at, f"{flag}={lv}", "--json", "--estimator", "ratio",
                        "--samples", "8", "--seed", "5", "--ray-id", n)
        assert t[n] == json_lines(out)[0]["T"]
        _, out, _ = cli("query", path, "--at", at, f"{flag}={lv}", "--json")
        assert exact[n] == json_lines(out)[0]["T"]
    assert exact[3] == 1.0 or flag == "--light-pos"
    assert exact[0] < 0.5


def test_float32_and_integer_points_are_accepted(corpus):
    vol = umbra.Volume(DATA / "cloud.vdb")
    a = np.array([[0, 1, 0], [1, 2, 0]], dtype=np.int32)
    b = np.array([[3, 4, 0], [-1, 2, 1]], dtype=np.float32)
    assert np.array_equal(vol.transmittance(a, b), vol.transmittance(a.astype(float), b.astype(np.float64)))
    # A Fortran-ordered or strided view is the same points.
    big = np.asfortranarray(np.vstack([a, a]).astype(float))
    assert np.array_equal(vol.transmittance(big[::2], b[[0, 0]]), vol.transmittance(a[[0, 0]], b[[0, 0]]))
    # No rows: empty answers.
    assert vol.transmittance(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


def test_properties_match_info(corpus):
    for name, grid in FILES:
        path = corpus / name
        vol = umbra.Volume(path, grid=grid)
        g = umbra.info(path, grid=grid)[0]
        assert vol.active_voxels == g["active_voxels"]
        assert vol.index_bbox.tolist() == g["index_bbox"]
        assert np.allclose(vol.world_bbox, np.array(g["world_bbox"]), rtol=1e-12, atol=1e-12)
        assert np.allclose(vol.world_from_index, np.array(g["world_from_index"]), rtol=0, atol=1e-12)
        assert np.allclose(vol.voxel_size, np.array(g["voxel_size"]), rtol=1e-9)
        assert vol.world_from_index.shape == (4, 4)


def test_a_nanovdb_file_answers_as_its_vdb(corpus, tmp_path):
    """A ``.nvdb`` (written by NanoVDB's own nanovdb_convert) loads through the same input layer:
    exact answers equal those of the ``.vdb`` it was made from, bit for bit, and ``info`` names
    each grid's codec, quantisation and checksum."""
    import shutil
    import subprocess
    exe = shutil.which("nanovdb_convert")
    assert exe, "needs nanovdb_convert (apt-get install libnanovdb-tools)"
    src = corpus / "gen/cloud_fbm.vdb"
    vol = umbra.Volume(src)
    a, b = segments(vol, 300, 9)
    for flags, codec in (([], "none"), (["-z"], "zip"), (["-b"], "blosc")):
        nv = tmp_path / f"cloud.{codec}.nvdb"
        subprocess.run([exe, *flags, "-g", "density", str(src), str(nv)], check=True,
                       capture_output=True)
        nano = umbra.Volume(nv)
        assert nano.active_voxels == vol.active_voxels
        assert np.array_equal(nano.transmittance(a, b), vol.transmittance(a, b))
        (meta,) = umbra.info(nv)
        assert (meta["codec"], meta["quantisation"], meta["checksum"]) == (codec.upper(), "none", "partial")
    with pytest.raises(umbra.FileError, match="not a NanoVDB file"):
        bad = tmp_path / "bad.nvdb"
        bad.write_bytes(b"not nanovdb at all, just text")
        umbra.Volume(bad)


def test_rays_missing_every_voxel_warn_as_the_cli_does():
    """Issue 58: rays that all miss every active voxel (T = 1 for each) warn, with the CLI's
    words; one ray through the cloud among them, or a light ray through it, does not."""
    import warnings
    vol = umbra.Volume(DATA / "cloud.vdb")
    far = np.array([[100.0, 100.0, 100.0], [100.0, 90.0, 0.0]])
    to = far + np.array([1.0, 0.0, 0.0])
    with pytest.warns(RuntimeWarning, match="none of the 2 queries met an active voxel") as rec:
        t = vol.transmittance(far, to)
    assert np.array_equal(t, [1.0, 1.0])
    assert "--xform" in str(rec[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        both = vol.transmittance(np.vstack([far[:1], [[-5.0, 1.5, 0.0]]]),
                                 np.vstack([to[:1], [[5.0, 1.5, 0.0]]]))
        assert both[0] == 1.0 and both[1] < 1.0
        assert vol.transmittance_to_light(np.array([[0.0, 1.5, 0.0]]),
                                          light_dir=(-1, -1, 0))[0] < 1.0
    with pytest.warns(RuntimeWarning, match="the query met no active voxel"):
        vol.transmittance_to_light(np.array([[0.0, 20.0, 0.0]]), light_dir=(0, -1, 0))
