#!/usr/bin/env bash
# Null-collision estimators on moving real caches, still against blurred and the blurred ones
# before and after the per-interval bounds (issue 61; docs/performance.md section 17).
# Usage: bench/blur_intervals.sh BEFORE_BIN AFTER_BIN [OUT_DIR]
# Caches: openvdb_smoke1_houdini_v222.vdb's density with a vec3s `vel` written by pyopenvdb
# (constant (30, 0, 10) units/s, and a swirl about y, up to 56 units/s), shutter 0,1 frames at
# 24 fps; Blender's Mantaflow cache (staggered `velocity`) at velocity scale 0.1, density
# scale 3000, shutter -0.25,0.25. 256-pixel ortho maps, 16 spp, seed 1. For each map: median
# seconds of 5 runs after a warm-up, the configurations alternated run by run, the report's
# spp and lookups/ray, and the RMS error against the exact map (still) or riemann at step 0.25
# with 128 stratified times (blurred).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
before="$1" after="$2"
dir="${3:-$(mktemp -d)}"
mkdir -p "$dir"
corpus="$repo/../shared/corpus/real"
/usr/bin/python3 "$repo/tests/motion/make_moving_smoke.py" "$corpus/openvdb_smoke1_houdini_v222.vdb" "$dir"
rms() {
  /usr/bin/python3 - "$1" "$2" <<'PY'
import sys, OpenImageIO as oiio, numpy as np
a = oiio.ImageBuf(sys.argv[1]).get_pixels(oiio.FLOAT)[..., 0]
b = oiio.ImageBuf(sys.argv[2]).get_pixels(oiio.FLOAT)[..., 0]
print(f"{np.sqrt(np.mean((a - b) ** 2)):.2e}")
PY
}
echo "load $(cut -d' ' -f1-3 /proc/loadavg), avx512f: $(grep -o -m1 avx512f /proc/cpuinfo || echo no)"
printf '%-14s %-13s %-16s %8s %6s %11s %9s\n' cache estimator map seconds spp lookups/ray rms
for cache in const swirl blender; do
  if [ "$cache" = blender ]; then
    f="$corpus/blender_smoke_fluid_data_0050.vdb"
    move=(--velocity velocity --velocity-scale 0.1 --shutter -0.25,0.25)
    common=(--density-scale 3000 --force)
  else
    f="$dir/smoke_$cache.vdb"
    move=(--velocity vel --shutter 0,1)
    common=(--force)
  fi
  ref="$dir/$cache.ref.exr" exact="$dir/$cache.exact.exr"
  [ -s "$ref" ] || "$after" bake "$f" "${common[@]}" -o "$ref" --res 256 --light-dir 0.2,-0.3,-1 \
    "${move[@]}" --estimator riemann --step 0.25 --time-samples 128 >/dev/null 2>&1
  [ -s "$exact" ] || "$after" bake "$f" "${common[@]}" -o "$exact" --camera "$ref" >/dev/null 2>&1
  for est in ratio track-length; do
    names=("still sweep" "still rays" "blurred before" "blurred after")
    bins=("$after" "$after" "$before" "$after")
    extra=("" "--order rays" "blur" "blur")
    declare -A times=() lines=()
    for run in 0 1 2 3 4 5; do
      for i in 0 1 2 3; do
        args=(bake "$f" "${common[@]}" -o "$dir/m$i.exr" --camera "$ref" --estimator "$est" --spp 16 --seed 1)
        case "${extra[$i]}" in
          blur) args+=("${move[@]}") ;;
          "") ;;
          *) args+=(${extra[$i]}) ;;
        esac
        s=$(date +%s.%N)
        line=$("${bins[$i]}" "${args[@]}" 2>&1 | grep 'lookups/ray' | tail -1)
        e=$(date +%s.%N)
        [ "$run" = 0 ] && continue
        times[$i]+="$(echo "$e - $s" | bc) "
        lines[$i]="$line"
      done
    done
    for i in 0 1 2 3; do
      med=$(echo ${times[$i]} | tr ' ' '\n' | sort -n | sed -n 3p)
      spp=$(echo "${lines[$i]}" | grep -o '[0-9.]* spp' | cut -d' ' -f1)
      lk=$(echo "${lines[$i]}" | grep -o '[0-9]* lookups/ray' | cut -d' ' -f1)
      want="$ref"; [ "$i" -lt 2 ] && want="$exact"
      printf '%-14s %-13s %-16s %8.3f %6s %11s %9s\n' "$cache" "$est" "${names[$i]}" "$med" "$spp" "$lk" \
        "$(rms "$dir/m$i.exr" "$want")"
    done
    unset times lines
  done
done
echo "load $(cut -d' ' -f1-3 /proc/loadavg)"
