"""Query throughput (issue 34): 10^6 random segments through ../shared/corpus/gen/cloud_fbm.vdb
(density scale 5), exact transmittance from umbra four ways (the Rust call:
`bench/programs/hotpaths.rs segments`, `umbra::regular::optical_depths` as `umbra query --rays` and
Python call it, leaf chords in batches on the SIMD kernel; the f64 walk per ray, the reference
the errors are measured against: `hotpaths segments-rays`;
Python's `Volume.transmittance`; the CLI `umbra query --rays CSV --json` as a whole process)
against a NanoVDB driver on the same segments (`bench/nanovdb_march.cpp --segments`: HDDA
spans, midpoint rule at steps 1 and 0.5). Every tool runs once as a warm-up, then REPS rounds
alternate them; medians. Times are each tool's own trace time (parsing and loading excluded)
except the CLI row (whole process). ns per voxel: the trace time over the voxels the segments
cross inside the grid's widened index box (counted by the NanoVDB driver, the same segments).

Run from the repository root after `cargo build --release --ignore-rust-version --example hotpaths` and with the
Python module installed (`python/run_tests.sh` builds it into target/py-venv), NanoVDB from
Debian's libnanovdb-dev + libnanovdb-tools (`bench/peer.sh` installs them):
    target/py-venv/bin/python bench/queries.py          # REPS=5 THREADS=2 N=1000000
"""
import json, os, statistics, subprocess, time
import numpy as np
import umbra

REPS = int(os.environ.get("REPS", "5"))
THREADS = int(os.environ.get("THREADS", "2"))
N = int(os.environ.get("N", "1000000"))
OUT = os.environ.get("OUT", "/tmp/umbra-queries")
FILE = "../shared/corpus/gen/cloud_fbm.vdb"
SCALE = 5.0
os.makedirs(OUT, exist_ok=True)
os.environ["RAYON_NUM_THREADS"] = str(THREADS)

nano = os.path.join(OUT, "nanovdb_march")
if not os.path.exists(nano) or os.path.getmtime("bench/nanovdb_march.cpp") > os.path.getmtime(nano):
    subprocess.run(["g++", "-O3", "-march=native", "-std=c++17", "-pthread", "-o", nano,
                    "bench/nanovdb_march.cpp"], check=True)
nvdb = os.path.join(OUT, "cloud_fbm.nvdb")
if not os.path.exists(nvdb):
    subprocess.run(["nanovdb_convert", "-f", "-g", "density", FILE, nvdb], check=True,
                   stdout=subprocess.DEVNULL)

# Segments between uniform points of the grid's world box grown by a quarter on each side.
vol = umbra.Volume(FILE, density_scale=SCALE)
lo, hi = np.array(vol.world_bbox[0]), np.array(vol.world_bbox[1])
pad = 0.25 * (hi - lo)
rng = np.random.default_rng(34)
a = rng.uniform(lo - pad, hi + pad, (N, 3))
b = rng.uniform(lo - pad, hi + pad, (N, 3))
csv = os.path.join(OUT, "rays.csv")
with open(csv, "w") as f:
    f.write("ox,oy,oz,ex,ey,ez\n")
    np.savetxt(f, np.hstack([a, b]), delimiter=",", fmt="%.17g")


def run_json(cmd):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def rust():
    j = run_json(["target/release/examples/hotpaths", "segments", FILE, csv, str(SCALE), "1",
                  os.path.join(OUT, "umbra.f32")])
    return j["trace_s"]


def rust_rays():
    j = run_json(["target/release/examples/hotpaths", "segments-rays", FILE, csv, str(SCALE), "1",
                  os.path.join(OUT, "umbra_rays.f32")])
    return j["trace_s"]


def nanovdb(step):
    def go():
        j = run_json([nano, nvdb, "--scale", str(SCALE), "--step", str(step), "--threads",
                      str(THREADS), "--segments", csv, "--out", os.path.join(OUT, f"nano_{step}.f32")])
        go.voxels = j["voxels_per_ray"]
        return j["trace_s"]
    return go


def python():
    t = time.perf_counter()
    vol.transmittance(a, b, threads=THREADS)
    return time.perf_counter() - t


def cli():
    t = time.perf_counter()
    subprocess.run(["target/release/umbra", "query", FILE, "--density-scale", str(SCALE), "--rays", csv,
                    "--threads", str(THREADS), "--json"], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


n1, n05 = nanovdb(1), nanovdb(0.5)
tools = [("umbra exact, Rust call", rust),
         ("umbra exact, one f64 walk per ray (regular::optical_depth, the reference)", rust_rays),
         ("umbra exact, Python Volume.transmittance", python),
         ("umbra exact, CLI query --rays (whole process)", cli), ("NanoVDB march step 1", n1),
         ("NanoVDB march step 0.5", n05)]
times = {name: [] for name, _ in tools}
load = [os.getloadavg()[0]]
for r in range(REPS + 1):
    for name, f in tools:
        t = f()
        if r > 0:
            times[name].append(t)
    load.append(os.getloadavg()[0])

batch = np.fromfile(os.path.join(OUT, "umbra.f32"), dtype=np.float32)
exact = np.fromfile(os.path.join(OUT, "umbra_rays.f32"), dtype=np.float32).astype(np.float64)
py_t = vol.transmittance(a, b, threads=THREADS)
assert np.array_equal(np.asarray(py_t, dtype=np.float32), batch), "Python and Rust differ"
voxels = n1.voxels * N
cpu = open("/proc/cpuinfo").read()
simd = "AVX-512" if "avx512f" in cpu else ("AVX2" if "avx2" in cpu else "SSE")
print(f"{N} segments through cloud_fbm.vdb (scale {SCALE}), {THREADS} threads, {simd} machine, "
      f"median of {REPS} after a warm-up, tools alternated; load average {min(load):.2f}-{max(load):.2f}; "
      f"{n1.voxels:.1f} voxels crossed per segment\n")
print("| tool | trace (s) | Mrays/s | ns per voxel crossed | RMSE of T vs exact | max abs error |")
print("|---|---|---|---|---|---|")
for name, _ in tools:
    s = statistics.median(times[name])
    if name.startswith("NanoVDB"):
        step = "1" if "step 1" in name else "0.5"
        t = np.fromfile(os.path.join(OUT, f"nano_{step}.f32"), dtype=np.float32)
    elif "reference" in name:
        t = exact
    else:
        t = batch  # Python's and the CLI's answers are the Rust call's (asserted above for Python)
    err = t.astype(np.float64) - exact
    acc = f"{np.sqrt(np.mean(err ** 2)):.2e} | {np.abs(err).max():.2e}"
    print(f"| {name} | {s:.3f} | {N / s / 1e6:.2f} | {s * 1e9 / voxels:.2f} | {acc} |")
