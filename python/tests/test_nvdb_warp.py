"""NanoVDB files written by NVIDIA Warp (issue 58): ``wp.Volume.save_to_nvdb`` with every codec
it writes (none, zip, blosc) wraps NanoVDB 32.8 grids ("NanoVDB1") in a file header that says
32.3.3, with most of the file metadata left zero. The files are made here, at test time, by
Warp on the CPU: a sparse float grid (tiles far apart, negative coordinates), an anisotropic
voxel size and a translation. umbra must place the grid where ``wp.volume_index_to_world``
does and answer the values ``wp.volume_sample_f`` (CLOSEST) gives, inside the tiles, in their
inactive gaps and in the background."""

import json

import numpy as np
import pytest

import umbra
import warp as wp  # warp-lang from PyPI (python/run_tests.sh installs it, and blosc)

CODECS = ("none", "zip", "blosc")
VOXEL = (0.25, 0.5, 0.125)
TRANSLATION = (3.5, -1.25, 7.0)
# Index-space origins of the 8^3 tiles Warp allocates: far apart (several upper nodes), some
# negative, two side by side.
TILES = [(0, 0, 0), (8, 0, 0), (64, -40, 8), (-200, 16, 296), (1000, 8, -16), (-8, -8, -8)]


@wp.kernel
def _fill(volume: wp.uint64, points: wp.array(dtype=wp.vec3i), values: wp.array(dtype=float)):
    t = wp.tid()
    p = points[t]
    wp.volume_store_f(volume, p[0], p[1], p[2], values[t])


@wp.kernel
def _sample(volume: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    t = wp.tid()
    q = wp.volume_world_to_index(volume, points[t])
    out[t] = wp.volume_sample_f(volume, q, wp.Volume.CLOSEST)


@wp.kernel
def _to_world(volume: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    t = wp.tid()
    out[t] = wp.volume_index_to_world(volume, points[t])


@pytest.fixture(scope="module")
def warp_volume():
    """A sparse float volume built by Warp on the CPU, with every voxel of its tiles given a
    value except a scattered few left at the background (active, value 0)."""
    wp.config.quiet = True
    wp.init()
    rng = np.random.default_rng(58)
    tiles = wp.array(np.array(TILES, dtype=np.int32), dtype=wp.vec3i, device="cpu")
    vol = wp.Volume.allocate_by_tiles(tiles, voxel_size=VOXEL, bg_value=0.0,
                                      translation=TRANSLATION, device="cpu")
    ijk = np.array([(x + i, y + j, z + k) for (x, y, z) in TILES
                    for i in range(8) for j in range(8) for k in range(8)], dtype=np.int32)
    values = (rng.random(len(ijk)) * 3.0 + 0.05).astype(np.float32)
    values[rng.random(len(ijk)) < 0.1] = 0.0
    wp.launch(_fill, dim=len(ijk), device="cpu",
              inputs=[vol.id, wp.array(ijk, dtype=wp.vec3i, device="cpu"),
                      wp.array(values, dtype=float, device="cpu")])
    return vol, ijk


@pytest.fixture(scope="module")
def warp_files(warp_volume, tmp_path_factory):
    vol, _ = warp_volume
    d = tmp_path_factory.mktemp("warp")
    out = {}
    for codec in CODECS:
        out[codec] = d / f"warp_{codec}.nvdb"
        vol.save_to_nvdb(str(out[codec]), codec=codec)
    return out


def _warp_sample(vol, world):
    out = wp.zeros(len(world), dtype=float, device="cpu")
    wp.launch(_sample, dim=len(world), device="cpu",
              inputs=[vol.id, wp.array(world, dtype=wp.vec3, device="cpu"), out])
    return out.numpy()


def _probe_points(vol, ijk, rng):
    """World points: inside voxels of the tiles (off centre, well inside the cell), just
    outside the tiles, and far away in the background."""
    inside = ijk[rng.choice(len(ijk), 1500, replace=False)].astype(np.float64)
    inside += rng.uniform(-0.3, 0.3, inside.shape)
    near = ijk[rng.choice(len(ijk), 300, replace=False)].astype(np.float64)
    near += rng.choice([-9.0, 9.0], near.shape) + rng.uniform(-0.3, 0.3, near.shape)
    far = rng.uniform(-1500, 1500, (200, 3))
    far = np.round(far) + rng.uniform(-0.3, 0.3, far.shape)
    index = np.vstack([inside, near, far])
    out = wp.zeros(len(index), dtype=wp.vec3, device="cpu")
    wp.launch(_to_world, dim=len(index), device="cpu",
              inputs=[vol.id, wp.array(index.astype(np.float32), dtype=wp.vec3, device="cpu"), out])
    return out.numpy().astype(np.float64), index


def test_warp_files_are_what_the_issue_describes(warp_files):
    """The files are the ones issue 58 names: a 32.3.3 file header around a "NanoVDB1" grid of
    32.8, the metadata's counts zero; ZIP and BLOSC with the byte count outside the file size."""
    for codec, path in warp_files.items():
        b = path.read_bytes()
        magic, version, count, c = np.frombuffer(b[:16], dtype="<u8,<u4,<u2,<u2")[0]
        assert (magic, version >> 21, (version >> 10) & 0x7FF, version & 0x3FF) == (
            0x304244566F6E614E, 32, 3, 3)
        assert (count, c) == (1, CODECS.index(codec))
        name_size = int(np.frombuffer(b[16 + 136:16 + 140], "<u4")[0])
        blob = 16 + 176 + name_size
        node_counts = np.frombuffer(b[16 + 140:16 + 156], "<u4")
        assert not node_counts.any(), "Warp leaves the node counts zero"
        file_size = int(np.frombuffer(b[16 + 8:16 + 16], "<u8")[0])
        if codec == "none":
            assert b[blob:blob + 8] == b"NanoVDB1"
            assert len(b) == blob + file_size
        else:
            assert int(np.frombuffer(b[blob:blob + 8], "<u8")[0]) == file_size
            assert len(b) == blob + 8 + file_size


def test_umbra_places_warp_grids_where_warp_does(warp_volume, warp_files):
    vol, ijk = warp_volume
    lo, hi = ijk.min(axis=0), ijk.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])], dtype=np.float32)
    out = wp.zeros(len(corners), dtype=wp.vec3, device="cpu")
    wp.launch(_to_world, dim=len(corners), device="cpu",
              inputs=[vol.id, wp.array(corners, dtype=wp.vec3, device="cpu"), out])
    warp_world = out.numpy().astype(np.float64)
    for codec, path in warp_files.items():
        v = umbra.Volume(path, grid="[0]", interp="nearest")
        m = v.world_from_index
        ours = corners.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
        # Warp maps in f32; umbra keeps NanoVDB's f64 map.
        np.testing.assert_allclose(ours, warp_world, rtol=1e-6, atol=1e-4, err_msg=codec)
        np.testing.assert_allclose(v.voxel_size, VOXEL, rtol=1e-6, err_msg=codec)
        np.testing.assert_allclose(m[:3, 3], TRANSLATION, rtol=1e-6, err_msg=codec)
        assert v.index_bbox.tolist() == [lo.tolist(), hi.tolist()], codec
        assert v.active_voxels == len(ijk), codec


