#!/usr/bin/env bash
# A light inside the volume: an exact 6 x N^2 cube map (`umbra bake --omni cube`, six pinholes
# swept in object order) against six aimed 90-degree pinhole bakes of the same faces traced ray
# by ray (`ortho_view --pinhole --order rays`: the only way before omni maps, since the sweep
# declined a light inside the box) and the same six faces swept one bake at a time
# (`--order auto`). Configurations alternate round by round, the first round is a warm-up;
# prints the median render seconds (umbra's `seconds`, ortho_view's `render_s` summed over
# the faces).
#
#   RES=512 THREADS=2 REPS=5 bash bench/omni.sh
set -euo pipefail
cd "$(dirname "$0")/.."
FILE=${FILE:-../shared/corpus/gen/cloud_fbm.vdb}
SCALE=${SCALE:-5}
LIGHT=${LIGHT:-0,0,0} # inside cloud_fbm's box [-1.92, 1.90] x [-1.24, 1.26] x [-1.58, 1.48]
RES=${RES:-512}
THREADS=${THREADS:-$(nproc)}
REPS=${REPS:-5}
OUT=${OUT:-/tmp/umbra-omni}
mkdir -p "$OUT"
cargo build --release --ignore-rust-version --bin umbra --example ortho_view -q
UMBRA=target/release/umbra
VIEW=target/release/examples/ortho_view
IFS=, read -r LX LY LZ <<<"$LIGHT"
FACES=("1,0,0" "-1,0,0" "0,1,0" "0,-1,0" "0,0,1" "0,0,-1")
UPS=("0,1,0" "0,1,0" "0,0,-1" "0,0,1" "0,1,0" "0,1,0")
cube() {
    "$UMBRA" bake "$FILE" --density-scale "$SCALE" --light-pos "$LIGHT" --omni cube \
        --res "$RES" --threads "$THREADS" -o "$OUT/cube.exr" --force --quiet --json |
        python3 -c 'import json,sys; print(json.load(sys.stdin)["seconds"])'
}
faces() { # order
    local total=0 k d c s
    for k in 0 1 2 3 4 5; do
        d=${FACES[$k]}
        IFS=, read -r dx dy dz <<<"$d"
        # The plane one unit in front of the light, a frame of 2: a 90-degree pinhole at LIGHT.
        c="$(python3 -c "print(f'{$LX+$dx},{$LY+$dy},{$LZ+$dz}')")"
        s=$("$VIEW" "$FILE" --grid density --scale "$SCALE" --dir="$d" --center="$c" \
            --up="${UPS[$k]}" --frame 2 --pinhole 1 --res "${RES}x${RES}" --threads "$THREADS" \
            --order "$1" | python3 -c 'import json,sys; print(json.load(sys.stdin)["render_s"])')
        total=$(python3 -c "print($total + $s)")
    done
    echo "$total"
}
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
cube >/dev/null
faces rays >/dev/null
faces auto >/dev/null
A=() B=() C=()
for _ in $(seq "$REPS"); do
    A+=("$(cube)")
    B+=("$(faces rays)")
    C+=("$(faces auto)")
done
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print a[int((NR + 1) / 2)]}'; }
echo "| light $LIGHT in $(basename "$FILE"), 6 x ${RES}^2, $THREADS threads | render (s) |"
echo "|---|---|"
echo "| umbra bake --omni cube (sweep, six faces) | $(median "${A[@]}") |"
echo "| six 90-degree pinholes, rays (before) | $(median "${B[@]}") |"
echo "| six 90-degree pinholes, swept one by one | $(median "${C[@]}") |"
