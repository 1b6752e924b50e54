#!/usr/bin/env bash
# Parallel speed-up and peak memory of a bake: the peer view (bench/peer.sh's presets) rendered
# by examples/ortho_view with every core and with 1 thread, alternating, REPS renders each in one
# process (median render time, so start-up and load are not in it; alternating keeps drift of
# the machine out of the ratio). Prints one Markdown table per file:
# rays/s, speed-up, parallel efficiency (speed-up / threads), and peak RSS against OpenVDB's
# file_mem_bytes plus the image.
#
#   bench/scaling.sh                  # cloud_fbm and data/cloud.vdb, 1024x1024, 7 reps
#   RES=512x512 REPS=5 bench/scaling.sh
set -euo pipefail
cd "$(dirname "$0")/.."
RES=${RES:-1024x1024}
REPS=${REPS:-7}
N=$(nproc)
cargo build --release --ignore-rust-version --example ortho_view >&2
UMBRA=target/release/examples/ortho_view
field() { sed -nE "s/.*\"$1\":([0-9.eE+-]+).*/\\1/p"; }

echo "$RES, median of $REPS renders per cell, $N cores; load average $(cut -d' ' -f1-3 /proc/loadavg)"
for preset in cloud_fbm cloud; do
    case $preset in
    cloud_fbm) FILE=../shared/corpus/gen/cloud_fbm.vdb VIEW=(--scale 5 --dir=0.6,-0.35,-1 --center=-2.07,1.21,1.93 --frame 4.4) ;;
    cloud) FILE=data/cloud.vdb VIEW=(--scale 4 --dir=0.6,-0.35,-1 --center=-2.514,3.1125,4.0815 --frame 6) ;;
    esac
    [ -f "$FILE" ] || continue
    echo
    echo "$(basename "$FILE")"
    echo
    echo "| estimator | rays/s, 1 thread | rays/s, $N threads | speed-up | efficiency | peak RSS (MB) | file_mem_bytes (MB) | image (MB) | peak RSS - start / (1.5 file_mem + image) |"
    echo "|---|---|---|---|---|---|---|---|---|"
    for est in "regular" "riemann --step 1" "residual-ratio --spp 16" "unbiased-raymarch --spp 16"; do
        # shellcheck disable=SC2086
        out=$("$UMBRA" "$FILE" "${VIEW[@]}" --res "$RES" --estimator $est --threads "$N,1" --reps "$REPS")
        read -r rn r1 < <(sed -nE 's/.*"render_s_by_threads":\[([^],]*),([^]]*)\].*/\1 \2/p' <<<"$out")
        rss=$(field peak_rss <<<"$out" | tail -1)
        start=$(field peak_rss_start <<<"$out")
        fmb=$(field file_mem_bytes <<<"$out")
        awk -v e="$est" -v t1="$r1" -v tn="$rn" -v n="$N" -v rss="$rss" -v st="$start" -v f="$fmb" -v res="$RES" 'BEGIN {
            split(res, R, "x"); img = R[1] * R[2] * 4; rays = R[1] * R[2];
            printf "| %s | %.0f | %.0f | %.2f | %.0f%% | %.1f | %.1f | %.1f | %.2f |\n",
                e, rays / t1, rays / tn, t1 / tn, 100 * t1 / tn / n, rss / 1048576, f / 1048576, img / 1048576,
                (rss - st) / (1.5 * f + img) }'
    done
done
