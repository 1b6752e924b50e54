# Whole `umbra bake` of .vdb and .nvdb files by several umbra builds, alternated (issue 61): a
# 256 map (--light-dir 0.6,-0.35,-1), each build on each file once per round, the first round a
# warm-up; per file and build the medians of the bake's `total_seconds`, of its load and set-up
# (`total_seconds - seconds`), of the process's CPU seconds, and its peak RSS; and whether every
# build wrote the same map, byte for byte. Results in docs/performance.md ("Loading NanoVDB").
#
#   python3 bench/nvdb_bake.py ROUNDS OLD_UMBRA,NEW_UMBRA FILE[:GRID[:SCALE]]...
#   python3 bench/nvdb_bake.py 7 /tmp/umbra.old,target/quick/umbra dense.vdb:[0]:0.02 dense.zip.nvdb:[0]:0.02
#
# GRID defaults to density, SCALE (--density-scale) to 1. Needs GNU time at /usr/bin/time.
import json
import os
import statistics
import subprocess
import sys
import tempfile


def main():
    if len(sys.argv) < 4:
        sys.exit("usage: nvdb_bake.py ROUNDS UMBRA[,UMBRA...] FILE[:GRID[:SCALE]]...")
    rounds, builds = int(sys.argv[1]), sys.argv[2].split(",")
    files = [(a.split(":") + ["density", "1"])[:3] for a in sys.argv[3:]]
    out = tempfile.mkdtemp()
    runs = {}
    print("load average before:", " ".join(open("/proc/loadavg").read().split()[:3]))
    for r in range(rounds + 1):
        for path, grid, scale in files:
            for k, umbra in enumerate(builds):
                exr = os.path.join(out, f"{k}.{os.path.basename(path)}.exr")
                cmd = ["/usr/bin/time", "-f", "%M %U %S", umbra, "bake", path, "--grid", grid,
                       "--density-scale", scale, "--light-dir", "0.6,-0.35,-1", "--res", "256",
                       "-o", exr, "--force", "--quiet", "--json"]
                p = subprocess.run(cmd, capture_output=True, text=True, check=True)
                j = json.loads(p.stdout)
                rss, user, sys_s = p.stderr.split()[-3:]
                if r > 0:
                    runs.setdefault((path, k), []).append(
                        (j["total_seconds"], j["total_seconds"] - j["seconds"],
                         float(user) + float(sys_s), int(rss) / 1024))
    print("load average after:", " ".join(open("/proc/loadavg").read().split()[:3]))
    print("| file | build | bake total | load and set-up | CPU s | peak RSS MiB |")
    print("|---|---|---:|---:|---:|---:|")
    for path, _, _ in files:
        maps = set()
        for k, _ in enumerate(builds):
            v = runs[(path, k)]
            med = [statistics.median(x[i] for x in v) for i in range(3)]
            print(f"| {path} | {k} | {med[0]:.3f} | {med[1]:.3f} | {med[2]:.2f} | "
                  f"{max(x[3] for x in v):.1f} |")
            with open(os.path.join(out, f"{k}.{os.path.basename(path)}.exr"), "rb") as f:
                maps.add(f.read())
        if len(maps) != 1:
            print(f"MAPS DIFFER between builds: {path}")


main()
