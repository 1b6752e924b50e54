#!/usr/bin/env bash
# Every figure issue 67 asks for, re-measured on one build (docs/performance.md sections 16, 17
# and 19, "re-measured on main"): blurred against still riemann maps (wall and CPU, alternated),
# null-collision lookups per sample, whole bakes of .nvdb against .vdb, the still riemann sweep
# against NanoVDB's march, and umbra's riemann map against Warp's CPU kernel.
# Usage: bench/issue67.sh [UMBRA_BIN]   (default target/quick/umbra); ROUNDS (5); OUT; WARP=1
# adds the Warp rows; FROM=N starts at part N (1-3 can be skipped) (bench/peer.sh, which builds the --release ortho_view example first).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
cd "$repo"
U="$(realpath "${1:-target/quick/umbra}")"
ROUNDS=${ROUNDS:-5}
OUT=${OUT:-/tmp/umbra-issue67}
mkdir -p "$OUT"
corpus="$repo/../shared/corpus"
echo "== $(date -u +%FT%TZ); $(git rev-parse --short HEAD); $(grep -o -m1 avx512f /proc/cpuinfo || echo 'no avx512f (AVX2)'); load $(cut -d' ' -f1-3 /proc/loadavg)"

if [ "${FROM:-1}" -le 1 ]; then
echo "== 1. blurred against still riemann, 256 map, shutter of one frame (bench/alternate.py)"
for kind in constant swirl; do
  f="$OUT/$kind.vdb"
  [ -s "$f" ] || /usr/bin/python3 bench/motion_cache.py "$corpus/real/openvdb_smoke1_houdini_v222.vdb" "$f" "$kind" >/dev/null
  "$U" bake "$f" --grid density --force --quiet -o "$OUT/$kind.ref.exr" --res 256 --light-dir 0.3,-1,0.2 \
    --velocity vel --shutter 0,1 --estimator riemann --time-samples 128
  c="bake $f --grid density --force --quiet --camera $OUT/$kind.ref.exr --estimator riemann"
  echo "-- $kind velocity"
  python3 bench/alternate.py "$ROUNDS" "still (sweep)=$U $c -o $OUT/s.exr" \
    "blurred, 8 times (sweep)=$U $c -o $OUT/b.exr --velocity vel --shutter 0,1" \
    "blurred, 8 times (rays)=$U $c -o $OUT/r.exr --velocity vel --shutter 0,1 --order rays"
  /usr/bin/python3 - "$OUT/b.exr" "$OUT/$kind.ref.exr" <<'PY'
import sys, OpenImageIO as oiio, numpy as np
a = oiio.ImageBuf(sys.argv[1]).get_pixels(oiio.FLOAT)[..., 0]
b = oiio.ImageBuf(sys.argv[2]).get_pixels(oiio.FLOAT)[..., 0]
print(f"RMS of the 8-time sweep against 128 times: {np.sqrt(np.mean((a - b) ** 2)):.2e}")
PY
done

fi
if [ "${FROM:-1}" -le 2 ]; then
echo "== 2. null collisions: lookups per sample, still against blurred (bench/blur_intervals.sh)"
bash bench/blur_intervals.sh "$U" "$U" "$OUT/intervals" | grep -v "blurred before"

fi
echo "== 3. whole bakes of .nvdb against .vdb (bench/nvdb_bake.py)"
dense="$OUT/dense.vdb"
[ -s "$dense" ] || /usr/bin/python3 - "$dense" <<'PY'
import sys, numpy as np, pyopenvdb as vdb
rng = np.random.default_rng(61)
a = rng.random((256, 256, 256), dtype=np.float32)
g = vdb.FloatGrid()
g.copyFromArray(a)
g.name = "density"
vdb.write(sys.argv[1], grids=[g])
PY
files=()
for src in "$dense:0.02" "$corpus/real/openvdb_smoke1_houdini_v222.vdb:1" "$corpus/gen/cloud_fbm.vdb:1"; do
  path="${src%:*}" scale="${src##*:}" stem="$(basename "${path%.vdb}")"
  files+=("$path:density:$scale")
  for codec in none zip blosc; do
    nv="$OUT/$stem.$codec.nvdb"
    case $codec in none) flag=() ;; zip) flag=(-z) ;; blosc) flag=(-b) ;; esac
    [ -s "$nv" ] || nanovdb_convert -f "${flag[@]}" -g density "$path" "$nv" >/dev/null
    files+=("$nv:density:$scale")
  done
done
python3 bench/nvdb_bake.py "$ROUNDS" "$U" "${files[@]}"

echo "== 4. the still riemann sweep against NanoVDB's march (bench/still_riemann.py)"
UMBRA="$U" ROUNDS="$ROUNDS" OUT="$OUT/still" python3 bench/still_riemann.py

if [ "${WARP:-0}" = 1 ]; then
  # peer.sh builds its own `ortho_view` (the --release example: a long build).
  echo "== 5. umbra's riemann map against Warp's CPU kernel (bench/peer.sh)"
  ONLY='warp_|umbra_riemann_nvdb' THREADS=2 RES=512x512 CYCLES=0 MITSUBA=0 NANOVDB=0 REPS=3 \
    bash bench/peer.sh 2>&1 | tail -15 || echo "peer.sh failed"
fi
echo "== done $(date -u +%FT%TZ); load $(cut -d' ' -f1-3 /proc/loadavg)"
