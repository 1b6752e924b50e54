#!/usr/bin/env bash
# Motion-blurred maps against still ones on a moving real cache (docs/performance.md section
# 17): the corpus's Houdini smoke with a velocity grid (bench/motion_cache.py: a constant
# (30, 0, 10) units/s, and a swirl), 256x256 ortho maps, shutter [0, 1] frame at 24 fps.
# For each map: the median whole-process time of REPS runs after a warm-up, the configurations
# alternated run by run; the lookups per ray (the bake's JSON); the RMS error against the
# reference: the exact map for still maps, riemann with 128 stratified times for blurred ones.
# Usage: bench/motion_maps.sh [UMBRA_BIN] [EXTRA BAKE ARGS...]   (default target/release/umbra)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
bin="${1:-$repo/target/release/umbra}"
shift || true
REPS=${REPS:-7}
dir="$(mktemp -d)"
trap 'rm -rf "$dir"' EXIT
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg); $(grep -o -m1 avx512f /proc/cpuinfo || echo 'no avx512f'); $(nproc) cores"
for kind in constant swirl; do
  f="$dir/$kind.vdb"
  /usr/bin/python3 "$repo/bench/motion_cache.py" "$repo/../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb" "$f" "$kind"
  common=(bake "$f" --grid density --force --quiet "$@")
  blur=(--velocity vel --shutter 0,1)
  # The camera frames the blurred box (the reference's); every map reuses it.
  "$bin" "${common[@]}" -o "$dir/ref_blur.exr" --res 256 --light-dir 0.3,-1,0.2 "${blur[@]}" \
    --estimator riemann --time-samples 128
  "$bin" "${common[@]}" -o "$dir/ref_still.exr" --camera "$dir/ref_blur.exr"
  names=(); args=(); refs=()
  add() { names+=("$1"); refs+=("$2"); shift 2; args+=("$*"); }
  add "still riemann (sweep)" ref_still --estimator riemann
  add "blurred riemann, 8 times (sweep)" ref_blur "${blur[*]}" --estimator riemann
  add "blurred riemann, 8 times (rays)" ref_blur "${blur[*]}" --estimator riemann --order rays
  add "blurred riemann, 16 times (sweep)" ref_blur "${blur[*]}" --estimator riemann --time-samples 16
  n=${#names[@]}
  declare -A times=()
  for ((r = 0; r <= REPS; r++)); do
    for ((i = 0; i < n; i++)); do
      # shellcheck disable=SC2086
      s=$(date +%s.%N); "$bin" "${common[@]}" -o "$dir/m$i.exr" --camera "$dir/ref_blur.exr" ${args[$i]} >/dev/null; e=$(date +%s.%N)
      [ "$r" -gt 0 ] && times[$i]+="$(echo "$e - $s" | bc) "
    done
  done
  echo "== $kind velocity; load after: $(cut -d' ' -f1-3 /proc/loadavg)"
  printf '%-36s %9s %12s %10s\n' map seconds lookups/ray rms
  for ((i = 0; i < n; i++)); do
    med=$(echo "${times[$i]}" | tr ' ' '\n' | grep . | sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}')
    # shellcheck disable=SC2086
    lpr=$("$bin" "${common[@]}" -o "$dir/m$i.exr" --camera "$dir/ref_blur.exr" ${args[$i]} --json | /usr/bin/python3 -c 'import json,sys; print("%.0f" % json.load(sys.stdin)["lookups_per_ray"])')
    rms=$(/usr/bin/python3 - "$dir/m$i.exr" "$dir/${refs[$i]}.exr" <<'PY'
import sys, OpenImageIO as oiio, numpy as np
a = oiio.ImageBuf(sys.argv[1]).get_pixels(oiio.FLOAT)[..., 0]
b = oiio.ImageBuf(sys.argv[2]).get_pixels(oiio.FLOAT)[..., 0]
print(f"{np.sqrt(np.mean((a - b) ** 2)):.2e}")
PY
)
    printf '%-36s %9.3f %12s %10s\n' "${names[$i]}" "$med" "$lpr" "$rms"
  done
  unset times
done
