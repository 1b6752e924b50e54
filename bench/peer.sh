#!/usr/bin/env bash
# Peer benchmark: the same orthographic transmittance view rendered by OpenVDB's vdb_render
# (Debian libopenvdb-tools, ray marching at steps 0.5, 1, 2 voxels, -cutoff 0), by Blender's
# Cycles (Debian blender, absorption-only volume, step rate 1 and 2, 1 and 4 spp), by a NanoVDB
# C++ ray marcher (bench/nanovdb_march.cpp on Debian libnanovdb-dev: HDDA empty-space skipping,
# midpoint rule over merged leaf spans at steps 0.25, 0.5, 1 voxel, plus NanoVDB's own
# SampleFromVoxels at step 0.5 as a baseline), by Mitsuba 3 (PyPI mitsuba, llvm_ad_mono: the
# volpath integrator, delta tracking through an albedo-0 heterogeneous medium, 16 spp; and a
# Dr.Jit vectorised midpoint march through an mi.Texture3f of the dense grid, step 0.5 voxel;
# bench/mitsuba_transmittance.py) and by umbra (exact regular tracking, trilinear; Riemann ray
# marching at steps 0.5-2; residual ratio tracking and unbiased ray marching at 1 and 16 samples
# per pixel), same resolution, same thread count. Every renderer runs once as a warm-up, then
# REPS rounds in which each runs once in turn (so slow drift of the machine hits all alike).
# Prints one Markdown table: median wall time of the whole process (start-up, load, render, EXR
# write), median render time as each tool reports it, peak RSS, RMSE against umbra's exact image,
# and wall time and RMSE as ratios to vdb_render at step 1; its header gives the load average
# before, during (highest 1-minute value at the start of a round) and after the runs, and the
# share of the machine's CPU time that other processes took meanwhile (/proc/stat less this
# script's children).
# Installs what is missing: libopenvdb-tools; blender (CYCLES=0 skips Cycles); libnanovdb-dev and
# libnanovdb-tools (NANOVDB=0 skips NanoVDB); python3-openvdb, libllvm19 and a venv with mitsuba
# (MITSUBA=0 skips Mitsuba; Dr.Jit gets DRJIT_LIBLLVM_PATH = Debian's libLLVM.so.19 unless set).
# NanoVDB keeps OpenVDB's voxel convention; Mitsuba's cell-centred grid is placed to match it
# (bench/mitsuba_transmittance.py), so both are scored against umbra's exact image as they are.
#
#   bench/peer.sh                       # gen/cloud_fbm.vdb, 512x512, all cores, 3 rounds
#   PRESET=cloud REPS=5 THREADS=1 RES=256x256 bench/peer.sh
#   REPS=5 RES=512x512 THREADS=2 CYCLES=0 bench/peer.sh
#
# Environment: PRESET (cloud_fbm | cloud | smoke), ONLY (a regex of entry names to run, e.g.
# 'umbra_exact_rays|nanovdb_1$|vdb_render_1$|cycles_rate1_spp1'; the exact references always
# run), RES (512x512), THREADS (nproc), REPS (3), CYCLES (1),
# NANOVDB (1), MITSUBA (1), WARP (1), VENV (bench/.venv, the Python environment with mitsuba),
# WARP_VENV (bench/.venv-warp), OUT
# (directory for images, logs and the table, /tmp/umbra-peer). The view follows
# ../shared/research/peers.md: vdb_render's -absorb is per voxel (= scale x voxel size), rays
# start on the image plane through CENTER and run along DIR; T = 1 - alpha of its EXR.
set -euo pipefail
cd "$(dirname "$0")/.."

PRESET=${PRESET:-cloud_fbm}
RES=${RES:-512x512}
THREADS=${THREADS:-$(nproc)}
REPS=${REPS:-3}
OUT=${OUT:-/tmp/umbra-peer}
VENV=${VENV:-bench/.venv}
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
smoke)
    # A real Houdini smoke (1.0 M active voxels in a 111x222x112 box, half floats).
    FILE=../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb
    SCALE=0.3 VOXEL=0.47619 DIR=0.6,-0.35,-1 CENTER=-34.35,56.21,45.43 UP=0,1,0 FRAME=130
    ;;
