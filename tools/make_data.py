#!/usr/bin/python3
"""Recipe for umbra's sample OpenVDB files in data/.

Run from the repository root with Debian's interpreter:

    /usr/bin/python3 tools/make_data.py

Needs Debian 12 packages: python3-openvdb (pyopenvdb, OpenVDB 10.0.1),
python3-numpy; libopenvdb-tools provides vdb_print for inspecting the output.

Deterministic: no network, no random number generator. Noise comes from an
integer lattice hash, and only +, -, *, /, sqrt, floor and min/max are used on
the float data, so the voxel values are reproduced bit for bit.  (OpenVDB writes
a fresh random UUID into every file header, so the .vdb bytes differ between
runs; data/stats.json does not.)

Writes:
    data/cloud.vdb       cumulus-like fog volume, leaves + active tiles
    data/cloud_half.vdb  the same grid saved with 16-bit half floats
    data/box_tiles.vdb   constant box made only of active tiles
    data/bg_multi.vdb    two grids (temperature, density), non-zero backgrounds
    data/stats.json      reference statistics read back from those files
"""

import json
import math
import os
import sys

import numpy as np
import pyopenvdb as vdb

CREATOR = "umbra tools/make_data.py"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "data")

# ---------------------------------------------------------------------------
# Procedural noise: hashed value noise on an integer lattice + fBm.
# ---------------------------------------------------------------------------

_U32 = np.uint32


def _lattice_hash(ix, iy, iz, seed):
    """Integer hash of lattice points -> float64 in [0, 1).

    ix, iy, iz: int64 arrays (may be negative). Arithmetic wraps in uint32.
    """
    x = ix.astype(np.int64).astype(_U32)
    y = iy.astype(np.int64).astype(_U32)
    z = iz.astype(np.int64).astype(_U32)
    h = (x * _U32(0x8DA6B343)) ^ (y * _U32(0xD8163841)) ^ (z * _U32(0xCB1AB31F))
    h = h ^ _U32(seed & 0xFFFFFFFF)
    # avalanche: xor-shift / multiply rounds
    h = h ^ (h >> _U32(16))
    h = h * _U32(0x7FEB352D)
    h = h ^ (h >> _U32(15))
    h = h * _U32(0x846CA68B)
    h = h ^ (h >> _U32(16))
    # top 24 bits -> [0, 1)
    return (h >> _U32(8)).astype(np.float64) / float(1 << 24)


