#!/usr/bin/env bash
# Time issue 20's outputs on data/cloud.vdb, side by side: a flat map, a deep map and a tiled +
# mip-mapped map at the default 1024 px, and transmittance volumes for suns along an axis, a
# diagonal, a lattice direction typed with decimals (0.3,-1,0.2), off the lattice, and a point
# light. Runs alternate between the set-ups, RUNS times (the first, a warm-up, dropped), and
# the medians of `--json`'s seconds are printed. Usage: bench/outputs.sh [RUNS] (default 6).
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-6}
U=${UMBRA:-target/release/umbra}
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
declare -A T
MAPS=(flat deep tiled)
VOLS=("axis 0,-1,0" "diagonal 1,-1,0" "lattice 0.3,-1,0.2" "off-lattice 0.3183,-1,0.2718" "point")
field() { python3 -c "import json,sys; j=json.load(sys.stdin); print($1)"; }
for run in $(seq 1 "$RUNS"); do
  for m in "${MAPS[@]}"; do
    case $m in
      flat) extra=() ;;
      deep) extra=(--deep) ;;
      tiled) extra=(--tile 64 --mipmap) ;;
    esac
    s=$("$U" bake data/cloud.vdb --light-dir=0.3,-1,0.2 --density-scale 4 "${extra[@]}" \
          -o "$OUT/$m.exr" --force --quiet --json | field 'j["total_seconds"]')
    [ "$run" -gt 1 ] && T[$m]+="$s "
  done
  for v in "${VOLS[@]}"; do
    set -- $v
    if [ "$1" = point ]; then light=(--light-pos=0.5,4,0.2); else light=("--light-dir=$2"); fi
    s=$("$U" bake data/cloud.vdb "${light[@]}" --density-scale 4 -o "$OUT/v.vdb" --force \
          --quiet --json | field '"%s %s %s" % (j["ns_per_voxel"], j["rays"], j["total_seconds"])')
    [ "$run" -gt 1 ] && T[$1]+="$s;"
  done
done
median() { python3 -c "import sys,statistics; v=[float(x) for x in sys.argv[1:]]; print('%.3f' % statistics.median(v))" "$@"; }
echo "| map (1024 px, 0.3,-1,0.2, scale 4) | total seconds, median of $((RUNS - 1)) |"
echo "|---|---|"
for m in "${MAPS[@]}"; do echo "| $m | $(median ${T[$m]}) |"; done
J=$("$U" bake data/cloud.vdb --light-dir=0.3,-1,0.2 --density-scale 4 --deep -o "$OUT/d.exr" --force --quiet --json)
echo "$J" | field '"deep: %.2f samples per pixel (most %d), %d of %d pixels empty, deep pass %.2f s" % (j["deep"]["mean_samples_per_pixel"], j["deep"]["max_samples_per_pixel"], j["deep"]["empty_pixels"], j["width"]*j["height"], j["deep"]["seconds"])'
echo "files: deep $(du -k "$OUT/d.exr" | cut -f1) kB, flat $(du -k "$OUT/flat.exr" | cut -f1) kB, tiled + mip $(du -k "$OUT/tiled.exr" | cut -f1) kB"
echo
echo "| transmittance volume (149,058 voxels) | ns per voxel | rays | total seconds |"
echo "|---|---|---|---|"
for v in "${VOLS[@]}"; do
  set -- $v
  IFS=';' read -ra rows <<< "${T[$1]}"
  ns=(); tot=(); rays=0
  for r in "${rows[@]}"; do set -- $r; ns+=("$1"); rays=$2; tot+=("$3"); done
  set -- $v
  echo "| $1 ${2:-(0.5,4,0.2)} | $(median "${ns[@]}") | $rays | $(median "${tot[@]}") |"
done
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