*)
    echo "unknown PRESET $PRESET (cloud_fbm | cloud | smoke)" >&2
    exit 2
    ;;
esac

if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
APT_UPDATED=0
apt_install() {
    echo "installing $* ..." >&2
    if [ "$APT_UPDATED" = 0 ]; then
        $SUDO apt-get update >&2 || true
        APT_UPDATED=1
    fi
    $SUDO apt-get install -y "$@" >&2
}

command -v vdb_render >/dev/null || apt_install libopenvdb-tools
cargo build --release --ignore-rust-version --example ortho_view >&2
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

# The render time a run printed (umbra, NanoVDB, Mitsuba: "render_s" of their JSON line;
# vdb_render -v: its ray-tracing step; Cycles: bench/blender_transmittance.py's timer), or the
# wall time when it printed none.
render_seconds() {
    local log=$1 wall=$2 s
    s=$(sed -nE 's/.*"render_s":([0-9.eE+-]+).*/\1/p' "$log" | head -1)
    [ -z "$s" ] && s=$(awk '/ray-tracing/ { getline; if (match($0, /completed in [0-9.eE+-]+/)) print substr($0, RSTART + 13, RLENGTH - 13) }' "$log" | head -1)
    [ -z "$s" ] && s=$(sed -nE 's/^CYCLES_RENDER_SECONDS ([0-9.eE+-]+).*/\1/p' "$log" | head -1)
    echo "${s:-$wall}"
}

rmse() { "$UMBRA" --compare "$1" "$2" | sed -E 's/.*"rmse":([^,}]*).*/\1/'; }

# The entries, in table order: entry NAME "LABEL" "NOTE" IMAGE:CHANNEL REFERENCE:CHANNEL CMD...
declare -a E_NAME E_LABEL E_NOTE E_IMG E_REF E_CMD
entry() {
    E_NAME+=("$1")
    E_LABEL+=("$2")
    E_NOTE+=("$3")
    E_IMG+=("$4")
    E_REF+=("$5")
    shift 5
    E_CMD+=("$(printf '%q ' "$@")")
}
REF="$OUT/umbra_exact.exr:T"

# umbra exact: the reference image of every row but Cycles'
entry umbra_exact "umbra exact (regular tracking, trilinear)" "reference: exact, object-order sweep" "$REF" "$REF" \
    "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --out "$OUT/umbra_exact.exr"
entry umbra_exact_rays "umbra exact, ray order" "exact, one HDDA walk per pixel (before the sweep)" \
    "$OUT/umbra_exact_rays.exr:T" "$REF" \
    "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --order rays --out "$OUT/umbra_exact_rays.exr"
for step in 0.5 1 2; do
    entry "vdb_render_$step" "vdb_render step $step" "-cutoff 0 -shadowstep 1e9" "$OUT/vdb_render_$step.exr:1-A" "$REF" \
        vdb_render "$FILE" "$OUT/vdb_render_$step.exr" -name density \
        -camera ortho -frame "$FRAME" -res "$RES" -translate "$CENTER" -lookat "$LOOKAT" -up "$UPV" \
        -scatter 0,0,0 -absorb "$ABSORB,$ABSORB,$ABSORB" -cutoff 0 -step "$step" -shadowstep 1e9 \
        -light "$(echo "$DIR" | awk -F, '{ printf "%s,%s,%s", -$1, -$2, -$3 }')" -cpus "$THREADS" -v
done
for step in 0.5 1 1.5 2; do
    entry "umbra_riemann_$step" "umbra riemann step $step" "midpoint rule per block chord, object-order sweep, biased" \
        "$OUT/umbra_riemann_$step.exr:T" "$REF" \
        "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --estimator riemann --step "$step" --out "$OUT/umbra_riemann_$step.exr"
