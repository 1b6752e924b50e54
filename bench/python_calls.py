"""Cost of the Python module's calls against the CLI: 10^6 random segments through
data/cloud.vdb by Volume.transmittance and by `umbra query --rays` (the same rows as CSV),
alternated run by run, the first run of each dropped; a one-ray call; a 1024^2 exact bake.
Run from the repository root with the module installed (`pip install ./python`) and
`cargo build --release --ignore-rust-version`: `python bench/python_calls.py`."""
import numpy as np, time, subprocess, umbra, statistics, os
vol = umbra.Volume("data/cloud.vdb")
rng = np.random.default_rng(0)
N = 1_000_000
a = rng.uniform([-2.2, 0.1, -2.1], [2.1, 3.2, 2.0], (N, 3)); b = rng.uniform([-2.2, 0.1, -2.1], [2.1, 3.2, 2.0], (N, 3))
with open("/tmp/rays1m.csv", "w") as f:
    f.write("ox,oy,oz,ex,ey,ez\n")
    np.savetxt(f, np.hstack([a, b]), delimiter=",", fmt="%.17g")
py, cli, one = [], [], []
for r in range(6):
    t = time.perf_counter(); vol.transmittance(a, b); py.append(time.perf_counter() - t)
    t = time.perf_counter(); subprocess.run(["target/release/umbra", "query", "data/cloud.vdb", "--rays", "/tmp/rays1m.csv", "--json"], stdout=subprocess.DEVNULL, check=True); cli.append(time.perf_counter() - t)
    t = time.perf_counter()
    for _ in range(1000): vol.transmittance(a[:1], b[:1])
    one.append((time.perf_counter() - t) / 1000)
print("python 1e6 rays median %.3f s (runs %s)" % (statistics.median(py[1:]), [round(x,3) for x in py]))
print("cli --rays 1e6 median %.3f s (runs %s)" % (statistics.median(cli[1:]), [round(x,3) for x in cli]))
print("python 1-ray call median %.1f us" % (1e6 * statistics.median(one[1:])))
t=time.perf_counter(); img, cam = vol.bake(light_dir=(-1,-1,0), res=(1024,1024)); print("bake 1024^2 %.3f s" % (time.perf_counter()-t))
