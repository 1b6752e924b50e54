#!/usr/bin/env bash
# A USD shot in, shadow maps out: write an animated shot with usd-core (make_shot.py), bake every
# frame under each of its lights with one batch job (lights and frames read from the stage), put
# frame 2's sun map back on the sun with --usd-out, and tile the previews into one picture.
#
#   bash examples/usd/run.sh [OUT_DIR]      (default examples/usd/out)
#
# Needs python3 with venv (usd-core is installed into OUT_DIR/venv from PyPI) and oiiotool
# (Debian openimageio-tools) for the contact sheet. UMBRA=path/to/umbra skips the build.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
out="${1:-$here/out}"
mkdir -p "$out/maps"
if [[ -z "${UMBRA:-}" ]]; then
    cargo build --release --ignore-rust-version --quiet --manifest-path "$root/Cargo.toml"
    UMBRA="$root/target/release/umbra"
fi
if [[ ! -x "$out/venv/bin/python" ]]; then
    python3 -m venv "$out/venv"
    "$out/venv/bin/python" -m pip install -q usd-core
fi

"$out/venv/bin/python" "$here/make_shot.py" "$out"
cp "$here/job.toml" "$out/job.toml"
"$UMBRA" batch "$out/job.toml" --force
"$UMBRA" bake "$out/shot.usda" --frame 2 --light sun --res 256 -o "$out/sun_f2.exr" \
    --usd-out "$out/shadows.usda" --force --quiet
echo "--- $out/shadows.usda"
cat "$out/shadows.usda"

# One row per light, frames 1-4 left to right.
oiiotool "$out"/maps/sun.000{1,2,3,4}.png --mosaic:pad=4 4x1 -o "$out/sun_row.png"
oiiotool "$out"/maps/lamp.000{1,2,3,4}.png --mosaic:pad=4 4x1 -o "$out/lamp_row.png"
oiiotool "$out/sun_row.png" "$out/lamp_row.png" --mosaic:pad=4 1x2 -o "$out/contact.png"
echo "contact sheet: $out/contact.png"
