"""Whole-process wall and CPU time of several commands, alternated (issue 67).

Each command runs once as a warm-up, then ROUNDS rounds run them all, the order reversed every
other round; per command the median wall time and the median CPU time (user + system of the
process and its children, from getrusage). The CPU time is the figure a loaded machine disturbs
least; the header gives the load average before and after and whether the CPU has AVX-512.

    python3 bench/alternate.py ROUNDS 'name=command ...' 'name=command ...' ...

The first command is the reference: each row also gives its medians over the reference's.
"""
import os, resource, shlex, statistics, subprocess, sys, time


def run(cmd):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main():
    rounds = int(sys.argv[1])
    named = [a.split("=", 1) for a in sys.argv[2:]]
    cmds = [(n, shlex.split(c)) for n, c in named]
    avx = "avx512f" if "avx512f" in open("/proc/cpuinfo").read() else "no avx512f (AVX2)"
    print(f"load average before: {' '.join(open('/proc/loadavg').read().split()[:3])}; {avx}; "
          f"{os.cpu_count()} cores; {rounds} rounds after a warm-up, alternated")
    times = {n: [] for n, _ in cmds}
    for r in range(rounds + 1):
        order = cmds if r % 2 == 0 else cmds[::-1]
        for n, c in order:
            t = run(c)
            if r > 0:
                times[n].append(t)
    print(f"load average after: {' '.join(open('/proc/loadavg').read().split()[:3])}")
    ref = cmds[0][0]
    rw = statistics.median(w for w, _ in times[ref])
    rc = statistics.median(c for _, c in times[ref])
    print(f"{'command':40} {'wall (s)':>9} {'CPU (s)':>9} {'wall x':>7} {'CPU x':>7}")
    for n, _ in cmds:
        w = statistics.median(x for x, _ in times[n])
        c = statistics.median(x for _, x in times[n])
        print(f"{n:40} {w:9.3f} {c:9.3f} {w / rw:7.2f} {c / rc:7.2f}")


if __name__ == "__main__":
    main()
