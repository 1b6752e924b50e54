"""The type stubs describe the installed module (mypy's stubtest), and the examples type-check
against them."""

import pathlib
import subprocess
import sys

import pytest

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def test_stubs_match_the_module(tmp_path):
    pytest.importorskip("mypy")
    # From a directory outside the checkout, so the installed package is the one checked.
    p = subprocess.run([sys.executable, "-m", "mypy.stubtest", "umbra"], cwd=tmp_path,
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr


def test_examples_type_check(tmp_path):
    pytest.importorskip("mypy")
    p = subprocess.run([sys.executable, "-m", "mypy", "--ignore-missing-imports", "--no-incremental",
                        *map(str, sorted(EXAMPLES.glob("*.py")))], cwd=tmp_path,
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr
