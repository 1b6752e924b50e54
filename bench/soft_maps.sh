#!/usr/bin/env bash
# A soft map (a sun with an angle) against the hard map of the same cache, whole process,
# alternated run by run (docs/performance.md, "Maps toward a light with extent"):
# bash bench/soft_maps.sh UMBRA [FILE] [ANGLE] [ROUNDS] [EXTRA...]. Prints "round job seconds"
# lines (round 0 is the warm-up to drop), then the soft map's penumbra statistics (texels with
# 0.02 < T < 0.98: count and largest std_err) and its sampled fraction.
set -euo pipefail
exe="$1"
file="${2:-$(dirname "$0")/../../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb}"
angle="${3:-4}"
rounds="${4:-3}"
shift $(( $# < 4 ? $# : 4 ))
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
py="${PYTHON:-python3}"  # with numpy and OpenEXR (the test venv of python/run_tests.sh has both)
for round in $(seq 0 "$rounds"); do
  for job in hard soft; do
    extra=()
    [ "$job" = soft ] && extra=(--light-angle "$angle" --stderr --json "$@")
    s=$( { /usr/bin/time -f "%e %U" "$exe" bake "$file" --light-dir=0,-1,0.3 --res 512 \
      -o "$out/$job.exr" --force -q "${extra[@]}" >"$out/$job.json"; } 2>&1 | tail -1)
    echo "$round $job $s"
  done
done
"$py" - "$out/soft.exr" "$out/soft.json" <<'PY'
import json, sys
import OpenEXR
import numpy as np
with OpenEXR.File(sys.argv[1]) as f:
    ch = f.channels()
    t, e = ch["T"].pixels, ch["T.stderr"].pixels
pen = (t > 0.02) & (t < 0.98)
light = json.load(open(sys.argv[2]))["light"]
over = int((e[pen] > 5e-3).sum())
print(f"penumbra texels {int(pen.sum())} of {t.size}, largest std_err there {e[pen].max():.3e}, "
      f"99th percentile {np.percentile(e[pen], 99):.3e}, median {np.median(e[pen]):.3e}, "
      f"{over} above 5e-3; sampled fraction {light['sampled_fraction']:.4f}")
PY
