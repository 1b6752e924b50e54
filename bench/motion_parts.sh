#!/usr/bin/env bash
# A blurred map whole and in parts under --max-memory (docs/motion.md, bounded memory): the
# sample cloud tiled 6 x 6 x 6 with a swirling velocity (tests/motion/make_moving_cloud.py,
# pyopenvdb), a 192x192 ortho riemann map, run whole / 128M / 192M alternately 4 times; each run
# prints its seconds and peak resident set (/usr/bin/time), then the parts taken. Drop run 0
# (warm-up) and take medians. The maps must be the same bytes (printed SAME).
# Usage: bench/motion_parts.sh [UMBRA_BIN]   (default target/release/umbra)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
bin="${1:-$repo/target/release/umbra}"
dir="$(mktemp -d)"
trap 'rm -rf "$dir"' EXIT
/usr/bin/python3 "$repo/tests/motion/make_moving_cloud.py" "$dir/m6.vdb" --copies 6 6 6
echo "load start: $(cat /proc/loadavg); $(grep -o -m1 avx512f /proc/cpuinfo || echo no avx512f)"
for i in 0 1 2 3; do
  for mm in whole 128M 192M; do
    a=()
    [ "$mm" = whole ] || a=(--max-memory "$mm")
    /usr/bin/time -f "$mm run$i %e s %M KiB" "$bin" bake "$dir/m6.vdb" -o "$dir/o_$mm.exr" \
      --velocity vel --estimator riemann --res 192x192 --light-dir 0.3,-1,0.2 --force --json \
      "${a[@]}" 2>&1 >"$dir/j_$mm.json" | tail -1
    grep -o '"parts":[0-9]*' "$dir/j_$mm.json"
  done
done
cmp "$dir/o_whole.exr" "$dir/o_128M.exr" && cmp "$dir/o_whole.exr" "$dir/o_192M.exr" && echo SAME
echo "load end: $(cat /proc/loadavg)"