def test_umbra_answers_warps_closest_values(warp_volume, warp_files):
    """A segment 1/100 of a voxel long inside one voxel has optical depth value x length with
    nearest interpolation: umbra's value there must be what ``volume_sample_f`` CLOSEST gives."""
    vol, ijk = warp_volume
    rng = np.random.default_rng(7)
    world, index = _probe_points(vol, ijk, rng)
    want = _warp_sample(vol, world)
    assert (want > 0).sum() > 1000 and (want == 0).sum() > 300, "probes in and out of the tiles"
    step = 0.01 * np.array(VOXEL)
    for codec, path in warp_files.items():
        v = umbra.Volume(path, grid="[0]", interp="nearest")
        tau = v.optical_depth(world - step / 2, world + step / 2)
        got = tau / np.linalg.norm(step)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6, err_msg=codec)


def test_info_describes_warp_files(warp_volume, warp_files, cli):
    _, ijk = warp_volume
    for codec, path in warp_files.items():
        _, out, _ = cli("info", "--json", path)
        info = json.loads(out)
        (g,) = info["grids"]
        assert (info["grid_count"], g["name"], g["stored_name"], g["value_type"]) == (
            1, "[0]", "", "float")
        assert (g["codec"], g["checksum"], g["nanovdb_version"]) == (
            codec.upper(), "absent", "32.8.0")
        assert g["active_voxels"] == len(ijk) and g["error"] is None
        # The library's report is the CLI's.
        (meta,) = umbra.info(path)
        assert meta["checksum"] == "absent" and meta["active_voxels"] == len(ijk)
        _, text, _ = cli("info", "-v", "--grid", "[0]", path)
        assert "NanoVDB 32.8.0  codec: " + codec.upper() in text, text


def test_hostile_bytes_in_warp_files_end_in_one_error_line(warp_files, cli, tmp_path):
    """Warp's files cut short or with bytes flipped (headers byte by byte, then anywhere): every
    codec ends in exit 0, 1 or 3 and at most one ``umbra: error:`` line, never a panic."""
    rng = np.random.default_rng(11)
    for codec, path in warp_files.items():
        good = path.read_bytes()
        n = len(good)
        cases = [good[:cut] for cut in list(range(0, 260, 7)) + [n // 3, n - 9, n - 1]]
        for at in list(range(0, 16 + 176 + 1 + 8 + 760, 11)) + list(rng.integers(0, n, 60)):
            b = bytearray(good)
            b[at] ^= 0x81
            cases.append(bytes(b))
        for i, data in enumerate(cases):
            bad = tmp_path / f"bad_{codec}.nvdb"
            bad.write_bytes(data)
            code, _, err = cli("info", bad, check=False)
            assert code in (0, 1, 3), (codec, i, code, err)
            assert "panicked" not in err and len(err.splitlines()) <= 1, (codec, i, err)
            if code:
                assert err.startswith("umbra: error: ") and "bad_" in err, (codec, i, err)
