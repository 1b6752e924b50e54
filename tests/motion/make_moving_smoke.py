"""Give a real cache a velocity: OpenVDB's smoke1 density with a vec3s `vel` written by pyopenvdb.

Usage: make_moving_smoke.py SMOKE_VDB OUT_DIR

Writes OUT_DIR/smoke_const.vdb (a constant (30, 0, 10) world units per second over the
density's active box) and OUT_DIR/smoke_swirl.vdb (a swirl about the box's vertical axis at
1.5 rad/s plus 5 sin(y / 10) upward, up to 56 units per second), each with the density grid
unchanged and the velocity on the density's transform (issue 61's benchmarks and tests).
"""
import sys

import numpy as np
import pyopenvdb as vdb

d = vdb.read(sys.argv[1], "density")
lo, hi = d.evalActiveVoxelBoundingBox()
shape = tuple(h - l + 1 for l, h in zip(lo, hi))
vs = d.transform.voxelSize()[0]
org = np.array(d.transform.indexToWorld(lo))
for name in ("const", "swirl"):
    a = np.zeros(shape + (3,), dtype=np.float32)
    if name == "const":
        a[...] = (30.0, 0.0, 10.0)
    else:
        i = np.indices(shape).astype(np.float64)
        x, y, z = (org[k] + i[k] * vs for k in range(3))
        cx, cz = (org[k] + (shape[k] - 1) * vs / 2 for k in (0, 2))
        a[..., 0] = -1.5 * (z - cz)
        a[..., 2] = 1.5 * (x - cx)
        a[..., 1] = 5.0 * np.sin(y / 10.0)
    v = vdb.Vec3SGrid()
    v.name = "vel"
    v.transform = d.transform
    v.copyFromArray(a, ijk=lo)
    vdb.write(f"{sys.argv[2]}/smoke_{name}.vdb", grids=[d, v])
