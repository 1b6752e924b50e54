#!/usr/bin/python3
"""Write a moving test cache with OpenVDB (pyopenvdb): the sample cloud tiled NX x NY x NZ times
(as tools/make_hero.py tiles it) as `density`, and a vec3s `vel` on a coarser lattice covering
every copy: a swirl about the z axis through the cache's centre and an updraft,
v(p) = W (-(y - cy), x - cx, 0) + (0, 0, VZ), world units per second.

Usage: make_moving_cloud.py OUT.vdb [--copies NX NY NZ] [--vel-voxel H] [--staggered]
                            [--speed S]

`--vel-voxel` is the velocity's voxel size (default 0.2, four density voxels); `--staggered`
stores component k on the face p - e_k / 2 of voxel p (class staggered, OpenVDB's MAC grids);
`--speed` multiplies the field (default 1: about 20 world units per second at the cache's
edge, 4 density voxels over the default 180-degree shutter at 24 fps). A bake in parts of
this cache must equal its whole bake bit for bit (tests/library/motion_parts.rs).
"""

import os
import sys

import numpy as np
import pyopenvdb as vdb

W, VZ = 3.0, 10.0


def take(args, flag, n, default):
    if flag not in args:
        return default
    i = args.index(flag)
    vals = args[i + 1 : i + 1 + n]
    del args[i : i + 1 + n]
    return vals


def main(argv):
    args = list(argv)
    copies = tuple(int(a) for a in take(args, "--copies", 3, ["3", "3", "3"]))
    h = float(take(args, "--vel-voxel", 1, ["0.2"])[0])
    speed = float(take(args, "--speed", 1, ["1"])[0])
    staggered = "--staggered" in args
    if staggered:
        args.remove("--staggered")
    out = args[0]
    here = os.path.dirname(os.path.abspath(__file__))
    cloud = vdb.read(os.path.join(here, "..", "..", "data", "cloud.vdb"), "density")
    (lo, hi) = cloud.evalActiveVoxelBoundingBox()
    shape = tuple(hi[a] - lo[a] + 1 for a in range(3))
    dense = np.zeros(shape, dtype=np.float32)
    cloud.copyToArray(dense, ijk=lo)
    step = tuple(shape[a] + 3 for a in range(3))
    dens = vdb.FloatGrid(background=cloud.background)
    dens.name = "density"
    dens.transform = cloud.transform
    dens.gridClass = cloud.gridClass
    for x in range(copies[0]):
        for y in range(copies[1]):
            for z in range(copies[2]):
                at = (lo[0] + x * step[0], lo[1] + y * step[1], lo[2] + z * step[2])
                dens.copyFromArray(dense, ijk=at, tolerance=0.0)
    # World box of the tiled density, and the velocity lattice over it (one voxel beyond).
    xf = cloud.transform
    w_lo = np.array(xf.indexToWorld(lo))
    top = tuple(lo[a] + copies[a] * step[a] for a in range(3))
    w_hi = np.array(xf.indexToWorld(top))
    centre = (w_lo + w_hi) / 2
    v_lo = np.floor(w_lo / h).astype(int) - 1
    v_hi = np.ceil(w_hi / h).astype(int) + 1
    n = v_hi - v_lo + 1
    i = [np.arange(v_lo[a], v_hi[a] + 1, dtype=float) for a in range(3)]
    u = np.stack(np.meshgrid(*i, indexing="ij"), axis=-1)
    vel = np.zeros(tuple(n) + (3,))
    for k in range(3):
        at = u.copy()
        if staggered:
            at[..., k] -= 0.5
        p = at * h
        d = p - centre
        comp = [-W * d[..., 1], W * d[..., 0], np.full(d.shape[:-1], VZ)][k]
        vel[..., k] = speed * comp
    g = vdb.Vec3SGrid()
    g.copyFromArray(vel.astype(np.float32), ijk=tuple(int(c) for c in v_lo), tolerance=(0, 0, 0))
    g.name = "vel"
    g.transform = vdb.createLinearTransform(voxelSize=h)
    if staggered:
        g.gridClass = vdb.GridClass.STAGGERED
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    vdb.write(out, grids=[dens, g])


if __name__ == "__main__":
    main(sys.argv[1:])