done
entry umbra_riemann_rays_1 "umbra riemann step 1, ray order" "the same points, one HDDA walk per pixel (before the sweep marched)" \
    "$OUT/umbra_riemann_rays_1.exr:T" "$REF" \
    "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --estimator riemann --step 1 --order rays --out "$OUT/umbra_riemann_rays_1.exr"
# The unbiased estimators: residual ratio tracking (minorant control) and unbiased ray marching,
# the most efficient unbiased one on this cloud (1 / (MSE x time), docs/performance.md).
for est in residual-ratio unbiased-raymarch; do
    for spp in 1 16; do
        entry "umbra_${est}_$spp" "umbra $est, $spp spp" "unbiased" "$OUT/umbra_${est}_$spp.exr:T" "$REF" \
            "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --estimator "$est" --spp "$spp" --out "$OUT/umbra_${est}_$spp.exr"
    done
done
# Null-collision maps swept block by block against the same maps traced ray by ray (before).
for est in ratio residual-ratio track-length; do
    [ "$est" = residual-ratio ] || entry "umbra_${est}_16" "umbra $est, 16 spp" "unbiased, object-order sweep" \
        "$OUT/umbra_${est}_16.exr:T" "$REF" \
        "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --estimator "$est" --spp 16 --out "$OUT/umbra_${est}_16.exr"
    entry "umbra_${est}_rays_16" "umbra $est, 16 spp, ray order" "unbiased, one HDDA walk per pixel (before the sweep)" \
        "$OUT/umbra_${est}_rays_16.exr:T" "$REF" \
        "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --estimator "$est" --spp 16 --order rays --out "$OUT/umbra_${est}_rays_16.exr"
done

# NanoVDB (NANOVDB=0 skips it): the grid converted once with nanovdb_convert (untimed), then
# bench/nanovdb_march.cpp built with g++ -O3 -march=native. Same voxel convention as OpenVDB.
if [ "${NANOVDB:-1}" = 1 ]; then
    if ! command -v nanovdb_convert >/dev/null || [ ! -f /usr/include/nanovdb/NanoVDB.h ]; then
        apt_install libnanovdb-dev libnanovdb-tools
    fi
    NANO="$OUT/nanovdb_march"
    if [ ! -x "$NANO" ] || [ bench/nanovdb_march.cpp -nt "$NANO" ]; then
        g++ -O3 -march=native -std=c++17 -pthread -o "$NANO" bench/nanovdb_march.cpp
    fi
    NVDB="$OUT/$PRESET.nvdb"
    [ "$NVDB" -nt "$FILE" ] || nanovdb_convert -f -g density "$FILE" "$NVDB" >&2
    for step in 0.25 0.5 1; do
        entry "nanovdb_$step" "NanoVDB march step $step" "HDDA spans, midpoint rule, corners from the leaf" \
            "$OUT/nanovdb_$step.exr:T" "$REF" \
            "$NANO" "$NVDB" "${VIEW[@]}" --threads "$THREADS" --step "$step" --out "$OUT/nanovdb_$step.exr"
    done
    entry nanovdb_sfv_0.5 "NanoVDB march step 0.5, SampleFromVoxels" "same spans, nanovdb::SampleFromVoxels<acc, 1> lookups" \
        "$OUT/nanovdb_sfv_0.5.exr:T" "$REF" \
        "$NANO" "$NVDB" "${VIEW[@]}" --threads "$THREADS" --step 0.5 --sampler nanovdb --out "$OUT/nanovdb_sfv_0.5.exr"
fi

