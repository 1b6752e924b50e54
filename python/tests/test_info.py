"""umbra.info and umbra.estimators are what `umbra info --json` and `umbra estimators --json`
print."""

import json

import pytest

import umbra
from conftest import DATA


@pytest.mark.parametrize(
    "name", ["gen/multigrid_smoke.vdb", "real/blender_smoke_fluid_data_0050.vdb", "gen/tiles_mixed.vdb",
             "real/houdini20_no_grids.vdb", "gen/extreme_nan_inf.vdb"]
)
def test_info_equals_cli(cli, corpus, name):
    path = corpus / name
    _, out, _ = cli("info", path, "--json", check=False)
    assert umbra.info(path) == json.loads(out)["grids"]


def test_info_one_grid(cli, corpus):
    path = corpus / "gen/multigrid_smoke.vdb"
    grids = umbra.info(path, grid="temperature")
    assert [g["name"] for g in grids] == ["temperature"]
    _, out, _ = cli("info", path, "--json", "--grid", "temperature")
    assert grids == json.loads(out)["grids"]
    assert grids[0]["active_voxels"] > 0


def test_info_takes_path_objects():
    assert umbra.info(DATA / "cloud.vdb") == umbra.info(str(DATA / "cloud.vdb"))


def test_estimators_equal_cli(cli):
    _, out, _ = cli("estimators", "--json")
    reg = umbra.estimators()
    assert reg == json.loads(out)
    names = [e["name"] for e in reg]
    assert names[0] == "regular" and "ratio" in names and "jackknife" in names
    assert {e["kind"] for e in reg} >= {"exact", "unbiased", "biased"}
