# Mitsuba 3 / Dr.Jit peers for bench/peer.sh: the orthographic transmittance view of
# bench/programs/ortho_view.rs, from a dense copy of the grid made by bench/vdb_dense.py.
#
#   bench/.venv/bin/python bench/mitsuba_transmittance.py DENSE.npz OUT.exr --mode volpath|march \
#       --scale 5 --dir=0.6,-0.35,-1 --center=-2.07,1.21,1.93 --up=0,1,0 --frame 4.4 \
#       --res 512x512 --threads 2 [--spp 16] [--step 0.5] [--seed 0] [--variant llvm_ad_mono]
#
# Needs `pip install mitsuba` (3.9.1 was used) and, for the LLVM variants, Debian's libllvm19 with
# DRJIT_LIBLLVM_PATH pointing at it (set here when unset and the file exists): Debian's default
# LLVM 15 crashes Dr.Jit's kernels.
#
# Voxel convention. OpenVDB (and umbra, vdb_render, NanoVDB) put voxel (i, j, k) at the index
# point (i, j, k) and interpolate trilinearly between index points. Mitsuba's grids put the N
# values of an axis at the cell centres (c + 0.5) / N of the unit cube and clamp beyond the first
# and last centre. So the unit cube maps to index space by q = origin - 0.5 + N u, i.e.
# to_world = world_from_index x translate(origin - 0.5) x scale(N), and the one-voxel zero margin
# of vdb_dense.py keeps the clamped field zero outside OpenVDB's support.
#
# --mode volpath: Mitsuba's `volpath` integrator, a `cube` with a `null` BSDF bounding a
#   `heterogeneous` medium (sigma_t = `gridvolume` of the density x --scale per world unit,
#   albedo 0, no emitter sampling from inside, Mitsuba's default global majorant: delta
#   tracking), in front of a `constant` environment of radiance 1, seen by an `orthographic`
#   sensor framed like ortho_view (box filter, independent sampler, --spp samples per pixel).
#   A path that meets a real collision dies (albedo 0), so the pixel is the fraction of escaping
#   paths: an unbiased Bernoulli estimate of T with variance T (1 - T) / spp. Its samples are
#   spread over the pixel's footprint (ortho_view's rays go through pixel centres), an effect far
#   below its noise here.
# --mode march: a vectorised midpoint ray march written with Dr.Jit: one lane per pixel ray
#   through pixel centres, each clipped to the padded grid box in index space, n = ceil(len /
#   step) pieces, one trilinear `mi.Texture3f` lookup at each midpoint in a `dr.while_loop`
#   (one LLVM kernel), T = exp(-tau). No empty-space skipping: the dense box is marched whole.
#
# Prints one JSON line: "load_s" (variant, scene or texture set-up, not timed as render),
# "render_s" (mi.render or the march, to evaluated results; kernels come from Dr.Jit's on-disk
# cache after the first run). Writes a float EXR whose channel Y is T.
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_args import parse, vec  # noqa: E402


