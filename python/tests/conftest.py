"""Shared fixtures: the repository, the corpus beside it, and the `umbra` binary the Python
module is held to (UMBRA_BIN, else target/release/umbra, built if missing)."""

import json
import re
import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
CORPUS = pathlib.Path(os.environ.get("UMBRA_CORPUS", REPO.parent / "shared" / "corpus"))
DATA = REPO / "data"


def _binary() -> pathlib.Path:
    env = os.environ.get("UMBRA_BIN")
    if env:
        return pathlib.Path(env)
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    exe = target / "release" / "umbra"
    if not exe.exists():
        subprocess.run(["cargo", "build", "--release", "--ignore-rust-version", "--bin", "umbra"], cwd=REPO, check=True)
    return exe


@pytest.fixture(scope="session")
def umbra_bin() -> pathlib.Path:
    exe = _binary()
    assert exe.exists(), f"no umbra binary at {exe}"
    return exe


@pytest.fixture(scope="session")
def corpus() -> pathlib.Path:
    assert (CORPUS / "gen").is_dir(), f"the corpus is missing: {CORPUS}"
    return CORPUS


@pytest.fixture
def cli(umbra_bin):
    """Run `umbra ARGS...` in the repository: (exit code, stdout, stderr)."""

    def run(*args, check=True):
        p = subprocess.run(
            [str(umbra_bin), *map(str, args)], cwd=REPO, capture_output=True, text=True
        )
        if check and p.returncode != 0:
            raise AssertionError(f"umbra {' '.join(map(str, args))}: {p.returncode}\n{p.stderr}")
        return p.returncode, p.stdout, p.stderr

    return run


def cli_error(stderr: str) -> str:
    """The message of the CLI's one `umbra: error: ...` line, as the Python module words the
    same error: each front end names options its own way (`--deep-error` is the keyword
    `deep_error`, `--force` is `force=True`); everything else is the same text."""
    lines = [l for l in stderr.splitlines() if l.startswith("umbra: error: ")]
    assert len(lines) == 1, stderr
    message = lines[0][len("umbra: error: "):]
    message = re.sub(r"invalid argument '--([a-z0-9-]+)'",
                     lambda m: "invalid argument '%s'" % m.group(1).replace("-", "_"), message)
    return message.replace("(use --force to overwrite)", "(pass force=True to replace it)")


def json_lines(stdout: str):
    return [json.loads(l) for l in stdout.splitlines() if l.strip()]


@pytest.fixture(autouse=True)
def in_repo(monkeypatch):
    """Every test runs in the repository, as the CLI runs are (maps record paths as given)."""
    monkeypatch.chdir(REPO)
