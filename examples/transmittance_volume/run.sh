#!/usr/bin/env bash
# A transmittance volume beside its density: bake data/cloud.vdb's T toward two suns into .vdb
# files, merge density and T into one cache (grids `density` and `shadow`), list it with
# vdb_print and render the middle z-slice of density, T and density x T as a PNG.
#
#   bash examples/transmittance_volume/run.sh [OUT_DIR]     (default examples/transmittance_volume/out)
#
# Needs Debian's /usr/bin/python3 with pyopenvdb and numpy (python3-openvdb), vdb_print
# (libopenvdb-tools) and oiiotool (openimageio-tools). UMBRA=path/to/umbra skips the build.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
out="${1:-$here/out}"
mkdir -p "$out"
py=/usr/bin/python3

if [[ -z "${UMBRA:-}" ]]; then
    cargo build --release --ignore-rust-version --quiet --manifest-path "$root/Cargo.toml"
    UMBRA="$root/target/release/umbra"
fi

bake() { # NAME LIGHT_DIR: bake, keep the JSON, print its headline numbers
    local name="$1" dir="$2"
    "$UMBRA" bake "$root/data/cloud.vdb" --light-dir="$dir" --density-scale 4 \
        -o "$out/$name.vdb" --force --json >"$out/$name.json"
    "$py" - "$out/$name.json" "$name" "$dir" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
step = f" (line step {r['line_step']})" if r.get("line_step") else ""
print(f"{sys.argv[2]} (light-dir {sys.argv[3]}): {r['voxels']} voxels, sharing {r['sharing']}{step}, "
      f"{r['rays']} rays, {r['ns_per_voxel']:.0f} ns/voxel ({r['seconds']:.3f} s tracing), "
      f"T min {r['T_min']:.3g} max {r['T_max']:.4g} mean {r['T_mean']:.3f}")
PY
}

echo "== bake (umbra bake ... -o NAME.vdb --json)"
bake sun_down 0,-1,0
bake sun_oblique 0.4,-1,0.3

echo "== combine: density + shadow (oblique sun) -> cloud_lit.vdb"
"$py" "$here/combine.py" "$root/data/cloud.vdb" "$out/sun_oblique.vdb" "$out/cloud_lit.vdb"
vdb_print -l "$out/cloud_lit.vdb"

echo "== slice: rows sun_down, sun_oblique; columns density | T | density x T"
"$py" "$here/slice.py" "$out/slices.png" "$out/cloud_lit.vdb:density" \
    "$out/sun_down.vdb:transmittance" "$out/cloud_lit.vdb:shadow"