# NVIDIA Warp (WARP=0 skips it; issue 61): bench/warp_march.py, a fixed-step trilinear march of
# wp.Volume on Warp's CPU device over the same .nvdb (NanoVDB's voxel convention, so scored
# against umbra's exact image as it is). Its "render_s" is the kernel alone: wp.init, the .nvdb
# load and the first launch (the kernel's compile) are excluded; Warp's CPU device runs a
# launch on one OS thread whatever THREADS says. WARP_VENV (bench/.venv-warp) gets warp-lang,
# numpy and OpenEXR from PyPI when it lacks them.
if [ "${WARP:-1}" = 1 ]; then
    WARP_VENV=${WARP_VENV:-bench/.venv-warp}
    if ! "$WARP_VENV/bin/python" -c 'import warp, OpenEXR, numpy' 2>/dev/null; then
        echo "creating $WARP_VENV with warp-lang ..." >&2
        python3 -m venv "$WARP_VENV"
        "$WARP_VENV/bin/pip" install --quiet warp-lang numpy "OpenEXR>=3.2" >&2
    fi
    command -v nanovdb_convert >/dev/null || apt_install libnanovdb-tools
    NVDB="$OUT/$PRESET.nvdb"
    [ "$NVDB" -nt "$FILE" ] || nanovdb_convert -f -g density "$FILE" "$NVDB" >&2
    for step in 0.5 1; do
        entry "warp_$step" "Warp CPU march step $step (kernel time, 1 thread)" "wp.Volume volume_sample_f LINEAR, no empty-space skipping" \
            "$OUT/warp_$step.exr:T" "$REF" \
            "$WARP_VENV/bin/python" bench/warp_march.py "$NVDB" "$OUT/warp_$step.exr" "${VIEW[@]}" --step "$step" --reps 1
        # umbra on Warp's input: the same .nvdb, view and step (its whole process is the wall time).
        entry "umbra_riemann_nvdb_$step" "umbra riemann step $step, the .nvdb" "the Warp row's file, view and step; object-order sweep" \
            "$OUT/umbra_riemann_nvdb_$step.exr:T" "$REF" \
            "$UMBRA" "$NVDB" "${VIEW[@]}" --threads "$THREADS" --estimator riemann --step "$step" --out "$OUT/umbra_riemann_nvdb_$step.exr"
    done
fi

# Mitsuba 3 (MITSUBA=0 skips it): the grid copied once to a dense array with a zero margin
# (bench/vdb_dense.py, pyopenvdb; untimed), placed with Mitsuba's cell-centred convention.
if [ "${MITSUBA:-1}" = 1 ]; then
    /usr/bin/python3 -c 'import pyopenvdb, numpy' 2>/dev/null || apt_install python3-openvdb python3-numpy
    LIBLLVM=$(ls /usr/lib/*/libLLVM.so.19* 2>/dev/null | head -1 || true)
    if [ -z "$LIBLLVM" ]; then
        apt_install libllvm19
        LIBLLVM=$(ls /usr/lib/*/libLLVM.so.19* | head -1)
    fi
    export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-$LIBLLVM}
    if ! "$VENV/bin/python" -c 'import mitsuba' 2>/dev/null; then
        echo "creating $VENV with mitsuba ..." >&2
        python3 -m venv "$VENV" >&2 || { apt_install python3-venv && /usr/bin/python3 -m venv "$VENV" >&2; }
        "$VENV/bin/pip" install --quiet mitsuba==3.9.1 numpy >&2
    fi
    DENSE="$OUT/${PRESET}_dense.npz"
    [ "$DENSE" -nt "$FILE" ] || /usr/bin/python3 bench/vdb_dense.py "$FILE" density "$DENSE"
    MITSUBA_PY=("$VENV/bin/python" bench/mitsuba_transmittance.py "$DENSE")
    entry mitsuba_volpath_16 "Mitsuba 3 volpath, 16 spp" "llvm_ad_mono, albedo 0, delta tracking, global majorant, unbiased" \
        "$OUT/mitsuba_volpath_16.exr:Y" "$REF" \
        "${MITSUBA_PY[@]}" "$OUT/mitsuba_volpath_16.exr" --mode volpath --spp 16 "${VIEW[@]}" --threads "$THREADS"
    entry drjit_march_0.5 "Dr.Jit march step 0.5 (Mitsuba Texture3f)" "llvm_ad_mono, dense box, no empty-space skipping" \
        "$OUT/drjit_march_0.5.exr:Y" "$REF" \
        "${MITSUBA_PY[@]}" "$OUT/drjit_march_0.5.exr" --mode march --step 0.5 "${VIEW[@]}" --threads "$THREADS"
