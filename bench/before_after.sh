#!/usr/bin/env bash
# Two builds of umbra side by side on the hot paths a change to traversal or the sweep can move:
# an exact 1024 px map (the object-order sweep), a nearest exact map and a ratio-tracking map
# (the ray path: hierarchical DDA and cell walks), 200,000 exact query segments (regular
# tracking per ray) and an off-lattice transmittance volume. Runs alternate between the two
# builds, RUNS times (the first, a warm-up, dropped); the medians of each tool's own `seconds`
# are printed with their ratio, and every output is compared between the builds.
# Usage: bench/before_after.sh OLD_UMBRA NEW_UMBRA [RUNS] (default 6).
set -euo pipefail
cd "$(dirname "$0")/.."
OLD=$1
NEW=$2
RUNS=${3:-6}
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg); $(grep -o -m1 'avx512f' /proc/cpuinfo || echo 'no avx512f'), $(grep -o -m1 'avx2' /proc/cpuinfo || echo 'no avx2')"
python3 - "$OUT/segs.csv" <<'EOF'
import random, sys
random.seed(7)
with open(sys.argv[1], "w") as f:
    for _ in range(200_000):
        a = [random.uniform(-3, 3), random.uniform(-1, 4), random.uniform(-3, 3)]
        b = [random.uniform(-3, 3), random.uniform(-1, 4), random.uniform(-3, 3)]
        f.write(",".join(f"{v:.6f}" for v in a + b) + "\n")
EOF
field() { python3 -c "import json,sys; j=json.load(sys.stdin); print($1)"; }
CASES=(sweep nearest ratio query volume)
run_case() { # tool case tag -> seconds
  local U=$1 c=$2 tag=$3
  case $c in
    sweep) "$U" bake data/cloud.vdb --light-dir=0.3,-1,0.2 --density-scale 4 --res 1024 \
             -o "$OUT/$tag.$c.exr" --force --quiet --json | field 'j["seconds"]' ;;
    nearest) "$U" bake data/cloud.vdb --light-dir=0.3,-1,0.2 --density-scale 4 --res 512 \
             --interp nearest -o "$OUT/$tag.$c.exr" --force --quiet --json | field 'j["seconds"]' ;;
    ratio) "$U" bake data/cloud.vdb --light-dir=0.3,-1,0.2 --density-scale 4 --res 256 \
             --estimator ratio --spp 16 -o "$OUT/$tag.$c.exr" --force --quiet --json \
             | field 'j["seconds"]' ;;
    query) local t0 t1; t0=$(date +%s.%N)
           "$U" query data/cloud.vdb --rays "$OUT/segs.csv" --density-scale 4 > "$OUT/$tag.$c.csv"
           t1=$(date +%s.%N); python3 -c "print($t1 - $t0)" ;;
    volume) "$U" bake data/cloud.vdb --light-dir=0.3183,-1,0.2718 --density-scale 4 \
             -o "$OUT/$tag.$c.vdb" --force --quiet --json | field 'j["seconds"]' ;;
  esac
}
declare -A T
for run in $(seq 1 "$RUNS"); do
  for c in "${CASES[@]}"; do
    for tag in old new; do
      U=$OLD; [ $tag = new ] && U=$NEW
      s=$(run_case "$U" "$c" "$tag")
      [ "$run" -gt 1 ] && T[$tag.$c]+="$s "
    done
  done
done
med() { python3 -c "import statistics,sys; print(statistics.median(map(float, sys.argv[1:])))" $1; }
printf "%-8s %10s %10s %7s  %s\n" case old_s new_s new/old "outputs"
for c in "${CASES[@]}"; do
  o=$(med "${T[old.$c]}"); n=$(med "${T[new.$c]}")
  same=differ
  for ext in exr csv vdb; do
    if [ -f "$OUT/old.$c.$ext" ] && cmp -s "$OUT/old.$c.$ext" "$OUT/new.$c.$ext"; then same=identical; fi
  done
  printf "%-8s %10.4f %10.4f %7.3f  %s\n" "$c" "$o" "$n" "$(python3 -c "print($n / $o)")" "$same"
done
