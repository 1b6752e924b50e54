"""The middle z-slice of a density grid beside transmittance grids, as one PNG.

    /usr/bin/python3 slice.py OUT.png DENSITY.vdb[:GRID] T.vdb[:GRID] [T.vdb[:GRID] ...]

One row per transmittance grid (default grid name: `shadow` if the file has one, else
`transmittance`), three panels per row, left to right:

* density, normalised by the slice's maximum (white: densest);
* T, the transmittance toward the light (white: fully lit, black: no light arrives);
* lit = density x T, on the density's scale: what a viewport that shades each voxel by the light
  reaching it shows.

The slice is the index plane k = middle of the density's active box; rows of the image run along
+y downward-flipped (up is +y), columns along +x. Pixels are 4x4 blocks of a voxel. Writes a
binary PGM next to OUT and converts it with `oiiotool X.pgm -o OUT.png`. Needs Debian's pyopenvdb
and numpy.
"""

import subprocess
import sys

import numpy as np
import pyopenvdb as vdb

SCALE = 4  # pixels per voxel
GAP = 6  # grey pixels between panels and rows


def read(spec, default):
    path, _, grid = spec.partition(":")
    if not grid:
        names = {g.name for g in vdb.readAllGridMetadata(path)}
        grid = next((n for n in default if n in names), None)
        if grid is None:
            raise SystemExit(f"{path}: none of {default} in {sorted(names)}")
    return vdb.read(path, grid)


def dense(grid, lo, hi):
    """Dense [i, j, k] copy of the box lo..hi (inclusive); inactive voxels hold the background."""
    arr = np.empty([h - l + 1 for l, h in zip(lo, hi)], np.float32)
    grid.copyToArray(arr, ijk=lo)
    return arr


def panel(img2d):
    """[i, j] slice -> image rows (y up) x columns (x), scaled up."""
    img = np.flipud(img2d.T)
    return np.kron(img, np.ones((SCALE, SCALE), np.float32))


def main():
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    out, dspec, tspecs = sys.argv[1], sys.argv[2], sys.argv[3:]
    dens = read(dspec, ["density"])
    lo, hi = dens.evalActiveVoxelBoundingBox()
    k = (lo[2] + hi[2]) // 2
    d = dense(dens, lo, hi)[:, :, k - lo[2]]
    dmax = float(d.max()) or 1.0
    z = dens.transform.indexToWorld((0, 0, k))[2]
    print(f"slice k = {k} (world z = {z:g}) of {dspec}: {d.shape[0]} x {d.shape[1]} voxels, "
          f"density max {dmax:.3g}")
    rows = []
    for spec in tspecs:
        tg = read(spec, ["shadow", "transmittance"])
        t = dense(tg, lo, hi)[:, :, k - lo[2]]
        inside = d > 0
        lit = d * t
        print(f"  {spec} ({tg.name}): T in the slice's cloud voxels min {t[inside].min():.3g} "
              f"mean {t[inside].mean():.3g} max {t[inside].max():.4g}; "
              f"lit / density mean {lit[inside].sum() / d[inside].sum():.3g}")
        panels = [panel(d / dmax), panel(np.clip(t, 0, 1)), panel(lit / dmax)]
        gap = np.full((panels[0].shape[0], GAP), 0.5, np.float32)
        rows.append(np.hstack([panels[0], gap, panels[1], gap, panels[2]]))
    sep = np.full((GAP, rows[0].shape[1]), 0.5, np.float32)
    img = rows[0]
    for r in rows[1:]:
        img = np.vstack([img, sep, r])
    pix = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
    pgm = out.rsplit(".", 1)[0] + ".pgm"
    with open(pgm, "wb") as f:
        f.write(b"P5\n%d %d\n255\n" % (pix.shape[1], pix.shape[0]))
        f.write(pix.tobytes())
    subprocess.run(["oiiotool", pgm, "-o", out], check=True)
    print(f"wrote {out} ({pix.shape[1]} x {pix.shape[0]}; rows: {', '.join(tspecs)}; "
          "columns: density | T | density x T)")


if __name__ == "__main__":
    main()