fi

# Blender Cycles (CYCLES=0 skips it): an absorption-only volume in front of a white world. Cycles
# puts voxel (i,j,k) at index (i,j,k)+0.5, so its images are scored against umbra's exact image of
# the grid shifted by half a voxel (../shared/research/peers.md section 3).
if [ "${CYCLES:-1}" = 1 ]; then
    command -v blender >/dev/null || apt_install blender
    "$UMBRA" "$FILE" "${VIEW[@]}" --threads "$THREADS" --index-offset 0.5 --out "$OUT/umbra_exact_half.exr" >"$OUT/umbra_exact_half.log"
    for cfg in "1 1" "1 4" "2 1"; do
        read -r rate spp <<<"$cfg"
        name="cycles_rate${rate}_spp$spp"
        entry "$name" "Cycles step rate $rate, $spp spp" "reference: exact, grid shifted +0.5 voxel" \
            "$OUT/$name.exr:R" "$OUT/umbra_exact_half.exr:T" \
            blender -b --factory-startup -P bench/blender_transmittance.py -- \
            "$FILE" "$OUT/$name.exr" "${VIEW[@]}" --step-rate "$rate" --spp "$spp" --threads "$THREADS"
    done
fi

# ONLY=REGEX keeps the entries whose name matches (plus the exact images they are scored against).
if [ -n "${ONLY:-}" ]; then
    declare -a K_NAME K_LABEL K_NOTE K_IMG K_REF K_CMD
    for i in "${!E_NAME[@]}"; do
        if [[ ${E_NAME[$i]} =~ ^umbra_exact(_half)?$ || ${E_NAME[$i]} =~ $ONLY ]]; then
            K_NAME+=("${E_NAME[$i]}") K_LABEL+=("${E_LABEL[$i]}") K_NOTE+=("${E_NOTE[$i]}")
            K_IMG+=("${E_IMG[$i]}") K_REF+=("${E_REF[$i]}") K_CMD+=("${E_CMD[$i]}")
        fi
    done
    E_NAME=("${K_NAME[@]}") E_LABEL=("${K_LABEL[@]}") E_NOTE=("${K_NOTE[@]}")
    E_IMG=("${K_IMG[@]}") E_REF=("${K_REF[@]}") E_CMD=("${K_CMD[@]}")
fi

# run_once I: one timed run of entry I, appending to its wall, render and RSS lists.
run_once() {
    local i=$1 name=${E_NAME[$1]} wall kb
    eval "/usr/bin/time -f '%e %M' -o \"\$OUT/\$name.time1\" ${E_CMD[$i]}" >"$OUT/$name.log" 2>&1 || {
        echo "$name failed; its log, $OUT/$name.log, ends with:" >&2
        tail -5 "$OUT/$name.log" >&2
        exit 1
    }
    read -r wall kb <"$OUT/$name.time1"
    echo "$wall" >>"$OUT/$name.times"
    render_seconds "$OUT/$name.log" "$wall" >>"$OUT/$name.render"
    echo "$kb" >>"$OUT/$name.rss"
}

# CPU time of the whole machine (busy and total jiffies, /proc/stat) and of this script's
# children (bash's `times`), so that the header can say how much of the machine other
# processes took while the renderers ran.
cpu_jiffies() { awk '/^cpu / { b = $2 + $3 + $4 + $7 + $8 + $9; print b, b + $5 + $6 }' /proc/stat; }
# (`times` must run in this shell, not in a pipeline's or a substitution's subshell.)
children_seconds() {
    times >"$OUT/times.txt"
    awk 'NR == 2 { s = 0; for (i = 1; i <= 2; i++) { split($i, a, /[ms]/); s += a[1] * 60 + a[2] }; print s }' "$OUT/times.txt"
}