def main():
    npz, out, opt = parse(
        sys.argv[1:], "usage: mitsuba_transmittance.py DENSE.npz OUT.exr --mode volpath|march [options]"
    )
    mode = opt.get("mode", "march")
    scale = float(opt.get("scale", "1"))
    d = vec(opt.get("dir", "0,0,-1"))
    d /= np.linalg.norm(d)
    center = vec(opt.get("center", "0,0,0"))
    up = vec(opt.get("up", "0,1,0"))
    frame = float(opt.get("frame", "1"))
    w, h = (int(x) for x in opt.get("res", "512x512").split("x"))
    threads = int(opt.get("threads", "0")) or os.cpu_count()
    spp = int(opt.get("spp", "16"))
    step = float(opt.get("step", "0.5"))
    seed = int(opt.get("seed", "0"))
    variant = opt.get("variant", "llvm_ad_mono")
    llvm19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(llvm19):
        os.environ["DRJIT_LIBLLVM_PATH"] = llvm19

    t_load = time.perf_counter()
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(variant)
    dr.set_thread_count(threads)

    data = np.load(npz)
    dens = np.ascontiguousarray(data["density"], dtype=np.float32)  # [z, y, x]
    origin = data["origin"].astype(np.float64)  # index of dens[0, 0, 0], x y z
    m = data["world_from_index"]
    n_xyz = np.array(dens.shape[::-1], dtype=np.float64)
    # unit cube -> index (cell centres at origin + c) -> world
    cube_to_index = np.eye(4)
    cube_to_index[:3, :3] = np.diag(n_xyz)
    cube_to_index[:3, 3] = origin - 0.5
    grid_to_world = m @ cube_to_index

    # The camera of ortho_view: row 0 at the top, rays from the image plane through CENTER.
    u = up - up.dot(d) * d
    u /= np.linalg.norm(u)
    r = np.cross(d, u)
    s = frame / w

    if mode == "volpath":
        # Mitsuba's orthographic sensor spans camera x in [-1, 1] over the film width and looks
        # along +z; look_at's local x is d x up ("left"), which its projection mirrors back.
        sensor_to_world = mi.ScalarTransform4f().look_at(
            origin=mi.ScalarPoint3f(*center), target=mi.ScalarPoint3f(*(center + d)), up=mi.ScalarVector3f(*u)
        ) @ mi.ScalarTransform4f().scale(mi.ScalarVector3f(frame / 2, frame / 2, 1.0))
        grid = mi.VolumeGrid(dens[..., None])
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": -1},
            "sensor": {
                "type": "orthographic",
                "to_world": sensor_to_world,
                "near_clip": 1e-6,
                "far_clip": 1e6,
                "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                         "pixel_format": "luminance", "component_format": "float32"},
                "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            },
            "light": {"type": "constant", "radiance": 1.0},
            "medium_box": {
                "type": "cube",
                # cube [-1, 1]^3 -> unit cube -> world
                "to_world": mi.ScalarTransform4f(grid_to_world)
                @ mi.ScalarTransform4f().translate(mi.ScalarVector3f(0.5, 0.5, 0.5))
                @ mi.ScalarTransform4f().scale(mi.ScalarVector3f(0.5, 0.5, 0.5)),
                "bsdf": {"type": "null"},
                "interior": {
                    "type": "heterogeneous",
                    "albedo": 0.0,
                    # no shadow rays from inside: with albedo 0 they are weighted 0 anyway, and
                    # their transmittance loops cost half the render (same image, bit for bit)
                    "sample_emitters": False,
                    "scale": scale,
                    "sigma_t": {"type": "gridvolume", "grid": grid, "to_world": mi.ScalarTransform4f(grid_to_world)},
                },
            },
        })
        load_s = time.perf_counter() - t_load
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        render_s = time.perf_counter() - t0
        t_img = np.array(img, dtype=np.float32).reshape(h, w)
    elif mode == "march":
        tex = mi.Texture3f(mi.TensorXf(dens[..., None]))
        dr.eval(tex.tensor())
        dr.sync_thread()
        load_s = time.perf_counter() - t_load
        mi_inv = np.linalg.inv(m)
        di = mi_inv[:3, :3] @ d
        idx_len = np.linalg.norm(di)  # index units per world unit along d
        di /= idx_len
        o_center = mi_inv[:3, :3] @ center + mi_inv[:3, 3]  # pixel origins, index space
        ri, ui = mi_inv[:3, :3] @ r, mi_inv[:3, :3] @ u
        lo, hi = origin, origin + n_xyz - 1.0  # the padded box: support of the trilinear field
        # Python floats from here on: numpy scalars would turn Dr.Jit arrays into numpy arrays
        di, o_center, ri, ui, lo, hi = ([float(c) for c in v] for v in (di, o_center, ri, ui, lo, hi))
        cell0 = [float(c) - 0.5 for c in origin]
        n3 = [float(c) for c in n_xyz]
        idx_len = float(idx_len)

        t0 = time.perf_counter()
        k = dr.arange(mi.UInt32, w * h)
        px = mi.Float(k % w)
        py = mi.Float(k // w)
        x = -frame / 2 + s / 2 + s * px
        y = frame / 2 * h / w - s / 2 - s * py
        o = mi.Vector3f(*(o_center[a] + ri[a] * x + ui[a] * y for a in range(3)))
        t_near, t_far = mi.Float(0.0), mi.Float(math.inf)
        for a in range(3):
            if di[a] != 0.0:
                ta = (lo[a] - o[a]) / di[a]
                tb = (hi[a] - o[a]) / di[a]
                t_near = dr.maximum(t_near, dr.minimum(ta, tb))
                t_far = dr.minimum(t_far, dr.maximum(ta, tb))
            else:
                inside = (o[a] >= lo[a]) & (o[a] <= hi[a])
                t_far = dr.select(inside, t_far, -1.0)
        length = dr.maximum(t_far - t_near, 0.0)
        n = mi.UInt32(dr.ceil(length / step - 1e-4))
        hstep = dr.select(n > 0, length / mi.Float(n), 0.0)
        # midpoint k at index point o + di (t_near + (k + 0.5) h); texture coordinates affine in k
        p0 = (o + mi.Vector3f(*di) * (t_near + 0.5 * hstep) - mi.Vector3f(*cell0)) / mi.Vector3f(*n3)
        dp = mi.Vector3f(*di) * hstep / mi.Vector3f(*n3)

        def cond(i, tau):
            return i < n

        def body(i, tau):
            p = dr.fma(dp, mi.Float(i), p0)
            return i + 1, tau + tex.eval(mi.Point3f(p))[0]

        _, tau = dr.while_loop(state=(mi.UInt32(0), mi.Float(0.0)), cond=cond, body=body)
        t_lane = dr.exp(-(scale / idx_len) * tau * hstep)
        dr.eval(t_lane)
        dr.sync_thread()
        render_s = time.perf_counter() - t0
        t_img = np.array(t_lane, dtype=np.float32).reshape(h, w)
        samples = float(np.sum(np.array(n, dtype=np.float64))) / (w * h)
    else:
        sys.exit(f"unknown --mode {mode} (volpath | march)")

    mi.Bitmap(t_img[..., None]).write(out)
    rec = {"mode": mode, "variant": variant, "threads": threads, "res": [w, h], "load_s": load_s, "render_s": render_s}
    if mode == "volpath":
        rec["spp"] = spp
    else:
        rec["step"] = step
        rec["samples_per_ray"] = samples
    print(json.dumps(rec, separators=(",", ":")), flush=True)


main()
