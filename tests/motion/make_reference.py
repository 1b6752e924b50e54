"""Write two motion-blur test caches with OpenVDB (pyopenvdb) and their blurred transmittance
by an independent NumPy march.

Usage: make_reference.py OUT_DIR

Each cache holds a float `density` (a Gaussian puff and a hard-edged block) and a vec3s `vel`:
a swirl about an axis parallel to z, an expansion and an updraft,
v(p) = w (-(y - cy), x - cx, 0) + e (p - c) + (0, 0, vz), world units per second. `swirl.vdb` stores it at voxel centres; `staggered.vdb` (class
staggered) stores component k on the face p - e_k / 2 of voxel p, as OpenVDB's MAC grids do.
`constant.vdb` holds the same density and a constant `vel` (an empty grid's background).
The field is linear, so any correct trilinear reading of either file gives the analytic field
exactly; the reference uses the analytic field, which makes it independent of how the file
stores it: a cell-centred reading of the staggered file would be half a voxel off.

Reference (`reference.json`): for each file and ray, T = mean over 200 shutter midpoints of
exp(-sum mu h) over 0.02-world-unit midpoint steps, mu = scale * trilinear(density) at
p - S v(p) t / F (OpenVDB's BoxSampler: the 8 voxels around the index point, background 0);
and the analytic velocity at probe points, which a reader must reproduce to f32 round-off (the
expansion's diagonal gradient makes a staggered grid read as cell-centred half a voxel off).
"""
import json
import sys

import numpy as np
import pyopenvdb as vdb

OUT = sys.argv[1]
VOXEL = 0.5
OFFSET = np.array([1.3, -2.1, 0.7])
N = 48
CENTRE = np.array([24.0, 22.0, 20.0]) * VOXEL + OFFSET
W, E, VZ = 20.0, 6.0, 72.0
SHUTTER, FPS, SCALE = (-0.5, 0.5), 24.0, 1.0
DENSITY_SCALE = 0.06
VEL_LO, VEL_HI = -16, N + 16
CONSTANT = (30.0, -12.0, 6.0)


def velocity(p):
    """The analytic field at world points p (..., 3)."""
    d = p - CENTRE
    swirl = np.stack([-W * d[..., 1], W * d[..., 0], np.full(d.shape[:-1], VZ)], axis=-1)
    return swirl + E * d


def index_to_world(u):
    return u * VOXEL + OFFSET


def density_array():
    i = np.arange(N, dtype=float)
    x, y, z = np.meshgrid(i, i, i, indexing="ij")
    r2 = (x - 24) ** 2 + (y - 22) ** 2 + (z - 20) ** 2
    d = 2.0 * np.exp(-r2 / (2 * 6.0**2))
    d[30:38, 20:28, 16:24] += 1.5
    d[d < 1e-4] = 0.0
    return d.astype(np.float32)


def transform():
    m = [[VOXEL, 0, 0, 0], [0, VOXEL, 0, 0], [0, 0, VOXEL, 0], list(OFFSET) + [1.0]]
    return vdb.createLinearTransform(m)


def write(path, staggered):
    dens = vdb.FloatGrid()
    dens.copyFromArray(density_array(), ijk=(0, 0, 0), tolerance=0)
    dens.name = "density"
    dens.transform = transform()
    dens.gridClass = vdb.GridClass.FOG_VOLUME
    n = VEL_HI - VEL_LO
    i = np.arange(VEL_LO, VEL_HI, dtype=float)
    x, y, z = np.meshgrid(i, i, i, indexing="ij")
    u = np.stack([x, y, z], axis=-1)
    vel = np.zeros((n, n, n, 3))
    for k in range(3):
        at = u.copy()
        if staggered:
            at[..., k] -= 0.5
        vel[..., k] = velocity(index_to_world(at))[..., k]
    g = vdb.Vec3SGrid()
    g.copyFromArray(vel.astype(np.float32), ijk=(VEL_LO, VEL_LO, VEL_LO), tolerance=(0, 0, 0))
    g.name = "vel"
    g.transform = transform()
    if staggered:
        g.gridClass = vdb.GridClass.STAGGERED
    vdb.write(path, grids=[dens, g])


def trilinear(a, u):
    """BoxSampler on the dense array a (index 0 at a[0]), background 0 outside."""
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    out = np.zeros(u.shape[:-1])
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                ix, iy, iz = i0[..., 0] + dx, i0[..., 1] + dy, i0[..., 2] + dz
                ok = (ix >= 0) & (ix < N) & (iy >= 0) & (iy < N) & (iz >= 0) & (iz < N)
                v = np.where(ok, a[np.clip(ix, 0, N - 1), np.clip(iy, 0, N - 1), np.clip(iz, 0, N - 1)], 0.0)
                w = (f[..., 0] if dx else 1 - f[..., 0]) * (f[..., 1] if dy else 1 - f[..., 1]) * (
                    f[..., 2] if dz else 1 - f[..., 2]
                )
                out += w * v
    return out


def blurred(dens, o, d, length):
    h = 0.02
    n = int(np.ceil(length / h))
    h = length / n
    s = (np.arange(n) + 0.5) * h
    p = o[None, :] + s[:, None] * d[None, :]
    v = velocity(p)
    times = SHUTTER[0] + (np.arange(200) + 0.5) / 200 * (SHUTTER[1] - SHUTTER[0])
    ts = []
    for t in times:
        y = p - SCALE * v * t / FPS
        u = (y - OFFSET) / VOXEL
        mu = DENSITY_SCALE * trilinear(dens, u)
        ts.append(np.exp(-mu.sum() * h))
    still = np.exp(-DENSITY_SCALE * trilinear(dens, (p - OFFSET) / VOXEL).sum() * h)
    return float(np.mean(ts)), float(still)


def rays():
    rng = np.random.default_rng(5)
    out = []
    for _ in range(8):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        target = CENTRE + rng.uniform(-4, 4, size=3)
        o = target - d * 20.0
        out.append((o, d, 40.0))
    out.append((CENTRE + np.array([0.0, -20.0, 2.0]), np.array([0.0, 1.0, 0.0]), 40.0))
    return out


dens = density_array()
ref = {"density_scale": DENSITY_SCALE, "shutter": SHUTTER, "fps": FPS, "scale": SCALE, "files": {}}
for name, staggered in (("swirl.vdb", False), ("staggered.vdb", True)):
    write(f"{OUT}/{name}", staggered)
    entries = []
    for o, d, length in rays():
        t, still = blurred(dens, o, d, length)
        entries.append({"origin": list(o), "dir": list(d), "length": length, "T": t, "still": still})
    ref["files"][name] = entries
# A constant velocity (the background of an empty vec3s grid): the blur is a translation.
dens_grid = vdb.FloatGrid()
dens_grid.copyFromArray(density_array(), ijk=(0, 0, 0), tolerance=0)
dens_grid.name = "density"
dens_grid.transform = transform()
still_vel = vdb.Vec3SGrid(CONSTANT)
still_vel.name = "vel"
still_vel.transform = transform()
vdb.write(f"{OUT}/constant.vdb", grids=[dens_grid, still_vel])
ref["constant"] = list(CONSTANT)
rng = np.random.default_rng(11)
probes = CENTRE + rng.uniform(-8.0, 8.0, size=(64, 3))
ref["probes"] = [list(p) + list(v) for p, v in zip(probes, velocity(probes))]
with open(f"{OUT}/reference.json", "w") as f:
    json.dump(ref, f)