N=${#E_NAME[@]}
LOAD_BEFORE=$(cut -d' ' -f1-3 /proc/loadavg)
read -r BUSY0 TOTAL0 < <(cpu_jiffies)
children_seconds >"$OUT/ours0.txt"
OURS0=$(cat "$OUT/ours0.txt")
echo "warm-up: $N renderers once each ..." >&2
for i in $(seq 0 $((N - 1))); do
    : >"$OUT/${E_NAME[$i]}.times"
    : >"$OUT/${E_NAME[$i]}.render"
    : >"$OUT/${E_NAME[$i]}.rss"
    run_once "$i"
    : >"$OUT/${E_NAME[$i]}.times"
    : >"$OUT/${E_NAME[$i]}.render"
    : >"$OUT/${E_NAME[$i]}.rss"
done
LOAD_MAX=0
for rep in $(seq "$REPS"); do
    l=$(cut -d' ' -f1 /proc/loadavg)
    LOAD_MAX=$(awk -v a="$LOAD_MAX" -v b="$l" 'BEGIN { print (b > a) ? b : a }')
    echo "round $rep of $REPS (load average $l) ..." >&2
    for i in $(seq 0 $((N - 1))); do
        run_once "$i"
    done
done
LOAD_AFTER=$(cut -d' ' -f1-3 /proc/loadavg)
read -r BUSY1 TOTAL1 < <(cpu_jiffies)
children_seconds >"$OUT/ours1.txt"
OTHERS=$(awk -v b0="$BUSY0" -v t0="$TOTAL0" -v b1="$BUSY1" -v t1="$TOTAL1" -v o0="$OURS0" -v o1="$(cat "$OUT/ours1.txt")" -v hz="$(getconf CLK_TCK)" \
    'BEGIN { o = ((b1 - b0) / hz - (o1 - o0)) / ((t1 - t0) / hz) * 100; printf "%.0f", (o < 0) ? 0 : o }')

declare -a ROWS
for i in $(seq 0 $((N - 1))); do
    name=${E_NAME[$i]}
    wall=$(median <"$OUT/$name.times")
    render=$(median <"$OUT/$name.render")
    kb=$(sort -n "$OUT/$name.rss" | tail -1)
    if [ "${E_IMG[$i]}" = "$REF" ]; then err=0; else err=$(rmse "${E_IMG[$i]}" "${E_REF[$i]}"); fi
    ROWS+=("${E_LABEL[$i]}|$wall|$render|$kb|$err|${E_NOTE[$i]}")
done

# The vdb_render step 1 row is the yardstick of both ratios.
base=$(printf '%s\n' "${ROWS[@]}" | awk -F'|' '$1 == "vdb_render step 1" { print $2, $5 }')
{
    echo "$(basename "$FILE"), $RES, $THREADS threads, median of $REPS runs after a warm-up, renderers alternated run by run; load average before: $LOAD_BEFORE, highest at a round's start: $LOAD_MAX, after: $LOAD_AFTER ($(nproc) cores); other processes used $OTHERS % of the machine's CPU time during the runs"
    echo
    echo "| renderer | wall (s) | render (s) | peak RSS (MB) | RMSE | wall / vdb_render step 1 | RMSE / vdb_render step 1 | note |"
    echo "|---|---|---|---|---|---|---|---|"
    # Without a vdb_render step 1 row (ONLY=...), the ratio columns are "-".
    printf '%s\n' "${ROWS[@]}" | awk -F'|' -v base="$base" 'BEGIN { n = split(base, B, " ") } {
        if (n == 2 && B[1] > 0 && B[2] > 0) { w = sprintf("%.3f", $2 / B[1]); r = sprintf("%.3f", $5 / B[2]) } else { w = "-"; r = "-" }
        printf "| %s | %.3f | %.3f | %.1f | %.2e | %s | %s | %s |\n", $1, $2, $3, $4 / 1024, $5, w, r, $6 }'
} | tee "$OUT/peer.md"
