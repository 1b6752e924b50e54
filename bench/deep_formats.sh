#!/usr/bin/env bash
# Fixed-size deep formats against the flat map and --deep, two umbra builds alternated run by
# run (docs/performance.md, "Fixed-size deep formats"): bash bench/deep_formats.sh OLD NEW
# [FILE]. Prints "round job build seconds" lines; round 0 is the warm-up to drop.
set -euo pipefail
old="$1"; new="$2"
file="${3:-$(dirname "$0")/../../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb}"
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
for round in 0 1 2 3; do
  for fmt in flat deep moments:4 moments:6 fourier:7 avsm:8; do
    for build in old new; do
      exe="$old"; [ "$build" = new ] && exe="$new"
      case "$fmt" in
        flat) extra=() ;;
        deep) extra=(--deep) ;;
        *) extra=(--deep-format "$fmt") ;;
      esac
      s=$( { /usr/bin/time -f "%e" "$exe" bake "$file" --light-dir=0,-1,0.3 --res 512 \
        -o "$out/$build.exr" --force -q "${extra[@]}" >/dev/null; } 2>&1 | tail -1)
      echo "$round $fmt $build $s"
    done
  done
done
