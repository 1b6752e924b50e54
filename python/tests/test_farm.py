"""Farm specs emitted by `umbra batch --emit`, run by the engines' own tools: an Open Job
Description template checked and run to completion by `openjd` (openjd-cli, the reference
implementation AWS Deadline Cloud's workers follow), its maps equal to a local run's byte for
byte, a corrupt frame's tasks failing with their error, and `--status` naming them; an
OpenCue spec equal to the one opencue-pyoutline writes for the same job, run chunk by chunk
as OpenCue's RQD runs a layer's frames; a Slurm array script submitted with a plain `sbatch`
to a one-node Slurm (Debian's slurm-wlm) the test starts."""

import json
import os
import pathlib
import shlex
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from conftest import DATA

OPENJD = pathlib.Path(sys.executable).with_name("openjd")
SLURM = [shutil.which(t) for t in ("munged", "slurmctld", "slurmd", "sbatch", "squeue")]
needs_openjd = pytest.mark.skipif(not OPENJD.exists(),
                                  reason="openjd-cli (pip install openjd-cli)")

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


@needs_openjd
def test_an_openjd_template_runs_the_job_as_a_local_run_does(cli, tmp_path):
    # A directory name with a space and a quote, and non-ASCII: the template quotes nothing
    # by hand, the engine passes arguments as they are.
    farm = _job(tmp_path / "it's a shot é", corrupt=2)
    template = farm.parent / "job.yaml"
    cli("batch", farm, "--emit", "openjd", "-o", template)
    t = json.loads(template.read_text())
    assert t["specificationVersion"] == "jobtemplate-2023-09"
    exe, job_file, out_dir = [p["default"] for p in t["parameterDefinitions"]]
    assert pathlib.Path(exe).is_absolute() and (job_file, out_dir) == ("job.toml", ".")
    [step] = t["steps"]
    assert step["parameterSpace"]["taskParameterDefinitions"][0]["range"] == "0-5"
    assert step["hostRequirements"]["amounts"][0]["min"] == 1
    assert step["script"]["actions"]["onRun"]["command"] == "{{Param.Umbra}}"
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


