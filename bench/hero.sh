#!/usr/bin/env bash
# Issue 18's benches on a hero-size cache, umbra against OpenVDB 10's vdb_print, side by side.
#
#   bash bench/hero.sh [FILE.vdb] [RUNS]
#
# FILE defaults to /tmp/umbra-hero/hero.vdb (made by tools/make_hero.py when missing); RUNS
# (default 5) timed runs per command after one warm-up, the tools alternated run by run. Prints
# the median wall time and median peak RSS (GNU time's %M) of each, and the ratios the issue's
# targets are about. Needs: a release build (cargo build --release), Debian packages
# libopenvdb-tools (vdb_print), python3-openvdb (to make the file) and time (/usr/bin/time).
# Run it on a quiet machine: the load average is printed before and after.
set -euo pipefail
cd "$(dirname "$0")/.."
FILE=${1:-/tmp/umbra-hero/hero.vdb}
RUNS=${2:-5}
UMBRA=${UMBRA:-target/release/umbra}
[ -f "$FILE" ] || /usr/bin/python3 tools/make_hero.py "$FILE"
[ -x "$UMBRA" ] || { echo "build first: cargo build --release" >&2; exit 1; }
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT

# A point inside the cache's first cloud, lit from above.
AT=${AT:-0.3,1.2,0.2}

declare -A CMD=(
  [vdb_print]="vdb_print $FILE"
  [umbra_query]="$UMBRA query $FILE --at $AT --light-dir 0,-1,0"
  [umbra_query_eager]="$UMBRA query $FILE --at $AT --light-dir 0,-1,0 --load eager"
  [vdb_print_l]="vdb_print -l $FILE"
  [umbra_info]="$UMBRA info $FILE"
  [umbra_bake]="$UMBRA bake $FILE --light-dir 0.3,-1,0.2 --res 1024 -o $OUT/map.exr --force --quiet"
  [umbra_bake_whole]="$UMBRA bake $FILE --light-dir 0.3,-1,0.2 --res 1024 -o $OUT/mapwhole.exr --force --quiet --max-memory 64G"
  [umbra_bake_512M]="$UMBRA bake $FILE --light-dir 0.3,-1,0.2 --res 1024 -o $OUT/map512.exr --force --quiet --max-memory 512M"
)
ORDER=(vdb_print umbra_query umbra_query_eager vdb_print_l umbra_info umbra_bake umbra_bake_whole umbra_bake_512M)

echo "file: $FILE ($(du -h "$FILE" | cut -f1)), $(nproc) cores, load: $(cut -d' ' -f1-3 /proc/loadavg)"
for name in "${ORDER[@]}"; do : > "$OUT/$name"; done
for run in $(seq 0 "$RUNS"); do
  for name in "${ORDER[@]}"; do
    /usr/bin/time -f "%e %M" -o "$OUT/t" ${CMD[$name]} > /dev/null 2>&1 || {
      echo "failed: ${CMD[$name]}" >&2; exit 1; }
    [ "$run" -gt 0 ] && cat "$OUT/t" >> "$OUT/$name"  # run 0 is the warm-up
  done
done
median() { sort -g | awk '{a[NR]=$1} END {print (NR%2 ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2)}'; }
declare -A WALL RSS
for name in "${ORDER[@]}"; do
  WALL[$name]=$(cut -d' ' -f1 "$OUT/$name" | median)
  RSS[$name]=$(cut -d' ' -f2 "$OUT/$name" | median)
  printf '%-18s wall %6.2f s   peak RSS %7.0f MB   (%s)\n' "$name" "${WALL[$name]}" \
    "$(echo "${RSS[$name]} / 1024" | bc -l)" "${CMD[$name]}"
done
ratio() { echo "scale=2; $1 / $2" | bc -l; }
echo "point query / vdb_print:  wall $(ratio "${WALL[umbra_query]}" "${WALL[vdb_print]}")x," \
  "RSS $(ratio "${RSS[umbra_query]}" "${RSS[vdb_print]}")x   (targets <= 1.0, <= 1.5)"
echo "info / vdb_print -l:      wall $(ratio "${WALL[umbra_info]}" "${WALL[vdb_print_l]}")x   (target <= 0.6)"
MEM=$(vdb_print -m "$FILE" | awk '/file_mem_bytes/ {print $2; exit}')
echo "1024^2 bake (no budget) peak RSS / file_mem_bytes: $(ratio "$((${RSS[umbra_bake]} * 1024))" "$MEM")x   (target <= 1.0)"
echo "the same held whole (--max-memory 64G): $(ratio "$((${RSS[umbra_bake_whole]} * 1024))" "$MEM")x," \
  "wall $(ratio "${WALL[umbra_bake]}" "${WALL[umbra_bake_whole]}")x of it for the bake without a budget"
echo "--max-memory 512M: peak RSS $(ratio "${RSS[umbra_bake_512M]}" 524288)x the budget," \
  "wall $(ratio "${WALL[umbra_bake_512M]}" "${WALL[umbra_bake]}")x the bake without a budget (target <= 2)," \
  "map $(cmp -s "$OUT/map.exr" "$OUT/map512.exr" && cmp -s "$OUT/map.exr" "$OUT/mapwhole.exr" && echo identical || echo DIFFERENT) to the whole bake's"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
