#!/usr/bin/python3
"""Make a hero-size test cache (about 1 GB) by tiling the sample cloud, for issue 18's benches.

Run from the repository root with Debian's interpreter:

    /usr/bin/python3 tools/make_hero.py [OUT.vdb] [--copies NX NY NZ]

Default: /tmp/umbra-hero/hero.vdb, 14 x 13 x 13 copies (2366 clouds, about 350 M active
voxels, 0.96 GB with blosc + active-value compression, OpenVDB 10's defaults).

Needs Debian 12 packages python3-openvdb and python3-numpy. Deterministic in its voxel values
(the copies are exact: the cloud is read once into a dense array and written at each
offset); the file's bytes differ run to run only by the UUID OpenVDB writes into the header.

The copies overlap nothing: their origins are spaced by the cloud's bounding box plus a gap,
and the spacing is *not* a multiple of 8, so every copy straddles leaves differently, as a
real cache's structures would. The grid keeps the cloud's transform, class and name
(`density`); OpenVDB adds its file_* statistics (file_mem_bytes among them) on write.
"""

import os
import sys
import time

import numpy as np
import pyopenvdb as vdb


def main(argv):
    out = "/tmp/umbra-hero/hero.vdb"
    copies = (14, 13, 13)
    args = list(argv)
    if "--copies" in args:
        i = args.index("--copies")
        copies = tuple(int(a) for a in args[i + 1 : i + 4])
        del args[i : i + 4]
    if args:
        out = args[0]
    here = os.path.dirname(os.path.abspath(__file__))
    src = os.path.join(here, "..", "data", "cloud.vdb")
    cloud = vdb.read(src, "density")
    (lo, hi) = cloud.evalActiveVoxelBoundingBox()
    shape = tuple(hi[a] - lo[a] + 1 for a in range(3))
    dense = np.zeros(shape, dtype=np.float32)
    cloud.copyToArray(dense, ijk=lo)
    step = tuple(shape[a] + 3 for a in range(3))
    hero = vdb.FloatGrid(background=cloud.background)
    hero.name = "density"
    hero.transform = cloud.transform
    hero.gridClass = cloud.gridClass
    hero["creator"] = "umbra tools/make_hero.py"
    t0 = time.time()
    n = 0
    for x in range(copies[0]):
        for y in range(copies[1]):
            for z in range(copies[2]):
                at = (lo[0] + x * step[0], lo[1] + y * step[1], lo[2] + z * step[2])
                hero.copyFromArray(dense, ijk=at, tolerance=0.0)
                n += 1
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    tmp = out + ".tmp"
    vdb.write(tmp, grids=[hero])
    os.replace(tmp, out)
    print(
        f"{out}: {n} copies, {hero.activeVoxelCount()} active voxels, {hero.leafCount()} "
        f"leaves, {os.path.getsize(out) / 1e9:.2f} GB, {time.time() - t0:.1f} s"
    )


if __name__ == "__main__":
    main(sys.argv[1:])
