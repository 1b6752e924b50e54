#!/usr/bin/env bash
# Peer benchmark: the same orthographic transmittance view rendered by OpenVDB's vdb_render
# (Debian libopenvdb-tools, ray marching at steps 0.5, 1, 2 voxels, -cutoff 0), by Blender's
# Cycles (Debian blender, absorption-only volume, step rate 1 and 2, 1 and 4 spp) and by umbra
# (exact regular tracking, trilinear; Riemann ray marching at steps 0.5-2; residual ratio
# tracking and unbiased ray marching at 1 and 16 samples per pixel), same resolution, same
# thread count, several runs each. Prints one Markdown table: median wall time of the whole
# process (start-up, load, render, EXR write), median render time as each tool reports it,
# peak RSS, RMSE against umbra's exact image, and wall time and RMSE as ratios to vdb_render at
# step 1. Installs libopenvdb-tools and blender when they are missing (CYCLES=0 skips Cycles).
#
#   bench/peer.sh                       # gen/cloud_fbm.vdb, 512x512, all cores, 3 runs
#   PRESET=cloud REPS=5 THREADS=1 RES=256x256 bench/peer.sh
#
# Environment: PRESET (cloud_fbm | cloud), RES (512x512), THREADS (nproc), REPS (3), CYCLES (1),
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

# The render time a run printed (umbra: "render_s", vdb_render -v: its ray-tracing step,
# Cycles: bench/blender_transmittance.py's timer), or the wall time when it printed none.
render_seconds() {
    local log=$1 wall=$2 s
    s=$(sed -nE 's/.*"render_s":([0-9.eE+-]+).*/\1/p' "$log" | head -1)
    [ -z "$s" ] && s=$(awk '/ray-tracing/ { getline; if (match($0, /completed in [0-9.eE+-]+/)) print substr($0, RSTART + 13, RLENGTH - 13) }' "$log" | head -1)
    [ -z "$s" ] && s=$(sed -nE 's/^CYCLES_RENDER_SECONDS ([0-9.eE+-]+).*/\1/p' "$log" | head -1)
    echo "${s:-$wall}"
}

# run NAME CMD...: REPS timed runs of the whole process; prints "median_wall median_render peak_rss_kb".
run() {
    local name=$1
    shift
    : >"$OUT/$name.times"
    : >"$OUT/$name.render"
    local rss=0
    for _ in $(seq "$REPS"); do
        /usr/bin/time -f "%e %M" -o "$OUT/$name.time1" "$@" >"$OUT/$name.log" 2>&1
        read -r wall kb <"$OUT/$name.time1"
        echo "$wall" >>"$OUT/$name.times"
        render_seconds "$OUT/$name.log" "$wall" >>"$OUT/$name.render"
        [ "$kb" -gt "$rss" ] && rss=$kb
    done
    echo "$(median <"$OUT/$name.times") $(median <"$OUT/$name.render") $rss"
}

rmse() { "$UMBRA" --compare "$1" "$2" | sed -E 's/.*"rmse":([^,}]*).*/\1/'; }

LOAD_BEFORE=$(cut -d' ' -f1-3 /proc/loadavg)
declare -a ROWS
add_row() { ROWS+=("$1|$2|$3|$4|$5|$6"); } # name|wall|render|rss_kb|rmse|note

