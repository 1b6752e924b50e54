#!/usr/bin/env python3
"""Calibration of soft maps against a fixed-count reference (docs/performance.md, section 18).

python3 bench/soft_calibration.py OUT_DIR UMBRA[,UMBRA2...] [CONFIG...]

For each config (the Houdini smoke `s` and data/cloud.vdb at --density-scale 4 `c`, under suns
0.53, 4 and 8 degrees across toward --light-dir 0.3,-1,0.2, a sphere light and a USD RectLight 4
degrees across; `box` a 32^3 box of density 0.2 under the 0.53-degree sun, receivers 400 below, a
hard edge) it bakes a `--light-samples 4096 --seed 0` reference once (kept in OUT_DIR; made with
the first build), then with each build the runs target 5e-3 (default), 2e-3, 1e-2 and fixed 64,
seed 1, and prints one table row per run: penumbra texels (0.02 < T_ref < 0.98), how many are
beyond 4 error bars (|T - T_ref| > 4 sqrt(se^2 + se_ref^2)), the share at or below the target
(to the float rounding of the stored error bar),
inexact texels with an error bar of 0, directions per sampled receiver (mean / p99), capped,
sampled fraction, wall and CPU seconds. Needs numpy and OpenImageIO (python3-openimageio), and
pyopenvdb (python3-openvdb) for the box.
"""
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np
import OpenImageIO as oiio

HERE = os.path.dirname(os.path.abspath(__file__))
SMOKE = os.path.join(HERE, "../../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb")
CLOUD = os.path.join(HERE, "../data/cloud.vdb")
DIR = np.array([0.3, -1.0, 0.2])


def info_centre(umbra, path):
    j = json.loads(subprocess.run([umbra, "info", path, "--json"], check=True,
                                  capture_output=True, text=True).stdout)
    lo, hi = (np.array(v) for v in j["grids"][0]["world_bbox"])
    return (lo + hi) / 2


def rect_stage(out, vdb, centre, away, w, h, scale):
    p = os.path.join(out, f"rect_{os.path.basename(vdb)}.usda")
    pos = centre + np.array([0.0, away, 0.0])
    with open(p, "w") as f:
        f.write(f"""#usda 1.0
(
    startTimeCode = 1
    endTimeCode = 1
)

def Volume "vol"
{{
    rel field:density = </vol/density>

    def OpenVDBAsset "density"
    {{
        asset filePath = @{os.path.abspath(vdb)}@
        token fieldName = "density"
    }}
}}

def RectLight "rect"
{{
    float inputs:width = {w}
    float inputs:height = {h}
    double3 xformOp:translate = ({pos[0]}, {pos[1]}, {pos[2]})
    double3 xformOp:rotateXYZ = (-90, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
}}
""")
    return p, ["--density-scale", str(scale)] if scale != 1 else []


def box(out):
    p = os.path.join(out, "box32.vdb")
    if not os.path.exists(p):
        import pyopenvdb as vdb
        g = vdb.FloatGrid()
        g.fill((0, 0, 0), (31, 31, 31), 0.2, True)
        g.name = "density"
        g.gridClass = vdb.GridClass.FOG_VOLUME
        vdb.write(p, grids=[g])
    return p


def configs(umbra, out):
    d = ",".join(str(x) for x in DIR)
    u = DIR / np.linalg.norm(DIR)
    c = {}
    for tag, vdb, scale, away, radius, rect in [
        ("s", SMOKE, 1, 150.0, 5.24, (10.5, 7)),
        ("c", CLOUD, 4, 6.0, 0.2095, (0.42, 0.28)),
    ]:
        ds = ["--density-scale", str(scale)] if scale != 1 else []
        for angle, res in [("0.53", 64), ("4", 128), ("8", 64)]:
            c[f"{tag} {angle}"] = [vdb, "--light-dir", d, "--light-angle", angle,
                                   "--res", str(res)] + ds
        pos = info_centre(umbra, vdb) - away * u
        c[f"{tag} sphere"] = [vdb, "--light-dir", d, "--light-pos",
                              ",".join(f"{x:.4f}" for x in pos), "--light-radius", str(radius),
                              "--res", "64"] + ds
        stage, extra = rect_stage(out, vdb, info_centre(umbra, vdb), away, *rect, scale)
        c[f"{tag} rect"] = [stage, "--res", "64"] + extra
    c["box"] = [box(out), "--light-dir", "0.05,-1,0.03", "--light-angle", "0.53",
                "--res", "96", "--receiver-depth", "400"]
    return c


def bake(umbra, args, out, extra):
    t0 = time.time()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([umbra, "bake", *args, "--stderr", "--json", "-q", "--force", "-o", out,
                        *extra], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{umbra} bake {' '.join(args)} {' '.join(extra)}: {p.stderr.strip()}")
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime
    return json.loads(p.stdout)["light"], time.time() - t0, cpu


def pixels(path):
    a = oiio.ImageBuf(path).get_pixels(oiio.FLOAT)
    return a[..., 0].astype(float), a[..., 1].astype(float)


def main():
    out, builds = sys.argv[1], sys.argv[2].split(",")
    os.makedirs(out, exist_ok=True)
    cs = configs(builds[0], out)
    names = sys.argv[3:] or list(cs)
    print("| config | build | run | penumbra | beyond 4 | error bar <= target | inexact with bar 0 "
          "| directions mean / p99 | capped | sampled | wall s (CPU s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in names:
        args = cs[name]
        ref = os.path.join(out, f"ref_{name.replace(' ', '_')}.exr")
        if not os.path.exists(ref):
            bake(builds[0], args, ref, ["--light-samples", "4096", "--seed", "0"])
        rt, rs = pixels(ref)
        pen = (rt > 0.02) & (rt < 0.98)
        for b, umbra in enumerate(builds):
            for run, extra, target in [
                ("target 5e-3 (default)", [], 5e-3),
                ("target 2e-3", ["--target-error", "2e-3"], 2e-3),
                ("target 1e-2", ["--target-error", "1e-2"], 1e-2),
                ("fixed 64 (fewest)", ["--light-samples", "64"], None),
            ]:
                # One file per run: OpenImageIO caches images by name.
                o = os.path.join(out, f"run_{name.replace(' ', '_')}_{b}_{len(extra)}"
                                 f"{''.join(extra).replace('-', '')}.exr")
                light, wall, cpu = bake(umbra, args, o, extra + ["--seed", "1"])
                t, s = pixels(o)
                z = np.abs(t - rt) / np.sqrt(s ** 2 + rs ** 2 + 1e-300)
                beyond = int((pen & (z > 4)).sum())
                zero = int(((s == 0) & (np.abs(t - rt) > 4 * rs) & (rt < 1)).sum())
                within = "" if target is None else \
                    f"{100 * (pen & (s <= target * (1 + 2 ** -22))).sum() / max(pen.sum(), 1):.1f}%"
                print(f"| {name} | {b} | {run} | {int(pen.sum())} | {beyond} "
                      f"({100 * beyond / max(pen.sum(), 1):.2f}%) | {within} | {zero} | "
                      f"{light['mean_directions']:.1f} / {light['p99_directions']} | "
                      f"{light['capped']} | {100 * light['sampled_fraction']:.1f}% | "
                      f"{wall:.2f} ({cpu:.2f}) |", flush=True)


if __name__ == "__main__":
    main()
