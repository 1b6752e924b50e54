#!/usr/bin/python3
# Dense copy of one OpenVDB float grid for bench/mitsuba_transmittance.py (Mitsuba 3 has no VDB
# reader). Run it with Debian's /usr/bin/python3, which has pyopenvdb (python3-openvdb) and numpy:
#
#   /usr/bin/python3 bench/vdb_dense.py FILE.vdb GRID OUT.npz
#
# OUT.npz holds:
# - density: float32 [z, y, x] (x fastest, Mitsuba's VolumeGrid / Texture3f layout), the grid's
#   values (active or not, tiles included, background elsewhere, as the accessor returns them)
#   over its active-voxel bbox [lo, hi] padded by one voxel of background on every side, so the
#   array covers index points lo - 1 .. hi + 1;
# - origin: int64 [3], the index (i, j, k) of density[0, 0, 0] (= lo - 1);
# - world_from_index: float64 [4, 4], the grid's affine index-to-world map (OpenVDB convention:
#   voxel (i, j, k) is the index point (i, j, k));
# - background: the grid's background value.
# The padding matters: Mitsuba's grid puts values at cell centres and clamps at the edges, so the
# one-voxel zero margin keeps its trilinear field zero beyond OpenVDB's (lo - 1, hi + 1) support.
import sys

import numpy as np
import pyopenvdb as vdb


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: /usr/bin/python3 vdb_dense.py FILE.vdb GRID OUT.npz")
    path, name, out = sys.argv[1:]
    grid = vdb.read(path, name)
    if grid.valueTypeName != "float":
        sys.exit(f"{path}: grid {name} holds {grid.valueTypeName}, not float")
    lo, hi = grid.evalActiveVoxelBoundingBox()
    origin = np.array(lo, dtype=np.int64) - 1
    shape = tuple(int(h - l + 3) for l, h in zip(lo, hi))  # x, y, z with the margin
    dense = np.full(shape, grid.background, dtype=np.float32)
    grid.copyToArray(dense, ijk=tuple(int(c) for c in origin))

    # The affine map from four points (OpenVDB's linear maps are affine; refuse anything else).
    xf = grid.transform
    o = np.array(xf.indexToWorld((0, 0, 0)))
    m = np.eye(4)
    m[:3, 3] = o
    for a in range(3):
        e = [0, 0, 0]
        e[a] = 1
        m[:3, a] = np.array(xf.indexToWorld(tuple(e))) - o
    probe = (7.0, -3.0, 5.0)
    if not np.allclose(xf.indexToWorld(probe), m[:3, :3] @ probe + o, rtol=1e-9, atol=1e-12):
        sys.exit(f"{path}: grid {name} has a non-affine transform")

    np.savez(out, density=np.ascontiguousarray(dense.transpose(2, 1, 0)), origin=origin,
             world_from_index=m, background=np.float32(grid.background))
    print(f"{out}: {shape[0]}x{shape[1]}x{shape[2]} voxels from index {tuple(origin)}", file=sys.stderr)


main()
