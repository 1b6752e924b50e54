"""umbra.run_job: the library's batch runner from Python, held to `umbra batch` byte for byte."""

import json
import pathlib

import pytest

import umbra

from conftest import DATA


def _job(dir, out, inputs=None, grid="density"):
    inputs = inputs or [DATA / "cloud.vdb", DATA / "cloud_half.vdb"]
    text = f'grid = "{grid}"\noutput = "{out}/shadow_{{light}}.{{stem}}.exr"\n'
    for f in inputs:
        text += f"[[inputs]]\nfile = {json.dumps(str(f))}\n"
    text += '[[lights]]\nname = "sun"\ndir = [0.3, -1.0, 0.2]\n'
    text += '[[lights]]\nname = "lamp"\npos = [0.0, 4.0, 3.0]\n'
    text += "[bake]\nres = [48, 40]\ndensity_scale = 2.0\n"
    path = dir / f"{out}.toml"
    path.write_text(text)
    return path


def test_run_job_bakes_what_the_cli_bakes(tmp_path, cli):
    cli("batch", _job(tmp_path, "cli"), "-q")
    calls = []
    report = umbra.run_job(_job(tmp_path, "py"), progress=lambda d, t: calls.append((d, t)))
    assert (report["selected"], report["baked"], report["skipped"], report["failed"]) == (4, 4, 0, 0)
    assert [r["status"] for r in report["records"]] == ["ok"] * 4
    for r in report["records"]:
        out = pathlib.Path(r["output"])
        assert out.parent == tmp_path / "py"
        twin = tmp_path / "cli" / out.name
        assert out.read_bytes() == twin.read_bytes(), out.name
    # Progress counts pixels of 48 x 40 maps, from 0 to the whole.
    assert calls[0] == (0, 4 * 48 * 40) and calls[-1] == (4 * 48 * 40, 4 * 48 * 40)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))
    # The log holds the records, as the CLI's does.
    lines = [json.loads(l) for l in (tmp_path / "py" / "umbra_batch.jsonl").read_text().splitlines()]
    assert sorted(l["task"] for l in lines) == [0, 1, 2, 3]
    # Again: everything is up to date; one task with force re-bakes it.
    again = umbra.run_job(_job(tmp_path, "py"))
    assert (again["skipped"], again["baked"]) == (4, 0)
    one = umbra.run_job(_job(tmp_path, "py"), task=2, force=True)
    assert (one["selected"], one["baked"]) == (1, 1) and one["records"][0]["task"] == 2
    shard = umbra.run_job(_job(tmp_path, "py"), shard=(2, 2), force=True, jobs=1)
    assert [r["task"] for r in shard["records"]] == [1, 3]


def test_run_job_errors(tmp_path):
    job = _job(tmp_path, "o")
    with pytest.raises(umbra.InvalidArgument, match="'task'"):
        umbra.run_job(job, task=9)
    with pytest.raises(umbra.InvalidArgument, match="'shard'"):
        umbra.run_job(job, shard=(3, 2))
    with pytest.raises(umbra.InvalidArgument, match="'log'"):
        umbra.run_job(job, log=tmp_path / "no" / "dir" / "log.jsonl")
    with pytest.raises(umbra.InvalidArgument, match="progress"):
        umbra.run_job(job, progress=3)  # type: ignore[arg-type]
    # A missing input refuses the job before anything is created.
    bad = _job(tmp_path, "missing", inputs=[tmp_path / "nope.vdb"])
    with pytest.raises(umbra.FileError):
        umbra.run_job(bad)
    assert not (tmp_path / "missing").exists()
    # A bad asset fails its own tasks only: recorded with their error, not raised.
    (tmp_path / "broken.vdb").write_bytes(b"not a vdb")
    broken = _job(tmp_path, "broken", inputs=[DATA / "cloud.vdb", tmp_path / "broken.vdb"])
    report = umbra.run_job(broken)
    assert (report["baked"], report["failed"]) == (2, 2)
    failed = [r for r in report["records"] if r["status"] == "failed"]
    assert [r["task"] for r in failed] == [2, 3]
    assert all("broken.vdb" in r["error"] for r in failed)


def test_run_job_rebakes_what_an_edit_changes_and_says_why(tmp_path):
    """The task key from Python: an edited setting re-bakes every task naming the key, a light
    only its own, an output without a key is stale unless keep_unkeyed; job_status lists stale
    tasks apart from missing ones."""
    job = _job(tmp_path, "k", inputs=[DATA / "cloud.vdb"])
    first = umbra.run_job(job)
    assert [r["reason"] for r in first["records"]] == ["output missing"] * 2
    assert [r["reason"] for r in umbra.run_job(job)["records"]] == ["up to date"] * 2
    job.write_text(job.read_text().replace("density_scale = 2.0", "density_scale = 3.0"))
    report = umbra.run_job(job)
    assert report["baked"] == 2
    assert all(r["reason"] == "settings changed: bake.density_scale" for r in report["records"])
    job.write_text(job.read_text().replace("dir = [0.3, -1.0, 0.2]", "dir = [1.0, -1.0, 0.0]"))
    report = umbra.run_job(job)
    baked = [(r["light"], r["reason"]) for r in report["records"] if r["status"] == "ok"]
    # A sun's new direction also moves the camera that frames its map.
    assert [light for light, _ in baked] == ["sun"]
    assert baked[0][1].startswith("light sun changed"), baked
    # An output written over: stale (unreadable), not missing.
    sun = tmp_path / "k" / "shadow_sun.cloud.exr"
    sun.write_bytes(b"not an exr")
    status = umbra.job_status(job)
    assert [t["task"] for t in status["stale"]] == [0] and status["missing"] == []
    assert "output unreadable" in status["stale"][0]["reason"]
    assert umbra.run_job(job)["baked"] == 1
    assert umbra.job_status(job, keep_unkeyed=True, verify=True)["stale"] == []
