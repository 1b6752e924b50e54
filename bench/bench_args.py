"""Command lines of the bench scripts: two positional arguments, then `--key value` or
`--key=value` options (the flags `bench/peer.sh` passes to every renderer)."""

import sys


def parse(args, usage):
    """`(first, second, {key: value})` from `args`; exits with `usage` unless there are exactly
    two positional arguments."""
    pos, opt = [], {}
    i = 0
    while i < len(args):
        a = args[i]
        if a.startswith("--"):
            if "=" in a:
                k, v = a[2:].split("=", 1)
            else:
                k, v = a[2:], args[i + 1]
                i += 1
            opt[k] = v
        else:
            pos.append(a)
        i += 1
    if len(pos) != 2:
        sys.exit(usage)
    return pos[0], pos[1], opt


def vec(s):
    """`x,y,z` as a numpy array of 3; exits naming the text otherwise."""
    import numpy as np

    v = np.array([float(x) for x in s.split(",")])
    if v.shape != (3,):
        sys.exit(f"expected x,y,z: {s}")
    return v


def ortho_view(opt):
    """The orthographic view every peer renders (bench/programs/ortho_view.rs), from the
    options `--scale --dir --center --up --frame --res`: `(scale, d, center, u, r, frame, w,
    h)` with `d` the unit direction, `u` the up vector made orthogonal to it and `r = d x u`."""
    import numpy as np

    scale = float(opt.get("scale", "1"))
    d = vec(opt.get("dir", "0,0,-1"))
    d /= np.linalg.norm(d)
    center = vec(opt.get("center", "0,0,0"))
    up = vec(opt.get("up", "0,1,0"))
    frame = float(opt.get("frame", "1"))
    w, h = (int(x) for x in opt.get("res", "512x512").split("x"))
    u = up - up.dot(d) * d
    u /= np.linalg.norm(u)
    return scale, d, center, u, np.cross(d, u), frame, w, h
