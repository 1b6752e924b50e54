#!/usr/bin/env bash
# Peer benchmark: the same orthographic transmittance view rendered by OpenVDB's vdb_render
# (Debian libopenvdb-tools, ray marching at steps 0.5, 1, 2 voxels, -cutoff 0) and by umbra
# (exact regular tracking, trilinear; Riemann ray marching at the same steps; residual ratio
# tracking at 1, 4 and 16 samples per pixel), same resolution, same thread count, several
# runs each. Prints one Markdown table: median wall time of the whole process (load, render,
# EXR write), RMSE against umbra's exact image, and both as ratios to vdb_render at step 1.
#
#   bench/peer.sh                       # gen/cloud_fbm.vdb, 512x512, all cores, 3 runs
#   PRESET=cloud REPS=5 THREADS=1 RES=256x256 bench/peer.sh
#
# Environment: PRESET (cloud_fbm | cloud), RES (512x512), THREADS (nproc), REPS (3),
# OUT (directory for images and the table, /tmp/umbra-peer). The view follows
# ../shared/research/peers.md: vdb_render's -absorb is per voxel (= scale x voxel size), rays
# start on the image plane through CENTER and run along DIR; T = 1 - alpha of its EXR.
set -euo pipefail
cd "$(dirname "$0")/.."

PRESET=${PRESET:-cloud_fbm}
RES=${RES:-512x512}
THREADS=${THREADS:-$(nproc)}
REPS=${REPS:-3}
OUT=${OUT:-/tmp/umbra-peer}
mkdir -p "$OUT"

case "$PRESET" in
cloud_fbm)
    FILE=../shared/corpus/gen/cloud_fbm.vdb
    SCALE=5 VOXEL=0.02 DIR=0.6,-0.35,-1 CENTER=-2.07,1.21,1.93 UP=0,1,0 FRAME=4.4
    ;;
cloud)
    FILE=data/cloud.vdb
    SCALE=4 VOXEL=0.05 DIR=0.6,-0.35,-1 CENTER=-2.514,3.1125,4.0815 UP=0,1,0 FRAME=6
    ;;
*)
    echo "unknown PRESET $PRESET (cloud_fbm | cloud)" >&2
    exit 2
    ;;
esac

if ! command -v vdb_render >/dev/null; then
    echo "installing libopenvdb-tools (vdb_render)..." >&2
    if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
    $SUDO apt-get install -y libopenvdb-tools >&2
fi
cargo build --release --example ortho_view >&2
UMBRA=target/release/examples/ortho_view

# The orthonormal camera up vector and look-at point vdb_render wants (OpenVDB math::aim).
read -r UPV LOOKAT ABSORB < <(awk -v d="$DIR" -v u="$UP" -v c="$CENTER" -v s="$SCALE" -v v="$VOXEL" 'BEGIN {
    split(d, D, ","); split(u, U, ","); split(c, C, ",");
    n = sqrt(D[1]^2 + D[2]^2 + D[3]^2); for (i = 1; i <= 3; i++) D[i] /= n;
    k = U[1]*D[1] + U[2]*D[2] + U[3]*D[3]; for (i = 1; i <= 3; i++) U[i] -= k * D[i];
    n = sqrt(U[1]^2 + U[2]^2 + U[3]^2); for (i = 1; i <= 3; i++) U[i] /= n;
    printf "%.17g,%.17g,%.17g %.17g,%.17g,%.17g %.17g\n", U[1], U[2], U[3],
        C[1] + D[1], C[2] + D[2], C[3] + D[3], s * v }')

VIEW=(--scale "$SCALE" "--dir=$DIR" "--center=$CENTER" "--up=$UPV" --frame "$FRAME" --res "$RES")

# median of the numbers on stdin
median() { sort -g | awk '{ a[NR] = $1 } END { print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2 }'; }

