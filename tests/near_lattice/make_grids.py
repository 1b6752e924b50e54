#!/usr/bin/python3
"""Near-lattice test grids and rays for tests/library/near_lattice.rs, written by real OpenVDB.

    /usr/bin/python3 make_grids.py OUT_DIR

writes, into OUT_DIR:
  layered_<map>.vdb   the same layered fog grid `density` under three transforms:
                      `scale` (voxel 0.05, translated: index axes are world axes),
                      `rotated` (30 deg about z, then 20 deg about x) and `sheared`
                      (an affine map with shear: index axes are neither orthogonal nor unit
                      in world space);
  layered_<map>.rays  world segments "ax ay az bx by bz" (17 significant digits), one per line,
                      each tagged after a '#' with which interpolations it is well defined for.

The grid: value g(k) depends on the index k alone, over i, j in [-8, 140) and k in [0, 200):
k < 128 constant 0.5 (a full 128^3 tile of a lower node after pruning, 8^3 tiles around it),
128 <= k < 160 a smooth ramp (leaves), 160 <= k < 168 constant 1.0 (8^3 tiles),
168 <= k < 200 another ramp. So a nearest lookup on a plane between two voxel columns along
i or j reads the same value from either column: rays on those tie planes have one exact answer.

Rays are index-space lines along an index axis A (both ways) whose other two coordinates lie
on lattice planes (integer: trilinear cell faces, leaf and tile faces), on nearest tie planes
(half-integers) or at voxel centres, with direction components perpendicular to A of
0, +-1e-17, +-1e-15, +-1e-13, +-1e-11, +-1e-9 (index units per index unit along A), mapped to
world by the grid's own transform (so the sheared and rotated maps add their own round-off).
"""
import sys

import numpy as np
import pyopenvdb as vdb

MAPS = {
    "scale": [[0.05, 0, 0, 0], [0, 0.05, 0, 0], [0, 0, 0.05, 0], [0.3, -0.2, 1.0, 1]],
}


def rot(ax, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    m = np.eye(3)
    i, j = [(1, 2), (2, 0), (0, 1)][ax]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def affine(m3, t):
    m = np.eye(4)
    m[:3, :3] = m3
    m[3, :3] = t
    return m.tolist()


MAPS["rotated"] = affine(0.05 * (rot(2, 30) @ rot(0, 20)).T, [0.3, -0.2, 1.0])
# Rows are the world images of the index axes: i stays on world x, j leans into x, k into x and y.
MAPS["sheared"] = affine(
    [[0.05, 0.0, 0.0], [0.0125, 0.05, 0.0], [0.007, -0.011, 0.05]], [-1.7, 0.4, 2.25]
)

DRIFTS = [0.0, 1e-17, -1e-17, 1e-15, -1e-15, 1e-13, -1e-13, 1e-11, -1e-11, 1e-9, -1e-9]
LATTICE = [0.0, 8.0, 64.0, 128.0, 139.0, 140.0, -1.0, 136.0]  # integer planes
TIES = [-0.5, 7.5, 127.5, 135.5, 63.5]  # nearest tie planes (voxel faces), inside the data
CENTRES_K = [3.0, 130.0, 163.0, 171.0]  # k at voxel centres for rays along i or j


def layered():
    k = np.arange(0, 200)
    g = np.where(k < 128, 0.5, 0.0)
    g = np.where((k >= 128) & (k < 160), 0.3 + 0.2 * np.sin(0.7 * k), g)
    g = np.where((k >= 160) & (k < 168), 1.0, g)
    g = np.where(k >= 168, 0.2 + 0.1 * np.cos(k), g)
    a = np.broadcast_to(g.astype(np.float32), (148, 148, 200)).copy()
    grid = vdb.FloatGrid(0.0)
    grid.copyFromArray(a, ijk=(-8, -8, 0), tolerance=0.0)
    grid.prune(0.0)
    grid.name = "density"
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    return grid


def rays():
    """(index start, index end, interps) for every ray of the set."""
    out = []
    span = {0: (-12.0, 152.0), 1: (-12.0, 152.0), 2: (-12.0, 215.0)}
    for axis in range(3):
        b, c = [x for x in range(3) if x != axis]
        pairs = []
        for u in LATTICE:
            pairs.append(((u, LATTICE[(LATTICE.index(u) + 3) % len(LATTICE)]), "trilinear"))
        for u in TIES:
            if axis == 2:
                # Along k every column reads the same values: ties on i and j are exact.
                pairs.append(((u, TIES[(TIES.index(u) + 2) % len(TIES)]), "both"))
            else:
                # Along i or j: the other lateral axis is i or j (ties exact), k at a centre.
                pairs.append(((u, CENTRES_K[TIES.index(u) % len(CENTRES_K)]), "both"))
        lo, hi = span[axis]
        for (pb, pc), interps in pairs:
            for drift in DRIFTS:
                for sign in (1.0, -1.0):
                    for start_at in (lo, 0.0 if sign > 0 else 140.0, 130.5):
                        p = [0.0, 0.0, 0.0]
                        p[axis], p[b], p[c] = start_at, pb, pc
                        end = hi if sign > 0 else lo
                        length = abs(end - start_at)
                        if length == 0.0:
                            continue
                        d = [0.0, 0.0, 0.0]
                        d[axis], d[b], d[c] = sign, drift, -0.6 * drift
                        q = [p[x] + length * d[x] for x in range(3)]
                        out.append((p, q, interps))
    return out


def main():
    out_dir = sys.argv[1]
    grid = layered()
    for name, m in MAPS.items():
        g = grid.deepCopy()
        g.transform = vdb.createLinearTransform(m)
        vdb.write(f"{out_dir}/layered_{name}.vdb", grids=[g])
        with open(f"{out_dir}/layered_{name}.rays", "w") as f:
            for p, q, interps in rays():
                a = g.transform.indexToWorld(p)
                b = g.transform.indexToWorld(q)
                vals = " ".join(repr(float(v)) for v in (*a, *b))
                f.write(f"{vals} # {interps}\n")


if __name__ == "__main__":
    main()
