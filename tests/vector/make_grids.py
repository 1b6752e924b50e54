#!/usr/bin/env python3
"""The vec3s grids of tests/library/vector.rs (pyopenvdb, Debian python3-openvdb).

Writes plain.vdb (the grid, an instance of it and a float grid), half.vdb (saved as half) and
staggered.vdb (class staggered, vector_type, is_local_space) into argv[1], and expect.json:
each file read back by OpenVDB, its values and active states at every probe voxel.
"""
import sys, json, pyopenvdb as vdb
out = sys.argv[1]
BG = (0.5, -0.25, 1.5)
NEG = tuple(-c for c in BG)
O1 = (3.0, -3.0, 2.0)
O2 = (-4.5, 4.25, 0.125)
def v(i, j, k):
    return (0.3 * i + 0.1 * j - 0.01, -0.7 * k + 0.05 * i * j, 1.0 / (1.0 + abs(i + j + k)))
def vec_grid(name):
    g = vdb.Vec3SGrid(BG)
    g.name = name
    g.transform = vdb.createLinearTransform(
        [[0.5, 0.1, 0, 0], [0, 0.25, 0, 0], [0.05, 0, 0.75, 0], [1.0, -2.0, 3.0, 1]])
    acc = g.getAccessor()
    # Twelve full leaves around the origin (negative coordinates too).
    for i in range(-8, 16):
        for j in range(0, 16):
            for k in range(-8, 8):
                acc.setValueOn((i, j, k), v(i, j, k))
    # Sparse leaves, one per way of storing inactive values: background, -background, both,
    # background and another, another, two others, three (all values stored).
    sparse = [((24, 0, 0), [BG]), ((32, 0, 0), [NEG]), ((40, 0, 0), [BG, NEG]),
              ((48, 0, 0), [BG, O1]), ((56, 0, 0), [O1]), ((0, 24, 0), [O1, O2]),
              ((0, 32, 0), [O1, O2, NEG])]
    for (o, inactive) in sparse:
        for n in range(512):
            ijk = (o[0] + (n >> 6), o[1] + ((n >> 3) & 7), o[2] + (n & 7))
            if n % 5 == 0:
                acc.setValueOn(ijk, v(*ijk))
            else:
                acc.setValueOff(ijk, inactive[n % len(inactive)])
    # Tiles: a leaf-sized active tile, an inactive one, a lower-node-sized active tile.
    g.fill((64, 0, 0), (71, 7, 7), (7.0, -8.0, 9.0), True)
    g.fill((72, 0, 0), (79, 7, 7), (-1.5, 2.5, -3.5), False)
    g.fill((128, 128, 128), (255, 255, 255), (-1.0, 2.0, -3.0), True)
    return g
def probes():
    pts = []
    for i in range(-8, 16):
        for j in range(0, 16):
            for k in range(-8, 8):
                pts.append((i, j, k))
    for o in [(24, 0, 0), (32, 0, 0), (40, 0, 0), (48, 0, 0), (56, 0, 0), (0, 24, 0), (0, 32, 0)]:
        for n in range(512):
            pts.append((o[0] + (n >> 6), o[1] + ((n >> 3) & 7), o[2] + (n & 7)))
    pts += [(64, 0, 0), (71, 7, 7), (66, 3, 5), (72, 0, 0), (79, 7, 7), (128, 128, 128),
            (200, 150, 255), (255, 255, 255), (256, 0, 0), (-1000, 5, 5), (5000, -5000, 7),
            (63, 0, 0), (80, 0, 0), (127, 128, 128)]
    return pts
density = vdb.FloatGrid(0.0)
density.name = "density"
density.getAccessor().setValueOn((1, 2, 3), 0.5)
files = {}
plain = vec_grid("vel")
inst = plain.copy()
inst.name = "vel_instance"
files["plain.vdb"] = [plain, inst, density]
half = vec_grid("vel")
half.saveFloatAsHalf = True
files["half.vdb"] = [half]
stag = vec_grid("vel")
stag.gridClass = vdb.GridClass.STAGGERED
stag.vectorType = "contravariant relative"
stag["is_local_space"] = True
files["staggered.vdb"] = [stag]
expect = {}
for name, grids in files.items():
    path = out + "/" + name
    vdb.write(path, grids=grids)
    back = vdb.read(path, "vel")
    acc = back.getConstAccessor()
    vals = []
    for p in probes():
        x = acc.getValue(p)
        vals.append([p[0], p[1], p[2], x[0], x[1], x[2], acc.isValueOn(p)])
    expect[name] = {"background": list(back.background), "class": str(back.gridClass),
                    "vector_type": back.vectorType, "probes": vals}
json.dump(expect, open(out + "/expect.json", "w"))