# run NAME CMD...: REPS timed runs of the whole process; prints "median_wall peak_rss_kb".
run() {
    local name=$1
    shift
    : >"$OUT/$name.times"
    local rss=0
    for _ in $(seq "$REPS"); do
        /usr/bin/time -f "%e %M" -o "$OUT/$name.time1" "$@" >"$OUT/$name.log" 2>&1
        read -r wall kb <"$OUT/$name.time1"
        echo "$wall" >>"$OUT/$name.times"
        [ "$kb" -gt "$rss" ] && rss=$kb
    done
    echo "$(median <"$OUT/$name.times") $rss"
}

rmse() { "$UMBRA" --compare "$1" "$2" | sed -E 's/.*"rmse":([^,}]*).*/\1/'; }

LOAD_BEFORE=$(cut -d' ' -f1-3 /proc/loadavg)
declare -a ROWS
add_row() { ROWS+=("$1|$2|$3|$4|$5"); } # name|wall|rss_kb|rmse|note

# umbra exact: the reference image
read -r wall kb < <(run umbra_exact "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --out "$OUT/umbra_exact.exr")
REF="$OUT/umbra_exact.exr:T"
add_row "umbra exact (regular tracking, trilinear)" "$wall" "$kb" 0 "reference"

for step in 0.5 1 2; do
    read -r wall kb < <(run "vdb_render_$step" vdb_render "$FILE" "$OUT/vdb_render_$step.exr" -name density \
        -camera ortho -frame "$FRAME" -res "$RES" -translate "$CENTER" -lookat "$LOOKAT" -up "$UPV" \
        -scatter 0,0,0 -absorb "$ABSORB,$ABSORB,$ABSORB" -cutoff 0 -step "$step" -shadowstep 1e9 \
        -light "$(echo "$DIR" | awk -F, '{ printf "%s,%s,%s", -$1, -$2, -$3 }')" -cpus "$THREADS")
    add_row "vdb_render step $step" "$wall" "$kb" "$(rmse "$OUT/vdb_render_$step.exr:1-A" "$REF")" "-cutoff 0 -shadowstep 1e9"
done
for step in 0.5 1 2; do
    read -r wall kb < <(run "umbra_riemann_$step" "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" \
        --estimator riemann --step "$step" --out "$OUT/umbra_riemann_$step.exr")
    add_row "umbra riemann step $step" "$wall" "$kb" "$(rmse "$OUT/umbra_riemann_$step.exr:T" "$REF")" "midpoint per HDDA segment"
done
for spp in 1 4 16; do
    read -r wall kb < <(run "umbra_rrt_$spp" "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" \
        --estimator residual-ratio --spp "$spp" --out "$OUT/umbra_rrt_$spp.exr")
    add_row "umbra residual ratio tracking, $spp spp" "$wall" "$kb" "$(rmse "$OUT/umbra_rrt_$spp.exr:T" "$REF")" "unbiased"
done
LOAD_AFTER=$(cut -d' ' -f1-3 /proc/loadavg)

# The vdb_render step 1 row is the yardstick of both ratios.
base=$(printf '%s\n' "${ROWS[@]}" | awk -F'|' '$1 == "vdb_render step 1" { print $2, $4 }')
{
    echo "$(basename "$FILE"), $RES, $THREADS threads, median of $REPS runs; load average before: $LOAD_BEFORE, after: $LOAD_AFTER ($(nproc) cores)"
    echo
    echo "| renderer | wall (s) | peak RSS (MB) | RMSE vs umbra exact | time / vdb_render step 1 | RMSE / vdb_render step 1 | note |"
    echo "|---|---|---|---|---|---|---|"
    printf '%s\n' "${ROWS[@]}" | awk -F'|' -v base="$base" 'BEGIN { split(base, B, " ") } {
        printf "| %s | %.2f | %.1f | %.2e | %.3f | %.3f | %s |\n", $1, $2, $3 / 1024, $4, $2 / B[1], $4 / B[2], $5 }'
} | tee "$OUT/peer.md"
