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
