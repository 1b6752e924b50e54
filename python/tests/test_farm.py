"""Farm specs emitted by `umbra batch --emit`, run by the engines' own tools: an Open Job
Description template checked and run to completion by `openjd` (openjd-cli, the reference
implementation AWS Deadline Cloud's workers follow), its maps equal to a local run's byte for
byte, a corrupt frame's tasks failing with their error, and `--status` naming them."""

import json
import pathlib
import shutil
import subprocess
import sys

import pytest

from conftest import DATA

OPENJD = pathlib.Path(sys.executable).with_name("openjd")
pytestmark = pytest.mark.skipif(not OPENJD.exists(), reason="openjd-cli (pip install openjd-cli)")

JOB = """output = "out/shadow_{light}.{frame:04}.exr"
[[inputs]]
pattern = "cloud.$F4.vdb"
frames = [1, 3]
[[lights]]
name = "sun"
dir = [0.3, -1.0, 0.2]
[[lights]]
name = "lamp"
pos = [0.0, 4.0, 3.0]
[bake]
res = 32
estimator = "ratio"
spp = 4
seed = 7
threads = 1
"""


def _job(dir, corrupt=None):
    dir.mkdir(parents=True)
    for f in (1, 2, 3):
        shutil.copy(DATA / "cloud.vdb", dir / f"cloud.{f:04d}.vdb")
    if corrupt:
        p = dir / f"cloud.{corrupt:04d}.vdb"
        p.write_bytes(p.read_bytes()[:50_000])
    (dir / "job.toml").write_text(JOB)
    return dir / "job.toml"


def _maps(dir):
    return {p.name: p.read_bytes() for p in sorted((dir / "out").glob("*.exr"))}


def test_an_openjd_template_runs_the_job_as_a_local_run_does(cli, tmp_path):
    # A directory name with a space and a quote, and non-ASCII: the template quotes nothing
    # by hand, the engine passes arguments as they are.
    farm = _job(tmp_path / "it's a shot é", corrupt=2)
    template = farm.parent / "job.yaml"
    cli("batch", farm, "--emit", "openjd", "-o", template)
    t = json.loads(template.read_text())
    assert t["specificationVersion"] == "jobtemplate-2023-09"
    assert [p["default"] for p in t["parameterDefinitions"]] == ["job.toml", "."]
    [step] = t["steps"]
    assert step["parameterSpace"]["taskParameterDefinitions"][0]["range"] == "0-5"
    assert step["hostRequirements"]["amounts"][0]["min"] == 1
    assert pathlib.Path(step["script"]["actions"]["onRun"]["command"]).is_absolute()
    check = subprocess.run([str(OPENJD), "check", str(template)], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    run = subprocess.run([str(OPENJD), "run", str(template), "--step", "bake"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=600)
    # The corrupt frame's two tasks fail; openjd stops the session at the first failure, so
    # run the remaining tasks one by one as a farm would schedule them.
    for i in range(6):
        subprocess.run([str(OPENJD), "run", str(template), "--step", "bake",
                        "--task-param", f"Task={i}"], capture_output=True, text=True,
                       cwd=tmp_path, timeout=600)
    by_engine = _maps(farm.parent)
    assert len(by_engine) == 4, run.stdout
    code, out, _ = cli("batch", farm, "--status", "--json", check=False)
    assert code == 3
    s = json.loads(out)
    assert len(s["done"]) == 4 and len(s["missing"]) == 0
    assert sorted(f["task"] for f in s["failed"]) == [2, 3]
    for f in s["failed"]:
        assert f["input"].endswith("cloud.0002.vdb") and f["error"], f
    # The same job run locally in one go writes the same bytes (the maps name their input
    # file, so the run happens in the same place).
    code, _, _ = cli("batch", farm, "--force", "--quiet", check=False)
    assert code == 3 and _maps(farm.parent) == by_engine
    # Mended, the failed tasks re-run through the engine; then the job is complete.
    shutil.copy(DATA / "cloud.vdb", farm.parent / "cloud.0002.vdb")
    for i in (2, 3):
        r = subprocess.run([str(OPENJD), "run", str(template), "--step", "bake",
                            "--task-param", f"Task={i}"], capture_output=True, text=True,
                           cwd=tmp_path, timeout=600)
        assert r.returncode == 0, r.stdout + r.stderr
    code, _, _ = cli("batch", farm, "--status", check=False)
    assert code == 0


def test_chunks_and_slurm_scripts(cli, tmp_path):
    job = _job(tmp_path / "shot")
    _, out, _ = cli("batch", job, "--emit", "openjd", "--chunk", "4")
    [step] = json.loads(out)["steps"]
    assert step["parameterSpace"]["taskParameterDefinitions"][0] == {
        "name": "Shard", "type": "INT", "range": "1-2"}
    assert "{{Task.Param.Shard}}/2" in step["script"]["actions"]["onRun"]["args"]
    _, out, _ = cli("batch", job, "--emit", "slurm")
    assert "#SBATCH --array=0-5\n" in out and '--task "$SLURM_ARRAY_TASK_ID"' in out
    assert "#SBATCH --cpus-per-task=1\n" in out
    # Each array element, run as Slurm would (the index in the environment), bakes its task.
    script = tmp_path / "job.sbatch"
    script.write_text(out)
    import os
    for i in range(6):
        env = dict(os.environ, SLURM_ARRAY_TASK_ID=str(i))
        subprocess.run(["bash", str(script)], env=env, check=True, capture_output=True)
    code, _, _ = cli("batch", job, "--status", check=False)
    assert code == 0
    # A template that would have to climb to its job file is refused.
    (tmp_path / "shot" / "farm").mkdir()
    code, _, err = cli("batch", job, "--emit", "openjd", "-o",
                       tmp_path / "shot" / "farm" / "job.yaml", check=False)
    assert code == 1 and "'--output'" in err, err


def test_python_emits_and_reports_as_the_cli_does(cli, umbra_bin, tmp_path):
    import umbra
    job = _job(tmp_path / "shot", corrupt=3)
    for engine in ("openjd", "slurm"):
        _, out, _ = cli("batch", job, "--emit", engine, "--chunk", "2")
        got = umbra.emit_job(job, engine, umbra=pathlib.Path(umbra_bin).resolve(), chunk=2)
        assert got == out, engine
    with pytest.raises(umbra.InvalidArgument, match="engine"):
        umbra.emit_job(job, "tractor", umbra=umbra_bin)
    cli("batch", job, "--quiet", check=False)
    _, out, _ = cli("batch", job, "--status", "--json", check=False)
    assert umbra.job_status(job) == json.loads(out)
    assert [t["task"] for t in umbra.job_status(job)["failed"]] == [4, 5]
