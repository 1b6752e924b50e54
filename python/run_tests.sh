#!/usr/bin/env bash
# Build and install the Python module into a fresh virtual environment (what `pip install
# ./python` does for a user), then run its tests against the `umbra` binary built beside it.
# NVIDIA Warp (warp-lang, on the CPU) and python-blosc write the .nvdb files of
# test_nvdb_warp.py at test time.
# Run from anywhere; PYTHON picks the interpreter (default python3, CPython >= 3.9).
# UMBRA_PROFILE picks the cargo profile of the module and the binary under test (default
# `quick`, the Rust tests' profile, so the README's test command builds the binary once; the
# code is the same as a release build's, without its link-time optimisation).
set -euo pipefail
profile="${UMBRA_PROFILE:-quick}"
repo="$(cd "$(dirname "$0")/.." && pwd)"
target="${CARGO_TARGET_DIR:-$repo/target}"
venv="$target/py-venv"
say() { echo "run_tests: $*" >&2; }
say "building the Python module (pip install ./python) into a fresh venv, with the test packages from PyPI..."
rm -rf "$venv"
"${PYTHON:-python3}" -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
MATURIN_PEP517_ARGS="--profile $profile" \
  "$venv/bin/python" -m pip install -q "$repo/python" pytest "OpenEXR>=3.2" mypy usd-core openjd-cli opencue-pyoutline packaging moderngl warp-lang blosc
# Blender as a Python module (the bpy wheel, Cycles built with OSL) runs
# examples/deep_formats.osl in the tests. It pins its own numpy and wants CPython 3.11, so it
# gets a venv of its own, kept between runs (the wheel is about 350 MB).
bpy_venv="$target/bpy-venv"
if ! "$bpy_venv/bin/python" -c "import bpy" >/dev/null 2>&1; then
  say "installing Blender's bpy wheel (~350 MB, once; kept in $bpy_venv)..."
  rm -rf "$bpy_venv"
  "${PYTHON:-python3}" -m venv "$bpy_venv"
  "$bpy_venv/bin/python" -m pip install -q "bpy==4.5.4"
fi
export UMBRA_BPY_PYTHON="$bpy_venv/bin/python"
# The binary as `cargo test` builds it: its dev-dependencies turn on features of shared crates
# (bitflags, bytemuck, either, rand_core), so `cargo build --bin umbra` would rebuild those and
# the binary; building a small test target instead finds it fresh after the README's command.
say "building the umbra binary under test ($profile; nothing to do after cargo test)..."
cargo test --profile "$profile" --ignore-rust-version --no-run --test layering \
  --manifest-path "$repo/Cargo.toml"
say "running pytest..."
# From outside the checkout, so `import umbra` is the installed package, not python/umbra.
cd "$target"
UMBRA_BIN="$target/$profile/umbra" "$venv/bin/python" -m pytest -q -p no:cacheprovider "$repo/python/tests"
