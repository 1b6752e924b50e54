"""A moving real cache for the motion benchmarks: the corpus's Houdini smoke density with a
vec3s `vel` grid over its active bounding box, on the density's transform (how a simulation
cache with velocity is laid out), written by OpenVDB.

Usage: motion_cache.py SRC.vdb OUT.vdb constant|swirl
  constant: (30, 0, 10) world units per second everywhere (the issue's held-out cloud moves so);
  swirl:    a turn of 1 radian per second about the vertical axis through the box's centre,
            plus an updraft of 10 units per second.
"""
import sys

import numpy as np
import pyopenvdb as vdb

src, out, kind = sys.argv[1], sys.argv[2], sys.argv[3]
d = vdb.read(src, "density")
v = vdb.Vec3SGrid()
v.name = "vel"
v.transform = d.transform
lo, hi = d.evalActiveVoxelBoundingBox()
if kind == "constant":
    v.fill(lo, hi, (30.0, 0.0, 10.0), active=True)
else:
    shape = tuple(h - l + 1 for l, h in zip(lo, hi))
    idx = np.stack(np.meshgrid(*[np.arange(l, h + 1) for l, h in zip(lo, hi)], indexing="ij"), -1)
    world = idx * d.transform.voxelSize()[0]
    centre = world.reshape(-1, 3).mean(0)
    r = world - centre
    vel = np.stack([-r[..., 2], np.full(shape, 10.0), r[..., 0]], -1).astype(np.float32)
    v.copyFromArray(vel, ijk=lo)
v.pruneInactive()
vdb.write(out, grids=[d, v])
