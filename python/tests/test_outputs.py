"""Transmittance volumes: Volume.write_transmittance_volume against `umbra bake ... -o OUT.vdb`
(the file, byte for byte), and Volume.transmittance_volume's arrays against the CLI's counts
and against transmittance_to_light at each voxel centre."""

import json

import numpy as np
import pytest

import umbra
from conftest import DATA, REPO, cli_error

CLOUD = "data/cloud.vdb"  # as the CLI is given it (the file records the source path as given)
XFORM = [0.5, 0, 0, 1.25, 0, 0.5, 0, -0.5, 0, 0, 0.5, 2.0, 0, 0, 0, 1]

CASES = [
    # (Volume kwargs, CLI load flags, call kwargs, CLI flags)
    ({}, [], dict(light_dir=(0, -1, 0)), ["--light-dir=0,-1,0"]),
    ({}, [], dict(light_dir=(0.3, -1, 0.2)), ["--light-dir=0.3,-1,0.2"]),
    ({}, [], dict(light_pos=(3, 6, 1)), ["--light-pos", "3,6,1"]),
    ({}, [], dict(light_dir=(-1, -1, 0), half=True), ["--light-dir=-1,-1,0", "--half"]),
    ({}, [], dict(light_dir=(1, 0, 0), grid="shadow"), ["--light-dir=1,0,0", "--out-grid", "shadow"]),
    (dict(density_scale=2.5, xform=XFORM), ["--density-scale", "2.5", "--xform", ",".join(map(str, XFORM))],
     dict(light_dir=(0, -1, 0)), ["--light-dir=0,-1,0"]),
    (dict(density_scale=0.5, xform=XFORM, interp="nearest"),
     ["--density-scale", "0.5", "--xform", ",".join(map(str, XFORM)), "--interp", "nearest"],
     dict(light_pos=(2, 4, 3)), ["--light-pos", "2,4,3"]),
    ({}, [], dict(light_pos=(3, 6, 1), estimator="ratio", samples=4, seed=3),
     ["--light-pos", "3,6,1", "--estimator", "ratio", "--seed", "3"]),
]


@pytest.mark.parametrize("vol_kw,load_flags,kw,flags", CASES)
def test_write_equals_cli_vdb(cli, tmp_path, vol_kw, load_flags, kw, flags):
    out = tmp_path / "cli.vdb"
    samples = str(kw.get("samples", 64))
    _, stdout, _ = cli("bake", CLOUD, "--grid", "density", *load_flags, *flags, "--samples", samples,
                       "-o", out, "--json", "--quiet")
    report = json.loads(stdout)
    vol = umbra.Volume(CLOUD, **vol_kw)
    stats = vol.write_transmittance_volume(tmp_path / "py.vdb", **kw)
    assert (tmp_path / "py.vdb").read_bytes() == out.read_bytes()
    for k in ("voxels", "leaves", "tile_leaves", "sharing", "line_step", "rays", "lookups"):
        assert stats[k] == report[k], k
    # One key for one figure in every front end: T_min, T_max, T_mean as `--json` says them.
    for k in ("T_min", "T_max", "T_mean"):
        assert stats[k] == report[k], k
    assert stats["ns_per_voxel"] > 0 and stats["seconds"] >= 0
    # In memory: the same voxels and stats.
    call = {k: v for k, v in kw.items() if k not in ("half", "grid")}
    ijk, t, st = vol.transmittance_volume(**call)
    assert ijk.dtype == np.int32 and ijk.shape == (st["voxels"], 3)
    assert t.dtype == np.float32 and t.shape == (st["voxels"],)
    assert st["voxels"] == report["voxels"]
    assert float(t.min()) == report["T_min"] and float(t.max()) == report["T_max"]


@pytest.mark.parametrize("light,sharing", [
    (dict(light_dir=(0, -1, 0)), "lines"),          # an axis
    (dict(light_dir=(0.3, -1, 0.2)), "lines"),      # the lattice step (3, -10, 2)
    (dict(light_dir=(-1, -0.7, 0.4)), "lines"),     # (-10, -7, 4)
    (dict(light_dir=(-1, -0.73, 0.41)), "rays"),    # off the lattice
    (dict(light_pos=(3, 6, 1)), "rays"),
])
def test_values_are_transmittance_to_light(cli, tmp_path, light, sharing):
    vol = umbra.Volume(CLOUD)
    ijk, t, stats = vol.transmittance_volume(**light)
    assert len(ijk) == stats["voxels"] == vol.active_voxels
    flags = (["--light-dir=" + ",".join(map(str, light["light_dir"]))] if "light_dir" in light
             else ["--light-pos", ",".join(map(str, light["light_pos"]))])
    _, stdout, _ = cli("bake", CLOUD, *flags, "-o", tmp_path / "t.vdb", "--json", "--quiet")
    assert json.loads(stdout)["voxels"] == len(ijk)
    # One row per voxel, in output order: leaves by origin, voxels by offset.
    assert len(np.unique(ijk, axis=0)) == len(ijk)
    leaf = ijk & ~7
    key = (leaf[:, 0].astype(np.int64), leaf[:, 1], leaf[:, 2], (ijk & 7) @ np.array([64, 8, 1]))
    assert (np.lexsort(key[::-1]) == np.arange(len(ijk))).all()
    assert ((t >= 0) & (t <= 1)).all() and t.min() < 0.5
    assert stats["sharing"] == sharing
    m = vol.world_from_index
    world = ijk.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    ref = vol.transmittance_to_light(world, **light)
    assert np.abs(t.astype(np.float64) - ref).max() <= 1e-6