def _fade(t):
    """Quintic smooth interpolation weight 6t^5 - 15t^4 + 10t^3."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def value_noise(x, y, z, seed):
    """Smooth value noise in [-1, 1] at float64 coordinates (any shape)."""
    fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
    ix, iy, iz = fx.astype(np.int64), fy.astype(np.int64), fz.astype(np.int64)
    ux, uy, uz = _fade(x - fx), _fade(y - fy), _fade(z - fz)
    acc = np.zeros(np.broadcast(x, y, z).shape, dtype=np.float64)
    for dx in (0, 1):
        wx = ux if dx else 1.0 - ux
        for dy in (0, 1):
            wy = uy if dy else 1.0 - uy
            for dz in (0, 1):
                wz = uz if dz else 1.0 - uz
                v = _lattice_hash(ix + dx, iy + dy, iz + dz, seed)
                acc += (wx * wy * wz) * v
    return acc * 2.0 - 1.0


def fbm(x, y, z, seed, octaves=5, lacunarity=2.0, gain=0.5):
    """Fractal Brownian motion of value noise, normalised to about [-1, 1]."""
    total = np.zeros(np.broadcast(x, y, z).shape, dtype=np.float64)
    amp, freq, norm = 1.0, 1.0, 0.0
    for o in range(octaves):
        # per-octave offsets decorrelate the lattices
        off = 17.31 * (o + 1)
        total += amp * value_noise(x * freq + off, y * freq - off * 0.5,
                                   z * freq + off * 0.25, seed + 1013 * o)
        norm += amp
        amp *= gain
        freq *= lacunarity
    return total / norm


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ---------------------------------------------------------------------------
# Grids
# ---------------------------------------------------------------------------

CLOUD_DIM = (96, 64, 96)          # array shape (x, y, z) in voxels
CLOUD_IJK = (-48, -16, -48)       # index of array element [0, 0, 0]
CLOUD_VOXEL = 0.05
CLOUD_TRANSLATE = (0.0, 0.9, 0.0)  # world y of index j=-16 is 0.1
CLOUD_SEED = 20240611
ACTIVE_EPS = 1e-3


def cloud_density():
    """float32 array (96, 64, 96) of cumulus-like density in [0, 1]."""
    nx, ny, nz = CLOUD_DIM
    # voxel-centre coordinates in array space, cloud centred on x = z = 48
    x = (np.arange(nx, dtype=np.float64) + 0.5 - nx / 2)[:, None, None]
    y = (np.arange(ny, dtype=np.float64) + 0.5)[None, :, None]
    z = (np.arange(nz, dtype=np.float64) + 0.5 - nz / 2)[None, None, :]

    # overlapping ellipsoid blobs: (centre), (radii), all in voxels
    blobs = [
        ((0.0, 24.0, 0.0), (28.0, 17.0, 26.0)),     # main body
        ((-17.0, 20.0, 8.0), (19.0, 13.0, 17.0)),   # left shoulder
        ((16.0, 21.0, -6.0), (20.0, 14.0, 18.0)),   # right shoulder
        ((3.0, 35.0, -3.0), (17.0, 14.0, 16.0)),    # upper tower
        ((-5.0, 44.0, 2.0), (10.0, 9.0, 10.0)),     # top puff
        ((-6.0, 18.0, -18.0), (17.0, 11.0, 13.0)),  # back lobe
    ]
    # the blob layout is stretched to fill the 96 x 64 x 96 array
    bx, bz = x / 1.18, z / 1.3 - 1.0
    by = 9.0 + (y - 3.0) * 0.76
    f = np.full((nx, ny, nz), -1.0, dtype=np.float64)
    for (cx, cy, cz), (rx, ry, rz) in blobs:
        d = np.sqrt(((bx - cx) / rx) ** 2 + ((by - cy) / ry) ** 2
                    + ((bz - cz) / rz) ** 2)
        f = np.maximum(f, 1.0 - d)

    # flattened base: clamp the field below y ~ 4 voxels
    base = (by - 9.0) / 8.0
    f = np.minimum(f, base)

    # billowy fBm displacement, stronger towards the top
    s = 1.0 / 14.0
    n = fbm(x * s, y * s, z * s, CLOUD_SEED, octaves=5)
    billow = 0.22 + 0.10 * smoothstep(10.0, 50.0, y)
    g = f + billow * n

    # soft edge ramp; deep interior saturates to exactly 1.0 (dense core)
    dens = np.clip(g * 3.5, 0.0, 1.0)
    # fine wisps modulate only the soft edge region (keeps core constant)
    w = fbm(x * (s * 3.0), y * (s * 3.0), z * (s * 3.0), CLOUD_SEED + 7,
            octaves=3)
    edge = np.where(dens < 1.0, dens * (0.85 + 0.15 * w), dens)
    dens = np.clip(edge, 0.0, 1.0)
    dens[dens <= ACTIVE_EPS] = 0.0
    dens = dens.astype(np.float32)

    # the blob set + flat base must leave the array border empty
    for a in (dens[0], dens[-1], dens[:, 0], dens[:, -1], dens[:, :, 0],
              dens[:, :, -1]):
        if a.max() != 0.0:
            raise RuntimeError("cloud touches the array border")
    return dens


def make_cloud():
    grid = vdb.FloatGrid(0.0)
    grid.copyFromArray(cloud_density(), ijk=CLOUD_IJK, tolerance=0.0)
    grid.prune(0.0)
    grid.name = "density"
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    grid.creator = CREATOR
    xf = vdb.createLinearTransform(CLOUD_VOXEL)
    xf.translate(CLOUD_TRANSLATE)
    grid.transform = xf
    return grid


def make_box_tiles():
    grid = vdb.FloatGrid(0.0)
    grid.fill((0, 0, 0), (255, 127, 127), 0.5, active=True)
    grid.prune(0.0)
    grid.name = "density"
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    grid.creator = CREATOR
    grid.transform = vdb.createLinearTransform(0.1)
    return grid


def make_bg_multi():
    bg_d = 0.02
    n = 32
    c = np.arange(n, dtype=np.float64) + 0.5 - n / 2  # centre at index 0
    x, y, z = c[:, None, None], c[None, :, None], c[None, None, :]
    r = np.sqrt(x * x + y * y + z * z) / 14.0          # 1 at radius 14
    t = np.clip(1.0 - r, 0.0, 1.0)
    prof = t * t * (3.0 - 2.0 * t)                     # smooth, 1 at centre
    dens = (bg_d + (1.0 - bg_d) * prof).astype(np.float32)
    dens[r >= 1.0] = np.float32(bg_d)                  # exactly background
    density = vdb.FloatGrid(bg_d)
    density.copyFromArray(dens, ijk=(-16, -16, -16), tolerance=0.0)
    density.prune(0.0)
    density.name = "density"
    density.gridClass = vdb.GridClass.FOG_VOLUME
    density.creator = CREATOR
    xf = vdb.createLinearTransform(0.1)
    xf.translate((0.0, 2.0, 0.0))
    density.transform = xf

    bg_t = 290.0
    m = 16
    c = np.arange(m, dtype=np.float64) + 0.5 - m / 2
    x, y, z = c[:, None, None], c[None, :, None], c[None, None, :]
    r = np.sqrt(x * x + (y + 2.0) ** 2 + z * z) / 7.0
    t = np.clip(1.0 - r, 0.0, 1.0)
    temp = (bg_t + 110.0 * t * t * (3.0 - 2.0 * t)).astype(np.float32)
    temp[r >= 1.0] = np.float32(bg_t)
    temperature = vdb.FloatGrid(bg_t)
    temperature.copyFromArray(temp, ijk=(-8, -8, -8), tolerance=0.0)
    temperature.prune(0.0)
    temperature.name = "temperature"
    temperature.creator = CREATOR
    xf = vdb.createLinearTransform(0.2)
    xf.translate((0.0, 2.0, 0.0))
    temperature.transform = xf
    # temperature first on purpose: readers must select "density" by name
    return [temperature, density]


# ---------------------------------------------------------------------------
# Reference statistics (computed from the files as read back)
# ---------------------------------------------------------------------------

def probe_points(grid):
    """Fixed index points: origin, bbox corners/centre, just outside, far."""
    lo, hi = grid.evalActiveVoxelBoundingBox()
    mid = tuple((a + b) // 2 for a, b in zip(lo, hi))
    pts = [(0, 0, 0), (-1, -1, -1), tuple(lo), tuple(hi), mid,
           (lo[0] - 1, lo[1], lo[2]), (hi[0], hi[1] + 1, hi[2]),
           (-20, 5, 10), (30, -10, -30), (7, 7, 7), (8, 8, 8),
           (1000, -1000, 1000)]
    # first leaf voxel with a fractional value and first active tile, in
    # OpenVDB's (deterministic) iteration order
    vmin, vmax = grid.evalMinMax()
    leaf_pt = tile_pt = None
    for item in grid.iterOnValues():
        if leaf_pt is None and item.depth == 3 and vmin < item.value < vmax:
            leaf_pt = tuple(item.min)
        if tile_pt is None and item.depth < 3:
            tile_pt = tuple(item.min)
    pts += [p for p in (leaf_pt, tile_pt) if p is not None]
    acc = grid.getConstAccessor()
    out = []
    for ijk in pts:
        value, active = acc.probeValue(ijk)
        out.append({"ijk": list(ijk), "value": float(value),
                    "active": bool(active)})
    return out


def grid_stats(grid):
    tiles = {}
    leaf_voxels = 0
    terms = []
    for item in grid.iterOnValues():
        cnt = int(item.count)
        terms.append(float(item.value) * cnt)
        if item.depth == 3:
            leaf_voxels += cnt
        else:
            tiles[item.depth] = tiles.get(item.depth, 0) + 1
    lo, hi = grid.evalActiveVoxelBoundingBox()
    vmin, vmax = grid.evalMinMax()
    xf = grid.transform
    m = [list(map(float, xf.indexToWorld((0, 0, 0))))]
    return {
        "name": grid.name,
        "value_type": grid.valueTypeName,
        "grid_class": str(grid.gridClass),
        "background": float(grid.background),
        "voxel_size": [float(v) for v in xf.voxelSize()],
        "transform_type": xf.typeName,
        "index_origin_world": m[0],
        "active_bbox_min": list(lo),
        "active_bbox_max": list(hi),
        "active_voxel_count": int(grid.activeVoxelCount()),
        "active_leaf_voxel_count": int(grid.activeLeafVoxelCount()),
        "leaf_count": int(grid.leafCount()),
        # tile depth: 0 root tile, 1 tile of a 4096^3 node (128^3 voxels),
        # 2 tile of a 128^3 node (8^3 voxels)
        "active_tiles_by_depth": {str(k): tiles[k] for k in sorted(tiles)},
        "active_tile_count": sum(tiles.values()),
        "min": float(vmin),
        "max": float(vmax),
        # correctly rounded float64 sum of value * voxel count over active
        # voxels and tiles (math.fsum, order independent)
        "active_sum": math.fsum(terms),
        "saved_as_half": bool(grid.metadata.get("is_saved_as_half_float",
                                                False)),
        # value (float32 widened to float64) and active state at fixed points
        "probes": probe_points(grid),
    }


def main():
    os.makedirs(DATA, exist_ok=True)
    meta = {"creator": CREATOR}

    cloud = make_cloud()
    vdb.write(os.path.join(DATA, "cloud.vdb"), [cloud], metadata=meta)
    half = cloud.deepCopy()
    half.saveFloatAsHalf = True
    vdb.write(os.path.join(DATA, "cloud_half.vdb"), [half], metadata=meta)
    vdb.write(os.path.join(DATA, "box_tiles.vdb"), [make_box_tiles()],
              metadata=meta)
    vdb.write(os.path.join(DATA, "bg_multi.vdb"), make_bg_multi(),
              metadata=meta)

    stats = {"generator": CREATOR,
             "openvdb_library_version": list(vdb.LIBRARY_VERSION),
             "files": {}}
    for fname in ("cloud.vdb", "cloud_half.vdb", "box_tiles.vdb",
                  "bg_multi.vdb"):
        path = os.path.join(DATA, fname)
        grids, fmeta = vdb.readAll(path)
        stats["files"][fname] = {
            "file_metadata": {k: fmeta[k] for k in sorted(fmeta)},
            "grids": [grid_stats(g) for g in grids],
        }
    with open(os.path.join(DATA, "stats.json"), "w") as fh:
        json.dump(stats, fh, indent=2, sort_keys=False)
        fh.write("\n")
    print("wrote", ", ".join(sorted(stats["files"])), "and stats.json",
          file=sys.stderr)


if __name__ == "__main__":
    main()
