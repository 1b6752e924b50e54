#!/usr/bin/env bash
# Loading a grid from NanoVDB against OpenVDB: each input converted by nanovdb_convert
# (libnanovdb-tools) into every codec and quantisation umbra reads, then loaded whole
# (`Volume::load`: decode, flat tree, bounds) by bench/programs/load_formats.rs in rounds that
# alternate the files (first round dropped), and each file once more in a process of its own
# for its peak resident memory. Results in docs/performance.md ("Loading NanoVDB").
# Usage: bench/nvdb_load.sh [ROUNDS] [VDB GRID]... (default 9 rounds; data/cloud.vdb density,
# the corpus's cloud_fbm density and Houdini smoke density).
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${1:-9}
shift || true
if [ $# -eq 0 ]; then
  set -- data/cloud.vdb density ../shared/corpus/gen/cloud_fbm.vdb density \
    ../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb density
fi
command -v nanovdb_convert >/dev/null || { echo "needs nanovdb_convert (apt-get install libnanovdb-tools)" >&2; exit 1; }
cargo build --release --ignore-rust-version --example load_formats -q
BIN=target/release/examples/load_formats
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg); $(grep -o -m1 'avx512f' /proc/cpuinfo || echo 'no avx512f'); $(nproc) cores"
while [ $# -ge 2 ]; do
  src=$1 grid=$2; shift 2
  stem=$(basename "$src" .vdb)
  files=("$src")
  for v in none:'' zip:-z blosc:-b fp16:--fp16 fp8:--fp8 fp4:--fp4 fpn:'--fpN -a 0.01'; do
    name=${v%%:*} flags=${v#*:}
    # shellcheck disable=SC2086
    nanovdb_convert -f $flags -g "$grid" "$src" "$OUT/$stem.$name.nvdb" >/dev/null
    files+=("$OUT/$stem.$name.nvdb")
  done
  "$BIN" "$grid" "$ROUNDS" "${files[@]}" | sed "s#$OUT/##"
  for f in "${files[@]}"; do "$BIN" --once "$grid" 1 "$f" | sed "s#$OUT/##"; done
done