def test_xform_and_scale_move_the_voxels(tmp_path):
    plain = umbra.Volume(CLOUD)
    moved = umbra.Volume(CLOUD, density_scale=3.0, xform=XFORM)  # paths half as long
    ijk0, t0, _ = plain.transmittance_volume(light_dir=(0, -1, 0))
    ijk1, t1, _ = moved.transmittance_volume(light_dir=(0, -1, 0))
    assert np.array_equal(ijk0, ijk1) and (t1 <= t0).all() and (t1 < t0).any()
    m = moved.world_from_index
    world = ijk1.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    ref = moved.transmittance_to_light(world, light_dir=(0, -1, 0))
    assert np.abs(t1 - ref).max() <= 1e-6


def test_refusals(cli, tmp_path):
    vol = umbra.Volume(CLOUD)
    with pytest.raises(umbra.InvalidArgument, match="not both"):
        vol.transmittance_volume(light_dir=(0, -1, 0), light_pos=(0, 5, 0))
    with pytest.raises(umbra.InvalidArgument, match="'light_dir': no light"):
        vol.transmittance_volume()
    with pytest.raises(umbra.InvalidArgument, match="not both"):
        vol.write_transmittance_volume(tmp_path / "x.vdb", light_dir=(0, -1, 0), light_pos=(0, 5, 0))
    with pytest.raises(umbra.InvalidArgument, match="light_dir"):
        vol.write_transmittance_volume(tmp_path / "x.vdb")
    with pytest.raises(umbra.InvalidArgument, match="light_dir.*no length"):
        vol.transmittance_volume(light_dir=(0, 0, 0))
    with pytest.raises(umbra.InvalidArgument, match="'out_grid'"):
        vol.write_transmittance_volume(tmp_path / "x.vdb", light_dir=(0, -1, 0), grid="")
    with pytest.raises(umbra.InvalidArgument, match="grid"):
        vol.write_transmittance_volume(tmp_path / "x.vdb", light_dir=(0, -1, 0), grid=3)  # type: ignore[arg-type]
    with pytest.raises(umbra.InvalidArgument, match="vdb"):
        vol.write_transmittance_volume(tmp_path / "x.exr", light_dir=(0, -1, 0))
    with pytest.raises(umbra.InvalidArgument, match="samples"):
        vol.transmittance_volume(light_dir=(0, -1, 0), estimator="ratio", samples=0)
    with pytest.raises(umbra.InvalidArgument, match="nope"):
        vol.transmittance_volume(light_dir=(0, -1, 0), estimator="nope")
    assert not (tmp_path / "x.vdb").exists() and not (tmp_path / "x.exr").exists()
    # An existing file: the CLI's message, the file untouched; overwrite replaces it.
    p = tmp_path / "t.vdb"
    p.write_bytes(b"keep")
    with pytest.raises(umbra.FileError) as e:
        vol.write_transmittance_volume(p, light_dir=(0, -1, 0))
    assert isinstance(e.value, OSError) and p.read_bytes() == b"keep"
    code, _, stderr = cli("bake", CLOUD, "--light-dir=0,-1,0", "-o", p, "--quiet", check=False)
    assert code != 0 and str(e.value) == cli_error(stderr)
    vol.write_transmittance_volume(p, light_dir=(0, -1, 0), overwrite=True)
    assert p.read_bytes()[:4] != b"keep"
    # The density it is made from is never replaced.
    with pytest.raises(umbra.InvalidArgument, match="replace the density"):
        umbra.Volume(p, grid="transmittance").write_transmittance_volume(
            p, light_dir=(0, -1, 0), overwrite=True)


def test_scene_is_refused(tmp_path):
    scene = tmp_path / "one.toml"
    scene.write_text(f'[[volume]]\nfile = "{DATA / "cloud.vdb"}"\ngrid = "density"\n')
    shot = REPO / "examples" / "scene" / "shot.toml"
    vols = [umbra.Volume.from_scene(scene)]
    try:
        vols.append(umbra.Volume.from_scene(shot))
    except umbra.FileError:
        pass  # the shot's level set lives in the corpus
    for vol in vols:
        with pytest.raises(umbra.InvalidArgument, match="one density grid.*scene file"):
            vol.transmittance_volume(light_dir=(0, -1, 0))
        with pytest.raises(umbra.InvalidArgument, match="one density grid.*scene file"):
            vol.write_transmittance_volume(tmp_path / "x.vdb", light_dir=(0, -1, 0))
    assert not (tmp_path / "x.vdb").exists()


def test_bad_voxels_warn_as_the_cli(cli, corpus, tmp_path):
    src = corpus / "gen" / "extreme_negative.vdb"
    out = tmp_path / "cli.vdb"
    _, _, stderr = cli("bake", src, "--light-dir=0,-1,0", "-o", out, "--quiet")
    # The CLI's `umbra: warning: X` lines are `umbra: X` RuntimeWarnings.
    lines = ["umbra: " + l[len("umbra: warning: "):] for l in stderr.splitlines()
             if l.startswith("umbra: warning: ")]
    assert lines
    with pytest.warns(RuntimeWarning):
        vol = umbra.Volume(src)
    with pytest.warns(RuntimeWarning) as rec:
        vol.write_transmittance_volume(tmp_path / "py.vdb", light_dir=(0, -1, 0))
    assert [str(w.message) for w in rec] == lines
    assert (tmp_path / "py.vdb").read_bytes() == out.read_bytes()
    with pytest.warns(RuntimeWarning) as rec:
        vol.transmittance_volume(light_dir=(0, -1, 0))
    assert [str(w.message) for w in rec] == lines