@needs_openjd
def test_openjd_reads_the_progress_of_every_task(cli, tmp_path):
    """Each task of an emitted template runs with `--progress openjd`; under `openjd run` its
    `openjd_progress: N` lines reach the session, whose action filter parses them (it appends
    ` -- ERROR: ...` to a line it cannot parse, and hands a parsed one to the session as the
    action's progress), rising from 0 to 100."""
    farm = _job(tmp_path / "progress")
    template = farm.parent / "job.yaml"
    cli("batch", farm, "--emit", "openjd", "--chunk", "2", "-o", template)
    [step] = json.loads(template.read_text())["steps"]
    args = step["script"]["actions"]["onRun"]["args"]
    assert args[args.index("--progress") + 1] == "openjd", args
    run = subprocess.run([str(OPENJD), "run", str(template), "--step", "bake"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    # openjd run prints the session's log, one `timestamp<TAB>message` per line.
    lines = [l.split("\t", 1)[-1] for l in run.stdout.splitlines() if "openjd_progress" in l]
    assert lines, run.stdout
    assert not any("ERROR" in l for l in lines), lines
    # Three farm tasks (shards of two job tasks each): each rises from 0 to 100.
    percents = [float(l.split(": ", 1)[1]) for l in lines]
    runs, current = [], []
    for p in percents:
        if p == 0 and current:
            runs.append(current)
            current = []
        current.append(p)
    runs.append(current)
    assert len(runs) == 3, percents
    for r in runs:
        assert r[0] == 0 and r[-1] == 100 and r == sorted(set(r)), r
    # The session's own parser takes every line as progress.
    from openjd.sessions._action_filter import ActionMessageKind, ActionMonitoringFilter
    import logging

    seen = []
    filt = ActionMonitoringFilter(session_id="s", callback=lambda kind, value, *_: seen.append(
        (kind, value)))
    for line in lines:
        record = logging.LogRecord("openjd", logging.INFO, __file__, 0, line, None, None)
        record.session_id = "s"
        filt.filter(record)
    assert seen == [(ActionMessageKind.PROGRESS, p) for p in percents]


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


def test_python_emits_and_reports_as_the_cli_does(cli, umbra_bin, tmp_path, monkeypatch):
    import umbra
    monkeypatch.setenv("USER", "td_bob")
    job = _job(tmp_path / "shot", corrupt=3)
    for engine in ("openjd", "opencue", "slurm"):
        cue = dict(shot="sh020") if engine == "opencue" else {}
        _, out, _ = cli("batch", job, "--emit", engine, "--chunk", "2",
                        *(["--shot", "sh020"] if cue else []))
        got = umbra.emit_job(job, engine, umbra=pathlib.Path(umbra_bin).resolve(), chunk=2,
                             **cue)
        assert got == out, engine
    # Show and shot are OpenCue's: elsewhere they are refused, not ignored.
    code, _, err = cli("batch", job, "--emit", "slurm", "--show", "mars", check=False)
    assert code == 1 and "'--show'" in err, err
    with pytest.raises(umbra.InvalidArgument, match="shot"):
        umbra.emit_job(job, "openjd", umbra=umbra_bin, shot="sh010")
    with pytest.raises(umbra.InvalidArgument, match="engine"):
        umbra.emit_job(job, "tractor", umbra=umbra_bin)
    cli("batch", job, "--quiet", check=False)
    _, out, _ = cli("batch", job, "--status", "--json", check=False)
    assert umbra.job_status(job) == json.loads(out)
    assert [t["task"] for t in umbra.job_status(job)["failed"]] == [4, 5]


def _cue_tree(element):
    """An XML element as nested (tag, attributes, text, children), whitespace ignored; a
    command as the argument vector a shell makes of it."""
    text = (element.text or "").strip()
    if element.tag == "cmd":
        text = shlex.split(text)
    return (element.tag, element.attrib, text, [_cue_tree(c) for c in element])


def _cuebot(command, job, layer, start, end, chunk):
    """A frame's command as cuebot hands it to RQD (DispatchSupportService: every placeholder
    replaced anywhere in the command, whatever surrounds it; the environment untouched)."""
    frame = f"{start:04d}-{layer}"
    for token, value in [("#ZFRAME#", f"{start:04d}"), ("#IFRAME#", str(start)),
                         ("#FRAME_START#", str(start)), ("#FRAME_END#", str(end)),
                         ("#FRAME_CHUNK#", str(chunk)), ("#LAYER#", layer), ("#JOB#", job),
                         ("#FRAMESPEC#", f"{start}-{end}"), ("#FRAME#", frame)]:
        command = command.replace(token, value)
    return command


def _rqd(spec_xml, cwd):
    """Run every frame of every layer as OpenCue's cuebot and RQD do: frames in chunks of
    `chunk` consecutive frames, cuebot's placeholders replaced in the command, the layer's
    environment set, the command through a shell. The exit code of each chunk, by its first
    frame."""
    codes = {}
    root = ET.fromstring(spec_xml.split("\n", 2)[2])
    job = root.find("job").get("name")
    for layer in root.iter("layer"):
        first, last = map(int, layer.find("range").text.split("-"))
        chunk = int(layer.find("chunk").text)
        env = dict(os.environ, **{k.get("name"): k.text or "" for k in layer.find("env")})
        for start in range(first, last + 1, chunk):
            end = min(start + chunk - 1, last)
            cmd = _cuebot(layer.find("cmd").text, job, layer.get("name"), start, end, chunk)
            codes[start] = subprocess.run(["/bin/sh", "-c", cmd], cwd=cwd, capture_output=True,
                                          env=env, timeout=600).returncode
    return codes


def test_an_opencue_spec_is_the_one_pyoutline_writes_and_runs_as_rqd_runs_it(
        umbra_bin, cli, tmp_path):
    pytest.importorskip("outline", reason="opencue-pyoutline (pip install opencue-pyoutline)")
    import outline
    import outline.cuerun
    import outline.modules.shell
    from outline.backend import cue

    farm = _job(tmp_path / "it's a shot é", corrupt=2)
    exe = pathlib.Path(umbra_bin).resolve()
    env = dict(os.environ, USER="td_alice", SHOW="ignored", SHOT="ignored")
    for chunk in (1, 2):
        p = subprocess.run([str(exe), "batch", str(farm), "--emit", "opencue", "--show",
                            "mars", "--shot", "sh010", "--chunk", str(chunk)], env=env,
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        ours = p.stdout
        # The same job built with pyoutline: one Shell layer over tasks 0-5 in chunks, one
        # core (the job's threads), the command a TD would write with the chunk's tokens.
        # The paths travel in the layer's environment (cuebot rewrites its placeholders
        # anywhere in the command).
        tokens = "#IFRAME#" if chunk == 1 else "#FRAME_START#-#FRAME_END#"
        command = f'"$UMBRA" batch "$UMBRA_JOB" --quiet --task {tokens}'
        ol = outline.Outline("umbra_job", show="mars", shot="sh010", user="td_alice")
        layer = outline.modules.shell.Shell("bake", command=command, range="0-5", chunk=chunk,
                                            cores=1)
        layer.set_env("UMBRA", str(exe))
        layer.set_env("UMBRA_JOB", str(farm))
        ol.add_layer(layer)
        launcher = outline.cuerun.OutlineLauncher(ol, show="mars", shot="sh010",
                                                  user="td_alice", nomail=True)
        theirs = cue.serialize_simple(launcher)
        # umbra leaves out the facility (cuebot then uses its default one; pyoutline writes
        # its config's "local") and never makes up an e-mail address.
        root = ET.fromstring(theirs.split(">", 2)[2])
        for tag in ("facility", "email"):
            for e in root.findall(tag):
                root.remove(e)
        assert ours.split("\n", 2)[:2] == [theirs[:21], theirs[21:theirs.index("<spec>")]]
        assert _cue_tree(ET.fromstring(ours.split("\n", 2)[2])) == _cue_tree(root)
    # Chunks of two: frame 2's chunk (tasks 2 and 3, the corrupt cache) fails, the others bake.
    codes = _rqd(ours, tmp_path)
    assert codes[0] == 0 and codes[4] == 0 and codes[2] != 0, codes
    code, out, _ = cli("batch", farm, "--status", "--json", check=False)
    assert code == 3
    s = json.loads(out)
    assert sorted(f["task"] for f in s["failed"]) == [2, 3] and len(s["done"]) == 4
    by_engine = _maps(farm.parent)
    code, _, _ = cli("batch", farm, "--force", "--quiet", check=False)
    assert code == 3 and _maps(farm.parent) == by_engine and len(by_engine) == 4
    # A name cuebot cannot take is refused, naming the flag; without USER the user is the
    # password database's name of this uid, as pyoutline's getpass finds it; LOGNAME, LNAME and
    # USERNAME come first, in that order.
    p = subprocess.run([str(exe), "batch", str(farm), "--emit", "opencue", "--show", "my show"],
                       capture_output=True, text=True, env=env)
    assert p.returncode == 1 and "'--show'" in p.stderr and not p.stdout, p.stderr
    import pwd
    p = subprocess.run([str(exe), "batch", str(farm), "--emit", "opencue"], capture_output=True,
                       text=True, env={k: v for k, v in env.items()
                                       if k not in ("USER", "LOGNAME", "LNAME", "USERNAME")})
    assert p.returncode == 0, p.stderr
    user = ET.fromstring(p.stdout.split("\n", 2)[2]).find("user").text
    assert user == pwd.getpwuid(os.getuid()).pw_name
    # The user is the one pyoutline's own get_user() finds, whichever variables are set.
    bare = {k: v for k, v in env.items() if k not in ("USER", "LOGNAME", "LNAME", "USERNAME")}
    for given in ({"LOGNAME": "td_l", "LNAME": "td_n"}, {"LNAME": "td_n", "USERNAME": "td_u"},
                  {"USERNAME": "td_u"}, {"USER": "td_a", "LOGNAME": "td_l"}, {}):
        e = dict(bare, **given)
        p = subprocess.run([str(exe), "batch", str(farm), "--emit", "opencue"],
                           capture_output=True, text=True, env=e)
        assert p.returncode == 0, p.stderr
        got = ET.fromstring(p.stdout.split("\n", 2)[2]).find("user").text
        want = subprocess.run([sys.executable, "-c", "import outline.util as u; print(u.get_user())"],
                              capture_output=True, text=True, env=e, check=True).stdout.strip()
        assert got == want, (given, got, want)


CUE_TOKENS = ["#ZFRAME#", "#IFRAME#", "#FRAME_START#", "#FRAME_END#", "#FRAME_CHUNK#",
              "#LAYER#", "#JOB#", "#FRAMESPEC#", "#FRAME#"]


def _hostile(tmp_path):
    """A job in a folder, and an umbra in a folder, whose names hold every OpenCue placeholder
    and OpenJD format strings; beside them the decoys an engine that expanded the names would
    run instead (a job in `shot0...`, an umbra in `bin0...`), each of which would leave a
    mark."""
    name = "shot " + " ".join(CUE_TOKENS) + " {{Task.Param.Task}} {{Param.JobFile}}"
    farm = _job(tmp_path / name)
    exe_dir = tmp_path / ("bin#IFRAME#{{Task.Param.Task}}#JOB#")
    exe_dir.mkdir()
    return farm, exe_dir


def test_farm_specs_run_the_job_they_name_whatever_its_paths_hold(umbra_bin, cli, tmp_path):
    farm, exe_dir = _hostile(tmp_path)
    exe = exe_dir / "umbra"
    shutil.copy(umbra_bin, exe)
    # Decoys: what the paths would become if an engine expanded its tokens in them.
    decoy = tmp_path / "decoy_ran"
    for d in [tmp_path / "bin0{{Task.Param.Task}}umbra_job", tmp_path / "bin0"]:
        d.mkdir(exist_ok=True)
        (d / "umbra").write_text(f"#!/bin/sh\ntouch '{decoy}'\n")
        (d / "umbra").chmod(0o755)
    # OpenCue: cuebot's substitution applied to the command, the layer's environment as is.
    for chunk in (1, 2):
        p = subprocess.run([str(exe), "batch", str(farm), "--emit", "opencue", "--chunk",
                            str(chunk), "--show", "mars", "--shot", "sh010"],
                           capture_output=True, text=True, env=dict(os.environ, USER="td"))
        assert p.returncode == 0, p.stderr
        for token in CUE_TOKENS:
            assert token not in p.stdout.split("<cmd>")[1].split("</cmd>")[0].replace(
                "#IFRAME#", "").replace("#FRAME_START#", "").replace("#FRAME_END#", "")
        codes = _rqd(p.stdout, tmp_path)
        assert set(codes.values()) == {0}, codes
        assert len(_maps(farm.parent)) == 6 and not decoy.exists()
        shutil.rmtree(farm.parent / "out")
        for log in farm.parent.glob("*.jsonl"):
            log.unlink()
    # OpenJD: `openjd check` takes the template, `openjd run` bakes this job's maps.
    if OPENJD.exists():
        template = farm.parent / "job.json"
        p = subprocess.run([str(exe), "batch", str(farm), "--emit", "openjd", "-o",
                            str(template)], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        check = subprocess.run([str(OPENJD), "check", str(template)], capture_output=True,
                               text=True)
        assert check.returncode == 0, check.stdout + check.stderr
        run = subprocess.run([str(OPENJD), "run", str(template), "--step", "bake"],
                             capture_output=True, text=True, cwd=tmp_path, timeout=600)
        assert run.returncode == 0, run.stdout + run.stderr
        assert len(_maps(farm.parent)) == 6 and not decoy.exists()
    # Slurm: each array element as Slurm runs it (bash, the index in the environment).
    shutil.rmtree(farm.parent / "out")
    p = subprocess.run([str(exe), "batch", str(farm), "--emit", "slurm"], capture_output=True,
                       text=True)
    assert p.returncode == 0, p.stderr
    script = tmp_path / "job.sbatch"
    script.write_text(p.stdout)
    for i in range(6):
        env = dict(os.environ, SLURM_ARRAY_TASK_ID=str(i))
        subprocess.run(["bash", str(script)], env=env, check=True, capture_output=True,
                       cwd=tmp_path)
    assert len(_maps(farm.parent)) == 6 and not decoy.exists()
    # A job file whose own name holds the tokens.
    named = farm.parent / "job{{Task.Param.Task}}#IFRAME#.toml"
    shutil.copy(farm, named)
    shutil.rmtree(farm.parent / "out")
    p = subprocess.run([str(exe), "batch", str(named), "--emit", "opencue"],
                       capture_output=True, text=True, env=dict(os.environ, USER="td"))
    assert p.returncode == 0, p.stderr
    assert set(_rqd(p.stdout, tmp_path).values()) == {0}
    assert len(_maps(farm.parent)) == 6 and not decoy.exists()
    if OPENJD.exists():
        template = farm.parent / "named.json"
        cli("batch", named, "--emit", "openjd", "-o", template)
        check = subprocess.run([str(OPENJD), "check", str(template)], capture_output=True,
                               text=True)
        assert check.returncode == 0, check.stdout + check.stderr


@pytest.fixture
def slurm(tmp_path_factory):
    """A one-node Slurm cluster of this machine (munged, slurmctld, slurmd on 127.0.0.1, its
    own key, ports, state and logs in a temporary directory): the environment `sbatch` and
    `squeue` need to reach it. Stopped afterwards. CI installs slurm-wlm, so there a missing
    Slurm fails the test."""
    if not all(SLURM):
        if os.environ.get("CI"):
            pytest.fail("slurm-wlm is not installed (.ci/run installs it)")
        pytest.skip("slurm-wlm (apt-get install slurm-wlm)")
    import getpass
    import socket
    d = tmp_path_factory.mktemp("slurm")
    (d / "state").mkdir()
    (d / "spool").mkdir()
    (d / "munge").mkdir(mode=0o700)
    key = d / "munge" / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o400)
    sock = d / "munge" / "munge.sock"
    ports = []
    for _ in range(2):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            ports.append(s.getsockname()[1])
    user, host = getpass.getuser(), socket.gethostname().split(".")[0]
    conf = d / "slurm.conf"
    conf.write_text("\n".join([
        "ClusterName=umbratest", f"SlurmctldHost={host}(127.0.0.1)",
        f"SlurmctldPort={ports[0]}", f"SlurmdPort={ports[1]}",
        f"SlurmUser={user}", f"SlurmdUser={user}",
        "AuthType=auth/munge", f"AuthInfo=socket={sock}", "CredType=cred/munge",
        f"StateSaveLocation={d}/state", f"SlurmdSpoolDir={d}/spool",
        f"SlurmctldPidFile={d}/slurmctld.pid", f"SlurmdPidFile={d}/slurmd.pid",
        f"SlurmctldLogFile={d}/slurmctld.log", f"SlurmdLogFile={d}/slurmd.log",
        "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none",
        "JobAcctGatherType=jobacct_gather/none", "AccountingStorageType=accounting_storage/none",
        "SchedulerType=sched/builtin", "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_Core", "ReturnToService=2", "MpiDefault=none",
        f"NodeName=umbranode NodeAddr=127.0.0.1 CPUs={os.cpu_count() or 1} State=UNKNOWN",
        "PartitionName=umbra Nodes=ALL Default=YES MaxTime=INFINITE State=UP", ""]))
    env = dict(os.environ, SLURM_CONF=str(conf))
    munged, slurmctld, slurmd, _, squeue = SLURM
    subprocess.run([munged, "--force", f"--key-file={key}", f"--socket={sock}",
                    f"--pid-file={d}/munge/munged.pid", f"--log-file={d}/munge/munged.log",
                    f"--seed-file={d}/munge/seed"], check=True, env=env)
    try:
        subprocess.run([slurmctld, "-i"], check=True, env=env)
        subprocess.run([slurmd, "-N", "umbranode"], check=True, env=env)
        import time
        deadline = time.monotonic() + 60
        while True:
            p = subprocess.run([shutil.which("sinfo") or "sinfo", "-h", "-o", "%t"], env=env,
                               capture_output=True, text=True)
            if p.stdout.strip() == "idle":
                break
            if time.monotonic() > deadline:
                logs = "".join(f.read_text() for f in d.glob("*.log"))
                pytest.fail(f"the test's Slurm did not come up: {p.stdout}{p.stderr}\n{logs}")
            time.sleep(0.5)
        yield env
    finally:
        subprocess.run([shutil.which("scontrol") or "scontrol", "shutdown"], env=env,
                       capture_output=True)
        for pid in (d / "slurmd.pid", d / "slurmctld.pid", d / "munge" / "munged.pid"):
            try:
                os.kill(int(pid.read_text()), 15)
            except (OSError, ValueError):
                pass


def test_an_emitted_slurm_script_runs_on_slurm(cli, slurm, tmp_path):
    import time
    farm = _job(tmp_path / "it's a shot é", corrupt=3)
    script = farm.parent / "job.sbatch"
    cli("batch", farm, "--emit", "slurm", "-o", script)
    p = subprocess.run([SLURM[3], "--parsable", str(script)], env=slurm, cwd=farm.parent,
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    job_id = p.stdout.strip().split(";")[0]
    deadline = time.monotonic() + 600
    while subprocess.run([SLURM[4], "-h", "-j", job_id], env=slurm, capture_output=True,
                         text=True).stdout.strip():
        assert time.monotonic() < deadline, "the Slurm job did not finish in 10 minutes"
        time.sleep(0.5)
    # One output file per array element (Slurm's default name in the submit directory).
    assert len(list(farm.parent.glob(f"slurm-{job_id}_*.out"))) == 6
    code, out, _ = cli("batch", farm, "--status", "--json", check=False)
    s = json.loads(out)
    assert code == 3 and sorted(f["task"] for f in s["failed"]) == [4, 5], s
    by_slurm = _maps(farm.parent)
    assert len(by_slurm) == 4
    code, _, _ = cli("batch", farm, "--force", "--quiet", check=False)
    assert code == 3 and _maps(farm.parent) == by_slurm