# umbra exact: the reference image of every row but Cycles'
read -r wall render kb < <(run umbra_exact "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --out "$OUT/umbra_exact.exr")
REF="$OUT/umbra_exact.exr:T"
add_row "umbra exact (regular tracking, trilinear)" "$wall" "$render" "$kb" 0 "reference: exact"

for step in 0.5 1 2; do
    read -r wall render kb < <(run "vdb_render_$step" vdb_render "$FILE" "$OUT/vdb_render_$step.exr" -name density \
        -camera ortho -frame "$FRAME" -res "$RES" -translate "$CENTER" -lookat "$LOOKAT" -up "$UPV" \
        -scatter 0,0,0 -absorb "$ABSORB,$ABSORB,$ABSORB" -cutoff 0 -step "$step" -shadowstep 1e9 \
        -light "$(echo "$DIR" | awk -F, '{ printf "%s,%s,%s", -$1, -$2, -$3 }')" -cpus "$THREADS" -v)
    add_row "vdb_render step $step" "$wall" "$render" "$kb" "$(rmse "$OUT/vdb_render_$step.exr:1-A" "$REF")" "-cutoff 0 -shadowstep 1e9"
done
for step in 0.5 1 1.5 2; do
    read -r wall render kb < <(run "umbra_riemann_$step" "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" \
        --estimator riemann --step "$step" --out "$OUT/umbra_riemann_$step.exr")
    add_row "umbra riemann step $step" "$wall" "$render" "$kb" "$(rmse "$OUT/umbra_riemann_$step.exr:T" "$REF")" "midpoint rule per HDDA segment, biased"
done
# The unbiased estimators: residual ratio tracking (minorant control) and unbiased ray marching,
# the most efficient unbiased one on this cloud (1 / (MSE x time), docs/performance.md).
for est in residual-ratio unbiased-raymarch; do
    for spp in 1 16; do
        read -r wall render kb < <(run "umbra_${est}_$spp" "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" \
            --estimator "$est" --spp "$spp" --out "$OUT/umbra_${est}_$spp.exr")
        add_row "umbra $est, $spp spp" "$wall" "$render" "$kb" "$(rmse "$OUT/umbra_${est}_$spp.exr:T" "$REF")" "unbiased"
    done
done

# Blender Cycles (CYCLES=0 skips it): an absorption-only volume in front of a white world. Cycles
# puts voxel (i,j,k) at index (i,j,k)+0.5, so its images are scored against umbra's exact image of
# the grid shifted by half a voxel (../shared/research/peers.md section 3).
if [ "${CYCLES:-1}" = 1 ]; then
    if ! command -v blender >/dev/null; then
        echo "installing blender (Cycles)..." >&2
        if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
        $SUDO apt-get install -y blender >&2
    fi
    "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --index-offset 0.5 --out "$OUT/umbra_exact_half.exr" >"$OUT/umbra_exact_half.log"
    for cfg in "1 1" "1 4" "2 1"; do
        read -r rate spp <<<"$cfg"
        name="cycles_rate${rate}_spp$spp"
        read -r wall render kb < <(run "$name" blender -b --factory-startup -P bench/blender_transmittance.py -- \
            "$FILE" "$OUT/$name.exr" "${VIEW[@]}" --step-rate "$rate" --spp "$spp" --threads "$THREADS")
        add_row "Cycles step rate $rate, $spp spp" "$wall" "$render" "$kb" \
            "$(rmse "$OUT/$name.exr:R" "$OUT/umbra_exact_half.exr:T")" "reference: exact, grid shifted +0.5 voxel"
    done
fi
LOAD_AFTER=$(cut -d' ' -f1-3 /proc/loadavg)

# The vdb_render step 1 row is the yardstick of both ratios.
base=$(printf '%s\n' "${ROWS[@]}" | awk -F'|' '$1 == "vdb_render step 1" { print $2, $5 }')
{
    echo "$(basename "$FILE"), $RES, $THREADS threads, median of $REPS runs; load average before: $LOAD_BEFORE, after: $LOAD_AFTER ($(nproc) cores)"
    echo
    echo "| renderer | wall (s) | render (s) | peak RSS (MB) | RMSE | wall / vdb_render step 1 | RMSE / vdb_render step 1 | note |"
    echo "|---|---|---|---|---|---|---|---|"
    printf '%s\n' "${ROWS[@]}" | awk -F'|' -v base="$base" 'BEGIN { split(base, B, " ") } {
        printf "| %s | %.3f | %.3f | %.1f | %.2e | %.3f | %.3f | %s |\n", $1, $2, $3, $4 / 1024, $5, $2 / B[1], $5 / B[2], $6 }'
} | tee "$OUT/peer.md"
