"""Put a density grid and umbra's transmittance grid into one .vdb: `density` and `shadow`.

    /usr/bin/python3 combine.py DENSITY.vdb TRANSMITTANCE.vdb OUT.vdb [--t-grid transmittance]

`shadow` is the transmittance volume `umbra bake ... -o NAME.vdb` writes (T = exp(-tau) from each
active voxel centre toward the light, background 1), renamed; both grids keep the density's
transform (checked to be the same one umbra wrote). Needs Debian's pyopenvdb.
"""

import argparse

import pyopenvdb as vdb


def same_transform(a, b):
    """Whether two grids map index to world alike (8 corners of a box of indices)."""
    corners = [(i, j, k) for i in (-100, 100) for j in (-100, 100) for k in (-100, 100)]
    return all(
        max(abs(p - q) for p, q in zip(a.transform.indexToWorld(c), b.transform.indexToWorld(c)))
        < 1e-9
        for c in corners
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("density")
    ap.add_argument("transmittance")
    ap.add_argument("out")
    ap.add_argument("--density-grid", default="density")
    ap.add_argument("--t-grid", default="transmittance")
    ap.add_argument("--name", default="shadow", help="name of the transmittance grid in OUT")
    a = ap.parse_args()

    dens = vdb.read(a.density, a.density_grid)
    t = vdb.read(a.transmittance, a.t_grid)
    if not same_transform(dens, t):
        raise SystemExit("the transmittance grid's transform differs from the density's")
    if t.activeVoxelCount() != dens.activeVoxelCount():
        raise SystemExit("the transmittance grid's active voxels differ from the density's")
    t.name = a.name
    t.transform = dens.transform  # one shared transform, as a smoke cache has
    dens.name = "density"
    vdb.write(a.out, grids=[dens, t])

    # Read it back: both grids, same transform, same active voxel count.
    back = {g.name for g in vdb.readAllGridMetadata(a.out)}
    assert back == {"density", a.name}, back
    d2, s2 = vdb.read(a.out, "density"), vdb.read(a.out, a.name)
    assert same_transform(d2, s2) and s2.activeVoxelCount() == d2.activeVoxelCount()
    lo, hi = s2.evalMinMax()
    print(f"wrote {a.out}: density ({d2.activeVoxelCount()} active voxels) and {a.name} "
          f"(T {lo:.3g} to {hi:.3g}, background {s2.background})")


if __name__ == "__main__":
    main()
