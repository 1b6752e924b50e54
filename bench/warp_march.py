# NVIDIA Warp peer for bench/peer.sh (issue 61): the orthographic transmittance view of
# bench/programs/ortho_view.rs marched by a Warp kernel on the CPU device over a `.nvdb` file,
# the way a Python developer in the NanoVDB world would write it today.
#
#   PY bench/warp_march.py FILE.nvdb OUT.exr --scale 5 --dir=0.6,-0.35,-1 \
#       --center=-2.07,1.21,1.93 --up=0,1,0 --frame 4.4 --res 512x512 --step 0.5 [--reps 3]
#
# PY is a Python with `warp-lang` (1.x), numpy and OpenEXR (>= 3.2); peer.sh makes a venv.
#
# The march (one kernel thread per pixel, Dr.Jit's march in bench/mitsuba_transmittance.py
# written in Warp): the pixel's ray starts on the image plane through CENTER (row 0 at the top)
# and runs along DIR; it goes to index space with `wp.volume_world_to_index(_dir)` (the step in
# voxels), is clipped to the box of the grid's leaves widened by one voxel (the support of the
# trilinear field), cut into n = ceil(len / step) equal pieces and sampled at each piece's
# midpoint with `wp.volume_sample_f(..., wp.Volume.LINEAR)` (NanoVDB's trilinear sampler: voxel
# (i, j, k) at index point (i, j, k), OpenVDB's convention, as umbra). T = exp(-scale tau h /
# |index per world|). Warp has no hierarchical empty-space skipping: every midpoint is a lookup.
#
# Timing. "load_s": wp.init and Volume.load_from_nvdb; "compile_s": the first launch, which
# builds (or loads from Warp's kernel cache) the CPU kernel; "render_s": the median of --reps
# launches after it, each to wp.synchronize. Warp's CPU device runs a launch's threads on one
# OS thread ("threads": 1 in the JSON line), whatever the machine has.
import json
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_args import ortho_view, parse  # noqa: E402


def main():
    path, out, opt = parse(sys.argv[1:], "usage: warp_march.py FILE.nvdb OUT.exr [options]")
    scale, d, center, u, r, frame, w, h = ortho_view(opt)
    step = float(opt.get("step", "0.5"))
    reps = int(opt.get("reps", "3"))

    t_load = time.perf_counter()
    import warp as wp

    wp.config.quiet = True
    wp.init()
    with open(path, "rb") as f:
        vol = wp.Volume.load_from_nvdb(f, device="cpu")
    tiles = vol.get_tiles().numpy()  # index origins of the 8^3 leaves
    lo = tiles.min(axis=0).astype(np.float64) - 1.0
    hi = tiles.max(axis=0).astype(np.float64) + 8.0  # last voxel origin + 7, widened by 1
    load_s = time.perf_counter() - t_load

    @wp.kernel
    def march(volume: wp.uint64, center: wp.vec3, r: wp.vec3, u: wp.vec3, d: wp.vec3,
              lo: wp.vec3, hi: wp.vec3, frame: float, width: int, height: int, step: float,
              scale: float, out: wp.array(dtype=float), samples: wp.array(dtype=int)):
        k = wp.tid()
        px = float(k % width)
        py = float(k // width)
        s = frame / float(width)
        x = -frame / 2.0 + s / 2.0 + s * px
        y = frame / 2.0 * float(height) / float(width) - s / 2.0 - s * py
        o = wp.volume_world_to_index(volume, center + r * x + u * y)
        di = wp.volume_world_to_index_dir(volume, d)
        per_world = wp.length(di)
        di = di / per_world
        t0 = float(0.0)
        t1 = float(1.0e30)
        for a in range(3):
            if di[a] != 0.0:
                ta = (lo[a] - o[a]) / di[a]
                tb = (hi[a] - o[a]) / di[a]
                t0 = wp.max(t0, wp.min(ta, tb))
                t1 = wp.min(t1, wp.max(ta, tb))
            elif o[a] < lo[a] or o[a] > hi[a]:
                t1 = -1.0
        length = wp.max(t1 - t0, 0.0)
        n = int(wp.ceil(length / step - 1.0e-4))
        tau = float(0.0)
        hstep = float(0.0)
        if n > 0:
            hstep = length / float(n)
            for i in range(n):
                p = o + di * (t0 + (float(i) + 0.5) * hstep)
                tau += wp.volume_sample_f(volume, p, wp.Volume.LINEAR)
        out[k] = wp.exp(-scale / per_world * tau * hstep)
        samples[k] = n

    t_img = wp.zeros(w * h, dtype=float, device="cpu")
    n_img = wp.zeros(w * h, dtype=int, device="cpu")
    args = [vol.id, wp.vec3(*center), wp.vec3(*r), wp.vec3(*u), wp.vec3(*d), wp.vec3(*lo),
            wp.vec3(*hi), frame, w, h, step, scale, t_img, n_img]
    t0 = time.perf_counter()
    wp.launch(march, dim=w * h, inputs=args, device="cpu")
    wp.synchronize()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(max(reps, 1)):
        t0 = time.perf_counter()
        wp.launch(march, dim=w * h, inputs=args, device="cpu")
        wp.synchronize()
        times.append(time.perf_counter() - t0)
    img = t_img.numpy().reshape(h, w).astype(np.float32)

    import OpenEXR

    OpenEXR.File({"type": OpenEXR.scanlineimage, "compression": OpenEXR.NO_COMPRESSION},
                 {"T": img}).write(out)
    rec = {"renderer": "warp", "version": wp.config.version, "device": "cpu", "threads": 1,
           "res": [w, h], "step": step, "load_s": load_s, "compile_s": compile_s,
           "render_s": statistics.median(times), "renders_s": times,
           "samples_per_ray": float(n_img.numpy().mean())}
    print(json.dumps(rec, separators=(",", ":")), flush=True)


main()
