"""The still `riemann` sweep against a NanoVDB HDDA march, whole process (issue 61).

`umbra bake` (the CLI: start-up, load of the .vdb, planning, the sweep, EXR encode and atomic
write) against `bench/nanovdb_march.cpp` (start-up, load of the .nvdb `nanovdb_convert` made
of the same grid, the march, its EXR write) on bench/peer.sh's 512x512 orthographic views of
cloud_fbm and the Houdini smoke (umbra takes the view as a `--camera` JSON object, the very
pixel rays `bench/programs/ortho_view.rs` builds), at the same step. Also `umbra bake` reading
the .nvdb NanoVDB reads (the same cache; the same pixels). Every command runs once as a
warm-up, then ROUNDS rounds run them all, the order reversed every other round; per command
the median wall time (the whole process), CPU time (user + system, children included) and
render time (umbra `--json`'s `seconds`, the march's `render_s`). The header gives the load
average before and after and the SIMD width the kernel takes.

Run from the repository root:
    python3 bench/still_riemann.py                        # ROUNDS=11 THREADS=2 STEPS=1,0.5
    UMBRA=path/to/old/umbra TAG=base python3 bench/still_riemann.py   # another build's rows
Environment: UMBRA (default target/quick/umbra, built with `cargo build --profile quick
--ignore-rust-version`; more builds as `UMBRA=a,b` and `TAG=x,y`), PRESETS (cloud_fbm,smoke),
OUT (/tmp/umbra-still-riemann: images, the .nvdb files, the driver).
"""
import json, math, os, re, statistics, subprocess, sys, time

ROUNDS = int(os.environ.get("ROUNDS", "11"))
THREADS = os.environ.get("THREADS", "2")
STEPS = os.environ.get("STEPS", "1,0.5").split(",")
PRESETS = os.environ.get("PRESETS", "cloud_fbm,smoke").split(",")
OUT = os.environ.get("OUT", "/tmp/umbra-still-riemann")
UMBRAS = os.environ.get("UMBRA", "target/quick/umbra").split(",")
TAGS = os.environ.get("TAG", ",".join(f"umbra{k}" if k else "umbra" for k in range(len(UMBRAS)))).split(",")
os.makedirs(OUT, exist_ok=True)

# bench/peer.sh's views: file, density scale, direction, centre, frame width.
VIEWS = {
    "cloud_fbm": ("../shared/corpus/gen/cloud_fbm.vdb", 5, [0.6, -0.35, -1], [-2.07, 1.21, 1.93], 4.4),
    "smoke": ("../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb", 0.3, [0.6, -0.35, -1],
              [-34.35, 56.21, 45.43], 130),
}
RES = 512


def camera(d, centre, frame):
    """ortho_view's orthographic camera (up 0,1,0) as `umbra bake --camera` takes it."""
    n = math.sqrt(sum(c * c for c in d))
    d = [c / n for c in d]
    k = d[1]
    u = [-k * d[0], 1 - k * d[1], -k * d[2]]
    n = math.sqrt(sum(c * c for c in u))
    u = [c / n for c in u]
    r = [d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0]]
    n = math.sqrt(sum(c * c for c in r))
    r = [c / n for c in r]
    s = frame / RES
    x0, y0 = -frame / 2 + s / 2, frame / 2 - s / 2
    origin = [centre[a] + r[a] * x0 + u[a] * y0 for a in range(3)]
    return {"kind": "ortho", "width": RES, "height": RES, "origin": origin,
            "step_x": [c * s for c in r], "step_y": [-c * s for c in u], "direction": d,
            "t_max": 1000.0}


def setup():
    nano = f"{OUT}/nanovdb_march"
    if not os.path.exists(nano) or os.path.getmtime("bench/nanovdb_march.cpp") > os.path.getmtime(nano):
        subprocess.run(["g++", "-O3", "-march=native", "-std=c++17", "-pthread", "-o", nano,
                        "bench/nanovdb_march.cpp"], check=True)
    cmds = []
    for p in PRESETS:
        file, scale, d, centre, frame = VIEWS[p]
        nvdb = f"{OUT}/{p}.nvdb"
        if not os.path.exists(nvdb):
            subprocess.run(["nanovdb_convert", "-f", "-g", "density", file, nvdb], check=True)
        cam = f"{OUT}/{p}.json"
        with open(cam, "w") as f:
            json.dump(camera(d, centre, frame), f)
        for step in STEPS:
            for umbra, tag in zip(UMBRAS, TAGS):
                for src, what in [(file, "vdb"), (nvdb, "nvdb")]:
                    cmds.append((f"{p} step {step}: {tag} bake ({what})",
                                 [umbra, "bake", src, "--camera", cam, "--density-scale", str(scale),
                                  "--estimator", "riemann", "--step", step, "--threads", THREADS,
                                  "-o", f"{OUT}/{p}_{tag}_{what}_{step}.exr", "--force", "--json"]))
            cmds.append((f"{p} step {step}: NanoVDB march",
                         [nano, nvdb, "--scale", str(scale), "--dir=" + ",".join(map(str, d)),
                          "--center=" + ",".join(map(str, centre)), "--up=0,1,0", "--frame", str(frame),
                          "--res", f"{RES}x{RES}", "--threads", THREADS, "--step", step,
                          "--out", f"{OUT}/{p}_nanovdb_{step}.exr"]))
    return cmds


def run(cmd):
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    out = p.stdout.read()
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    if status != 0:
        sys.exit(f"failed: {' '.join(cmd)}")
    m = re.search(rb'"(?:render_s|seconds)":([0-9.eE+-]+)', out)
    return wall, ru.ru_utime + ru.ru_stime, float(m.group(1)) if m else math.nan


def main():
    cmds = setup()
    simd = "avx512" if "avx512f" in open("/proc/cpuinfo").read() else "avx2 or less"
    load0 = open("/proc/loadavg").read().split()[:3]
    for _, c in cmds:
        run(c)
    times = {name: [] for name, _ in cmds}
    for r in range(ROUNDS):
        for name, c in cmds if r % 2 == 0 else cmds[::-1]:
            times[name].append(run(c))
    load1 = open("/proc/loadavg").read().split()[:3]
    print(f"load average before {' '.join(load0)}, after {' '.join(load1)}; CPU {simd}; "
          f"{ROUNDS} rounds, medians; threads {THREADS}")
    print("| command | wall (s) | CPU (s) | render (s) |")
    print("|---|---|---|---|")
    for name, _ in cmds:
        w, c, r = zip(*times[name])
        print(f"| {name} | {statistics.median(w):.4f} | {statistics.median(c):.4f} | "
              f"{statistics.median(r):.4f} |")


main()
