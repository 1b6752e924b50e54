#!/usr/bin/env bash
# Build and install the Python module into a fresh virtual environment (what `pip install
# ./python` does for a user), then run its tests against the `umbra` binary built beside it.
# Run from anywhere; PYTHON picks the interpreter (default python3, CPython >= 3.9).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
target="${CARGO_TARGET_DIR:-$repo/target}"
venv="$target/py-venv"
rm -rf "$venv"
"${PYTHON:-python3}" -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
"$venv/bin/python" -m pip install -q "$repo/python" pytest "OpenEXR>=3.2" mypy usd-core openjd-cli opencue-pyoutline packaging moderngl
cargo build --release --bin umbra --manifest-path "$repo/Cargo.toml"
# From outside the checkout, so `import umbra` is the installed package, not python/umbra.
cd "$target"
UMBRA_BIN="$target/release/umbra" "$venv/bin/python" -m pytest -q -p no:cacheprovider "$repo/python/tests"
