#!/usr/bin/env bash
# The cost of a motion-blurred map against the still map at equal error (docs/motion.md).
# Writes the OpenVDB-made swirl cache (tests/motion/make_reference.py), bakes 128x128 ortho maps
# of it, still and blurred over a shutter of [-1, 1] frames, and prints for each the median of
# 5 runs (a warm-up dropped) and the RMS error against its own reference: the exact map for the
# still ones, riemann at step 0.25 with 128 stratified times for the blurred ones.
# Usage: bench/motion_cost.sh [UMBRA_BIN]   (default target/release/umbra)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
bin="${1:-$repo/target/release/umbra}"
dir="$(mktemp -d)"
trap 'rm -rf "$dir"' EXIT
/usr/bin/python3 "$repo/tests/motion/make_reference.py" "$dir" >/dev/null
f="$dir/swirl.vdb"
common=(--density-scale 0.06 --quiet --force)
bake() { "$bin" bake "$f" "${common[@]}" "$@" 2>/dev/null; }
# The camera frames the blurred box (the reference's); every map reuses it.
bake -o "$dir/ref.exr" --light-dir 0.2,-0.3,-1 --res 128 --velocity vel --shutter -1,1 \
  --estimator riemann --step 0.25 --time-samples 128
bake -o "$dir/exact.exr" --camera "$dir/ref.exr"
time_of() { # median seconds of 5 runs after a warm-up
  "$@" >/dev/null
  for _ in 1 2 3 4 5; do
    s=$(date +%s.%N); "$@" >/dev/null; e=$(date +%s.%N)
    echo "$e - $s" | bc
  done | sort -n | sed -n 3p
}
rms() {
  /usr/bin/python3 - "$1" "$2" <<'PY'
import sys, OpenImageIO as oiio, numpy as np
a = oiio.ImageBuf(sys.argv[1]).get_pixels(oiio.FLOAT)[..., 0]
b = oiio.ImageBuf(sys.argv[2]).get_pixels(oiio.FLOAT)[..., 0]
print(f"{np.sqrt(np.mean((a - b) ** 2)):.2e}")
PY
}
printf '%-44s %9s %10s\n' map seconds rms_error
run() { # name, reference, args...
  local name="$1" ref="$2"; shift 2
  local t; t=$(time_of bake -o "$dir/m.exr" --camera "$dir/ref.exr" "$@")
  printf '%-44s %9.3f %10s\n' "$name" "$t" "$(rms "$dir/m.exr" "$ref")"
}
run "still exact (sweep)" "$dir/exact.exr"
run "still riemann step 1 (sweep)" "$dir/exact.exr" --estimator riemann
run "still riemann step 1 (rays)" "$dir/exact.exr" --estimator riemann --order rays
for k in 2 4 8 16 32; do
  run "blurred riemann step 1, $k times" "$dir/ref.exr" --velocity vel --shutter -1,1 \
    --estimator riemann --time-samples "$k"
done
run "blurred ratio, 16 spp" "$dir/ref.exr" --velocity vel --shutter -1,1 --estimator ratio --spp 16
run "blurred ratio, 64 spp" "$dir/ref.exr" --velocity vel --shutter -1,1 --estimator ratio --spp 64
