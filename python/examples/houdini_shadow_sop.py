"""Houdini Python SOP: how much of a light reaches each point through a VDB cloud.

Paste into a Python SOP (or point a Python SOP's code at this file) wired after the geometry
whose points you want lit. It writes a float point attribute ``shadowT``: the transmittance
``T = exp(-tau)`` from each point toward the light, exact (regular tracking), 1 where no cloud
is in the way. Use it to drive Cd, a light's shadow mask, or instancing.

Spare parameters it reads when present (defaults otherwise):
  vdb        file path of the .vdb            ($HIP/cloud.vdb)
  grid       grid name                        (density)
  density    density scale                    (1.0)
  lightdir   direction the light travels, 3 floats (-1, -1, 0)

The volume is loaded once per file/grid/scale/modification time and kept in ``hou.session``,
so scrubbing or cooking again only traces. The trace releases Python's GIL and runs on every
core; millions of points take about a second.
"""

import os

import numpy as np

import umbra

_CACHE: dict = {}


def load_volume(path, grid="density", density_scale=1.0, cache=None):
    """The umbra.Volume for a file, cached on (path, grid, scale, mtime)."""
    cache = _CACHE if cache is None else cache
    try:
        mtime = os.path.getmtime(path)
    except OSError:
        mtime = None  # umbra.Volume raises a FileError naming the file
    key = (os.path.abspath(path), grid, float(density_scale), mtime)
    vol = cache.get(key)
    if vol is None:
        for k in [k for k in cache if k[:3] == key[:3]]:
            del cache[k]  # an older version of the same file
        vol = cache[key] = umbra.Volume(path, grid=grid, density_scale=density_scale)
    return vol


def shadow_at_points(positions, path, grid="density", density_scale=1.0, light_dir=(-1, -1, 0),
                     cache=None):
    """T toward a directional light at each world position ((N, 3) array) -> (N,) float32."""
    vol = load_volume(path, grid, density_scale, cache)
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return vol.transmittance_to_light(p, light_dir=light_dir).astype(np.float32)


def _parm(node, name, default):
    p = node.parmTuple(name)
    if p is None:
        return default
    v = p.eval()
    return v[0] if len(v) == 1 else tuple(v)


def cook():
    """The SOP body: read P, trace, write shadowT."""
    import hou  # noqa: PLC0415 (only inside Houdini)

    node = hou.pwd()
    geo = node.geometry()
    path = hou.expandString(_parm(node, "vdb", "$HIP/cloud.vdb"))
    grid = _parm(node, "grid", "density")
    scale = float(_parm(node, "density", 1.0))
    light_dir = _parm(node, "lightdir", (-1.0, -1.0, 0.0))
    cache = hou.session.__dict__.setdefault("_umbra_volumes", {})
    try:
        positions = np.frombuffer(geo.pointFloatAttribValuesAsString("P"), dtype=np.float32)
        t = shadow_at_points(positions, path, grid, scale, light_dir, cache)
    except umbra.Error as e:  # FileError, InvalidArgument: the message names the file or value
        raise hou.NodeError(str(e))
    if geo.findPointAttrib("shadowT") is None:
        geo.addAttrib(hou.attribType.Point, "shadowT", 1.0)
    geo.setPointFloatAttribValuesFromString("shadowT", t.tobytes())


def _in_python_sop():
    """True when this file is a Python SOP's code (not imported as a module)."""
    if __name__ == "houdini_shadow_sop":
        return False
    try:
        import hou  # noqa: PLC0415
    except ImportError:
        return False
    node = hou.pwd()
    return node is not None and node.type().name() == "python"


if _in_python_sop():
    cook()
