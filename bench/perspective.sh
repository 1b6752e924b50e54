#!/usr/bin/env bash
# Perspective maps: the exact sweep against the exact ray path and Riemann (ray path) at a few
# steps, on bench/peer.sh's views seen through a pinhole DIST in front of the view's centre
# (`ortho_view --pinhole DIST`: the same frame at the centre, so a field of view of
# 2 atan(FRAME / 2 DIST)). Every configuration runs once per round, rounds alternate, the first
# round is a warm-up; prints the median render seconds and the RMSE against the exact image.
#
#   PRESET=cloud_fbm|smoke RES=512x512 THREADS=2 REPS=5 bash bench/perspective.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PRESET=${PRESET:-cloud_fbm}
RES=${RES:-512x512}
THREADS=${THREADS:-$(nproc)}
REPS=${REPS:-5}
OUT=${OUT:-/tmp/umbra-perspective}
mkdir -p "$OUT"
case "$PRESET" in
cloud_fbm)
    FILE=../shared/corpus/gen/cloud_fbm.vdb
    VIEW=(--scale 5 --dir=0.6,-0.35,-1 --center=-2.07,1.21,1.93 --up=0,1,0 --frame 4.4)
    DIST=4
    ;;
smoke)
    FILE=../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb
    VIEW=(--scale 0.3 --dir=0.6,-0.35,-1 --center=-34.35,56.21,45.43 --up=0,1,0 --frame 130)
    DIST=120
    ;;
*)
    echo "unknown PRESET $PRESET (cloud_fbm | smoke)" >&2
    exit 2
    ;;
esac
cargo build --release --ignore-rust-version --example ortho_view -q
BIN=target/release/examples/ortho_view
CONF=("regular auto" "regular rays" "riemann 1" "riemann 2" "riemann 4")
run() { # name est order-or-step [extra...]
    local est=$1 arg=$2
    shift 2
    local extra=(--estimator "$est")
    if [ "$est" = regular ]; then extra+=(--order "$arg"); else extra+=(--step "$arg"); fi
    "$BIN" "$FILE" --grid density "${VIEW[@]}" --pinhole "$DIST" --res "$RES" \
        --threads "$THREADS" "${extra[@]}" "$@"
}
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
for c in "${CONF[@]}"; do
    set -- $c
    run "$1" "$2" --out "$OUT/$1-$2.exr" >/dev/null
done
declare -A T
for _ in $(seq "$REPS"); do
    for c in "${CONF[@]}"; do
        set -- $c
        T[$c]+="$(run "$1" "$2" | python3 -c 'import json,sys; print(json.load(sys.stdin)["render_s"])') "
    done
done
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "| $PRESET $RES, $THREADS threads, pinhole $DIST | render (s) | RMSE |"
echo "|---|---|---|"
for c in "${CONF[@]}"; do
    set -- $c
    rmse=$("$BIN" --compare "$OUT/$1-$2.exr:T" "$OUT/regular-auto.exr:T" |
        python3 -c 'import json,sys; print("%.1e" % json.load(sys.stdin)["rmse"])')
    med=$(echo "${T[$c]}" | python3 -c 'import statistics,sys; print("%.3f" % statistics.median(map(float, sys.stdin.read().split())))')
    echo "| $c | $med | $rmse |"
done
