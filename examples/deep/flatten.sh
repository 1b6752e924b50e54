#!/usr/bin/env bash
# A deep shadow map, flattened: bake data/cloud.vdb as a flat map and as a deep map on the same
# camera, flatten the deep map with OpenImageIO (`oiiotool --flatten`), and check that its
# full-depth transmittance 1 - A equals the flat map's T within the deep error bound. Writes PNG
# previews of both and prints one deep pixel's samples with the transmittance they describe.
#
#   examples/deep/flatten.sh [OUT_DIR]        (default examples/deep/out)
#
# Environment: UMBRA (the umbra binary; default target/release/umbra, built if missing),
# DEEP_ERROR (default 0.002), RES (long side, default 256), SCALE (density scale, default 4),
# PIXEL (X,Y of the pixel to dump; default the centre). Needs oiiotool (openimageio-tools).
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=$(cd "$here/../.." && pwd)
out=${1:-$here/out}
umbra=${UMBRA:-$root/target/release/umbra}
err=${DEEP_ERROR:-0.002}
res=${RES:-256}
scale=${SCALE:-4}
light=0.3,-1,0.2
vdb=$root/data/cloud.vdb

command -v oiiotool >/dev/null || { echo "flatten.sh: oiiotool is needed (Debian: openimageio-tools)" >&2; exit 1; }
if [[ ! -x $umbra ]]; then
    echo "building umbra (cargo build --release --ignore-rust-version)" >&2
    (cd "$root" && cargo build --release --ignore-rust-version --quiet)
fi
mkdir -p "$out"

echo "== bake: flat map first, then the deep map on its camera (--camera flat.exr)"
"$umbra" bake "$vdb" --light-dir "$light" --density-scale "$scale" --res "$res" \
    -o "$out/flat.exr" --force --quiet
"$umbra" bake "$vdb" --camera "$out/flat.exr" --density-scale "$scale" \
    --deep --deep-error "$err" -o "$out/deep.exr" --force --quiet
oiiotool --info "$out/flat.exr" "$out/deep.exr"

echo
echo "== flatten: composite every pixel's samples front to back (alpha A = 1 - T over the whole ray)"
oiiotool "$out/deep.exr" --flatten -o "$out/deep_flat.exr"
# 1 - A as a channel named T, to compare with the flat map's T.
oiiotool "$out/deep_flat.exr" --ch A --mulc -1 --addc 1 --chnames T -o "$out/deep_flat_T.exr"

echo
echo "== compare 1 - A (flattened deep) with T (flat), failing above the deep error $err"
status=0
report=$(oiiotool -v "$out/deep_flat_T.exr" "$out/flat.exr" --ch T --fail "$err" --diff 2>&1) || status=$?
grep -v '^Reading ' <<<"$report"
max=$(awk '/Max error/ { print $4 }' <<<"$report")
echo "max |(1 - A_flattened) - T_flat| = ${max:-?} (bound $err)"
if (( status != 0 )); then
    echo "flatten.sh: the flattened deep map differs from the flat map by more than $err" >&2
    exit "$status"
fi

echo
echo "== previews (8-bit, linear T like umbra's --preview): flat | flattened deep"
oiiotool "$out/flat.exr" --ch T -d uint8 -o "$out/flat_T.png"
oiiotool "$out/deep_flat_T.exr" -d uint8 -o "$out/deep_flat_T.png"
oiiotool "$out/flat_T.png" "$out/deep_flat_T.png" --mosaic 2x1 -d uint8 -o "$out/side_by_side.png"
ls "$out"/*.png

# One pixel: cut a 1x1 window out of the deep map and dump its samples.
read -r w h < <(oiiotool --info "$out/deep.exr" | sed -E 's/.*: *([0-9]+) x +([0-9]+),.*/\1 \2/')
pixel=${PIXEL:-$((w / 2)),$((h / 2))}
px=${pixel%,*} py=${pixel#*,}
echo
echo "== deep pixel ($px, $py) of $w x $h: oiiotool --cut 1x1+$px+$py, --dumpdata"
oiiotool "$out/deep.exr" --cut "1x1+$px+$py" -o "$out/pixel.exr"
dump=$(oiiotool --dumpdata "$out/pixel.exr" | grep 'Pixel (')
echo "$dump"
echo
echo "the same samples, with the transmittance they leave behind (T after = product of 1 - A):"
awk '{
    sub(/^[^:]*: [0-9]+ samples :? ?/, "")
    n = split($0, s, " / ")
    t = 1
    printf "  %-3s %12s %12s %12s %12s\n", "#", "Z", "ZBack", "A", "T(ZBack)"
    for (i = 1; i <= n; i++) {
        split("", v)
        m = split(s[i], kv, " ")
        for (j = 1; j <= m; j++) { split(kv[j], p, "="); v[p[1]] = p[2] }
        t *= 1 - v["A"]
        printf "  %-3d %12.6f %12.6f %12.8f %12.8f\n", i, v["Z"], v["ZBack"], v["A"], t
    }
}' <<<"$dump"
flat_t=$(oiiotool --dumpdata "$out/flat.exr" | awk -v p="Pixel ($px, $py):" 'index($0, p) { print $NF }')
echo "flat map T at ($px, $py): $flat_t"
