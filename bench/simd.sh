#!/usr/bin/env bash
# The sweep kernel at each SIMD level this CPU runs (UMBRA_SIMD=avx512|avx2|portable caps the
# level, src/regular/kernel): the exact map and the Riemann march (step 1) of the cloud_fbm
# view bench/peer.sh renders, by examples/ortho_view (render time only, median of its --reps),
# levels alternated run by run after a warm-up; BASE=path/to/ortho_view adds an older build as
# one more entry (e.g. one built at an earlier commit). Prints one Markdown table (median over
# ROUNDS of each run's median) and the CPU, its AVX-512 support and the load average.
#
#   bench/simd.sh                                   # 512x512, 2 threads, 5 rounds of 5 reps
#   RES=2048x2048 THREADS=1 ROUNDS=3 bench/simd.sh
set -euo pipefail
cd "$(dirname "$0")/.."

RES=${RES:-512x512}
THREADS=${THREADS:-2}
ROUNDS=${ROUNDS:-5}
REPS=${REPS:-5}
LEVELS=${LEVELS:-"avx512 avx2 portable"}
cargo build --release --ignore-rust-version --example ortho_view >&2
BIN=target/release/examples/ortho_view
VIEW=(../shared/corpus/gen/cloud_fbm.vdb --grid density --scale 5 --dir=0.6,-0.35,-1
    --center=-2.07,1.21,1.93 --up=0,1,0 --frame 4.4 --res "$RES" --threads "$THREADS" --reps "$REPS")

grep -q avx512f /proc/cpuinfo && HAVE=avx512 || { grep -q avx2 /proc/cpuinfo && HAVE=avx2 || HAVE=portable; }
entries=()
for l in $LEVELS; do
    case "$HAVE:$l" in
    avx2:avx512 | portable:avx512 | portable:avx2) continue ;;
    esac
    entries+=("$l")
done
[ -n "${BASE:-}" ] && entries+=(base)

render_s() { sed -nE 's/.*"render_s":([0-9.eE+-]+).*/\1/p'; }
run() { # entry estimator -> render seconds
    local e=$1 est=$2
    if [ "$e" = base ]; then
        "$BASE" "${VIEW[@]}" --estimator "$est" --step 1 | render_s
    else
        UMBRA_SIMD=$e "$BIN" "${VIEW[@]}" --estimator "$est" --step 1 | render_s
    fi
}
median() { sort -g | awk '{ a[NR] = $1 } END { print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2 }'; }

declare -A times
load_before=$(cut -d' ' -f1 /proc/loadavg)
for est in regular riemann; do
    for e in "${entries[@]}"; do run "$e" "$est" >/dev/null; done # warm-up
done
for r in $(seq "$ROUNDS"); do
    for est in regular riemann; do
        for e in "${entries[@]}"; do
            times[$e:$est]+="$(run "$e" "$est") "
        done
    done
done
load_after=$(cut -d' ' -f1 /proc/loadavg)

echo "cloud_fbm $RES, $THREADS threads, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)" \
    "(widest SIMD: $HAVE), median of $ROUNDS rounds of $REPS reps, levels alternated;" \
    "load average $load_before before, $load_after after"
echo
echo "| kernel | exact map (s) | riemann step 1 (s) |"
echo "|---|---|---|"
for e in "${entries[@]}"; do
    a=$(echo "${times[$e:regular]}" | tr ' ' '\n' | grep . | median)
    b=$(echo "${times[$e:riemann]}" | tr ' ' '\n' | grep . | median)
    echo "| $e | $a | $b |"
done
