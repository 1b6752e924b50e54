"""umbra: how much light gets through this OpenVDB cloud?

Exact (regular tracking) and stochastic transmittance through ``.vdb`` volumes, NumPy in, NumPy
out. The work runs in Rust on every core with the GIL released, so other Python threads (a
DCC's UI, a farm submitter's heartbeat) keep running.

    >>> import numpy as np, umbra
    >>> vol = umbra.Volume("cloud.vdb", grid="density")
    >>> T = vol.transmittance(np.array([[0, 1.5, 0]]), np.array([[3, 4.5, 0]]))
    >>> image, camera = vol.bake(light_dir=(-1, -1, 0), res=(256, 256))
    >>> umbra.write_exr("shadow.exr", image, camera)
    >>> camera, deep = vol.write_deep_map("deep.exr", light_dir=(-1, -1, 0), res=256)

Results equal the command line's bit for bit: row ``n`` of a call uses ray id ``ray_id + n``,
as line ``n`` of ``umbra query --rays`` does, and ``bake`` makes the pixels ``umbra bake``
writes. Errors are :class:`umbra.Error` (:class:`umbra.FileError`, also an ``OSError``;
:class:`umbra.InvalidArgument`, also a ``ValueError``) with the CLI's messages.
"""

from __future__ import annotations

import json
import os
import warnings as _warnings
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _umbra
from ._errors import Error, FileError, InvalidArgument

__version__: str = _umbra.__version__

__all__ = [
    "Error",
    "FileError",
    "InvalidArgument",
    "Volume",
    "bake",
    "deep_lookup",
    "deep_transmittance",
    "emit_job",
    "estimators",
    "info",
    "job_status",
    "sample_omni",
    "run_job",
    "usd_lights",
    "usd_point_transmittance",
    "write_exr",
]

PathLike = Union[str, "os.PathLike[str]"]
Vec3 = Union[Sequence[float], np.ndarray]

def _invalid(name: str, reason: str) -> InvalidArgument:
    return InvalidArgument(f"invalid argument '{name}': {reason}")


def _path(name: str, p: Any) -> str:
    try:
        return os.fsdecode(os.fspath(p))
    except TypeError:
        raise _invalid(name, f"expected a path, got {type(p).__name__}") from None


def _points(name: str, a: Any) -> np.ndarray:
    """``a`` as a C-contiguous float64 (N, 3) array of finite world points."""
    try:
        arr = np.asarray(a)
    except (TypeError, ValueError) as e:
        raise _invalid(name, f"expected an (N, 3) array of numbers ({e})") from None
    if arr.dtype.kind not in "fiu":
        raise _invalid(name, f"expected an (N, 3) array of real numbers, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise _invalid(name, f"expected an array of shape (N, 3), got shape {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        row = int(np.argmax(bad))
        raise _invalid(
            name,
            f"row {row} ({', '.join(repr(float(v)) for v in arr[row])}) is not a finite point"
            f" ({int(bad.sum())} of {len(arr)} rows are not)",
        )
    return arr


def _vec3(name: str, v: Any) -> Optional[Tuple[float, float, float]]:
    if v is None:
        return None
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise _invalid(name, f"expected three numbers, got {v!r}") from None
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise _invalid(name, f"expected three finite numbers, got {v!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    raise TypeError(f"{v!r} is not a number, a string, a path or a sequence of them")


def _options(**kw: Any) -> str:
    """Bake options as the library reads them (JSON text): the keywords by their canonical
    names (a keyword left at ``None`` takes the library's default). The library checks every
    value and names the keyword that is wrong."""
    given = {k: v for k, v in kw.items() if v is not None}
    for k, v in given.items():
        try:
            json.dumps(v, default=_jsonable, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise _invalid(k, f"{v!r}: {e}") from None
    return json.dumps(given, default=_jsonable, allow_nan=False)


def _alias(canonical: str, value: Any, alias: str, alias_value: Any, default: Any) -> Any:
    """``value``, or the older spelling's ``alias_value`` when only that was given."""
    if alias_value is None:
        return value
    if value != default and value != alias_value:
        raise _invalid(alias, f"is another name of {canonical}: give one of them")
    return alias_value


def _extent(
    light_angle: Any, light_radius: Any, light_samples: Any
) -> Tuple[Optional[float], Optional[float], Optional[int]]:
    """The keywords of a light with extent, by type (the library checks their values and
    names the keyword that is wrong: negative, NaN, an angle of 180 degrees or more)."""

    def real(name: str, v: Any) -> Optional[float]:
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise _invalid(name, f"expected a number, got {v!r}")
        return float(v)

    n = None if light_samples is None else _count("light_samples", light_samples)
    if n is not None and n >= 2**32:
        raise _invalid("light_samples", f"{n} is out of range")
    return real("light_angle", light_angle), real("light_radius", light_radius), n


def _count(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise _invalid(name, f"expected a whole number, got {v!r}")
    if int(v) < 0 or int(v) >= 2**64:
        raise _invalid(name, f"{v} is out of range")
    return int(v)


#: The estimator keywords with their library defaults, in order (``estimator``, ``samples``,
#: ``seed``, ``step``, ``kernel``, ``points``, ``granularity``, ``global_majorant``,
#: ``colour_walk``, and motion blur's ``velocity``, ``shutter``, ``fps``, ``velocity_scale``,
#: ``time_samples``): the library's one list (``request::EstimatorOptions``). Every call that
#: takes an estimator takes all of them, forwarded through :func:`_estimator_options`
#: (``tests/test_keywords.py`` holds the signatures and stubs to it).
_ESTIMATOR_OPTIONS: Dict[str, Any] = json.loads(_umbra.estimator_options_json())


def _estimator_options(given: Dict[str, Any], **spelled: str) -> Dict[str, Any]:
    """The estimator keywords of a call, picked by the one list from the call's ``locals()``
    (``spelled``: a keyword the call spells otherwise, as ``points="points_per_estimate"``)."""
    return {k: given[spelled.get(k, k)] for k in _ESTIMATOR_OPTIONS}


def _segments(origins: Any, ends: Any) -> Tuple[np.ndarray, np.ndarray]:
    o = _points("origins", origins)
    e = _points("ends", ends)
    if o.shape != e.shape:
        raise _invalid("ends", f"{len(o)} origins but {len(e)} ends")
    return o, e


def _sampling(options: Dict[str, Any], ray_id: Any, threads: Any):
    """The native trace calls' trailing arguments: the estimator options (checked by the
    library, which names the keyword that is wrong), the first ray id and the thread count."""
    return (_options(**options), _count("ray_id", ray_id), _count("threads", threads))


def _xform(xform: Any) -> Optional[List[float]]:
    if xform is None:
        return None
    try:
        m = np.asarray(xform, dtype=np.float64)
    except (TypeError, ValueError):
        raise _invalid("xform", "expected a 4x4 matrix (or 16 numbers, row-major)") from None
    if m.size != 16 or m.ndim not in (1, 2) or (m.ndim == 2 and m.shape != (4, 4)):
        raise _invalid(
            "xform", f"expected a 4x4 matrix (or 16 numbers, row-major), got shape {m.shape}"
        )
    return [float(x) for x in m.reshape(16)]


def _warn(lines: Sequence[str]) -> None:
    for w in lines:
        _warnings.warn(f"umbra: {w}", RuntimeWarning, stacklevel=3)


def _finish(t: np.ndarray, err: np.ndarray, return_stderr: bool):
    if t.shape[1] == 1:
        t, err = t[:, 0], err[:, 0]
    return (t, err) if return_stderr else t


def info(path: PathLike, grid: Optional[str] = None) -> List[Dict[str, Any]]:
    """What ``umbra info --json PATH`` reports, one dict per grid (every grid, or only
    ``grid``): name, type, class, voxel size, transform, index and world boxes, active voxels,
    tiles, value range, NaN/Inf counts, memory. Only the header, topology and (streamed)
    values are read.

    Raises :class:`FileError` for a file that cannot be read, :class:`InvalidArgument` for a
    grid it does not hold or a scene file.
    """
    return json.loads(_umbra.info_json(_path("path", path), grid))["grids"]


def run_job(
    path: PathLike,
    *,
    task: Optional[int] = None,
    shard: Optional[Tuple[int, int]] = None,
    force: bool = False,
    log: Optional[PathLike] = None,
    jobs: int = 0,
    progress: Optional[Callable[[int, int], Any]] = None,
    keep_unkeyed: bool = False,
    verify: bool = False,
) -> Dict[str, Any]:
    """Run a batch job file as ``umbra batch PATH`` does (the same runner, the same outputs
    and JSON-lines log): every task, or only ``task`` (0-based, as ``--plan`` numbers them),
    or shard ``(I, N)`` (1-based); up-to-date outputs (those carrying the task's key: its
    settings, light, camera and the identity of every file it reads) are skipped unless
    ``force``; ``keep_unkeyed`` takes outputs without a key (an older umbra's) as up to date;
    ``verify`` hashes every input even when its size and time match the key's; ``log``
    replaces the job's log (its directory must exist); ``jobs`` tasks at once (0: as many as
    cores). ``progress(done, total)`` is called as work finishes, from the runner's threads:
    each task's share is its map's pixels when every map has a known size, else 1000 units
    (a positions task: 1), and moves as its bake does.

    Returns the run's report: ``selected``, ``baked``, ``skipped``, ``failed``, ``seconds``,
    ``workers``, ``threads_per_task``, ``log`` and ``records`` (one dict per task, as the log
    holds them: ``task``, ``input``, ``light``, ``output``, ``status``, ``error``, ``reason``
    (why it was baked, ``settings changed: bake.density_scale``, or ``up to date``), ...). A
    failed task does not raise: it is counted and recorded. Raises :class:`FileError` for a
    job file that cannot be read or is invalid, or a missing input;
    :class:`InvalidArgument` for ``task``/``shard``/``log`` out of range.
    """
    if task is not None:
        task = _count("task", task)
    if shard is not None:
        try:
            i, n = (int(x) for x in shard)
        except (TypeError, ValueError):
            raise _invalid("shard", f"{shard!r}: give (I, N), two integers") from None
        shard = (i, n)
    if progress is not None and not callable(progress):
        raise _invalid("progress", "give a callable progress(done, total)")
    log_path = None if log is None else _path("log", log)
    report = _umbra.run_job(
        _path("path", path),
        task,
        shard,
        bool(force),
        log_path,
        _count("jobs", jobs),
        progress,
        bool(keep_unkeyed),
        bool(verify),
    )
    return json.loads(report)


def _omni_coords(header: Dict[str, Any], points: Any, h: int, w: int):
    """Where world ``points`` land in an omnidirectional map of ``h x w`` texels (see
    :func:`sample_omni`): the texels around each ``(i0, j0, i1, j1)``, the bilinear weights
    ``(fx, fy)`` and each point's distance from the light."""
    if "camera" in header and isinstance(header["camera"], dict):
        cam = header["camera"]
        kind, origin = cam.get("kind"), cam.get("origin")
        fwd = np.asarray(cam.get("direction", (0, 0, 1)), dtype=np.float64)
        sx = np.asarray(cam.get("step_x", (-1, 0, 0)), dtype=np.float64)
        sy = np.asarray(cam.get("step_y", (0, -1, 0)), dtype=np.float64)
        axes = (-sx / np.linalg.norm(sx), -sy / np.linalg.norm(sy), fwd / np.linalg.norm(fwd))
    else:
        kind, origin = header.get("umbra:camera_kind"), header.get("umbra:camera_origin")
        axes = tuple(np.asarray(header.get(f"umbra:omni_{a}", e), dtype=np.float64)
                     for a, e in (("x", (1, 0, 0)), ("y", (0, 1, 0)), ("z", (0, 0, 1))))
    if kind not in ("cube", "latlong") or origin is None:
        raise _invalid("header", f"not an omnidirectional map (camera kind {kind!r})")
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if p.ndim != 2 or p.shape[1] != 3:
        raise _invalid("points", f"expected (3,) or (K, 3), got shape {np.shape(points)}")
    d = p - np.asarray(origin, dtype=np.float64)
    x, y, z = (d @ a for a in axes)
    if kind == "latlong":
        n = np.sqrt(x * x + y * y + z * z)
        lat = np.arcsin(np.clip(np.divide(y, n, out=np.zeros_like(y), where=n > 0), -1, 1))
        lon = np.where((x == 0) & (z == 0), 0.0, np.arctan2(x, z))
        px = (w - 1) * (0.5 - lon / (2 * np.pi))
        py = (h - 1) * (0.5 - lat / np.pi)
        lo = np.zeros_like(px)
        hi_x, hi_y = np.full_like(px, w - 1.0), np.full_like(py, h - 1.0)
        y0 = lo
    else:
        sof = w
        m = sof - 1.0
        ax, ay, az = np.abs(x), np.abs(y), np.abs(z)
        face = np.where((ax >= ay) & (ax >= az), np.where(x > 0, 0, 1),
                        np.where(ay >= az, np.where(y > 0, 2, 3), np.where(z > 0, 4, 5)))
        big = np.choose(np.minimum(face // 2, 2), [ax, ay, az])
        big = np.where(big == 0, 1.0, big)
        u = np.choose(face // 2, [y, x, x]) / big
        v = np.choose(face // 2, [z, z, y]) / big
        pif_x, pif_y = (u + 1) / 2 * m, (v + 1) / 2 * m
        # OpenEXR's pixelPosition, per face, within the face's rows [f N, f N + m].
        fx = np.choose(face, [pif_y, m - pif_y, pif_x, pif_x, m - pif_x, pif_x])
        fy = np.choose(face, [m - pif_x, m - pif_x, m - pif_y, pif_y, m - pif_y, m - pif_y])
        y0 = face * float(sof)
        px, py = fx, y0 + fy
        lo = np.zeros_like(px)
        hi_x, hi_y = np.full_like(px, m), y0 + m
    px = np.clip(px, lo, hi_x)
    py = np.clip(py, y0, hi_y)
    i0 = np.floor(px).astype(np.int64)
    j0 = np.floor(py).astype(np.int64)
    i1 = np.minimum(i0 + 1, hi_x.astype(np.int64))
    j1 = np.minimum(j0 + 1, hi_y.astype(np.int64))
    fx, fy = px - i0, py - j0
    return i0, j0, i1, j1, fx, fy, np.sqrt(x * x + y * y + z * z)


def sample_omni(image: Any, header: Dict[str, Any], points: Any) -> np.ndarray:
    """Look an omnidirectional map (``umbra bake --omni cube|latlong``) up toward world
    ``points``: for each point ``p``, the map's value along the ray from the light ``P`` through
    ``p`` (T of that whole ray, as the map holds it), bilinear between the texels around the
    direction, as OpenEXR's ``ImfEnvmap`` places them.

    ``image``: the map as read, ``(H, W)`` or ``(H, W, C)``. ``header``: the EXR's attributes
    as OpenImageIO's ``spec.extra_attribs`` give them (``umbra:camera_kind``,
    ``umbra:camera_origin``, ``umbra:omni_x``/``_y``/``_z``), or the dict ``bake`` and
    ``Volume.bake`` return (its ``camera``). ``points``: ``(3,)`` or ``(K, 3)``. Returns
    ``(K,)`` (or ``(K, C)``).

    The direction ``d = p - P`` in the map's axes, ``(x, y, z) = (d . X_m, d . Y_m, d . Z_m)``,
    lands at (the inverse of the texel directions of ``docs/omni.md``):

    - latlong (``W x H``): ``lat = asin(y / |d|)``, ``lon = atan2(x, z)``, at
      ``(W - 1) (1/2 - lon / 2 pi), (H - 1) (1/2 - lat / pi)``;
    - cube (``N x 6N``): the face of the largest ``|component|`` (``+X, -X, +Y, -Y, +Z, -Z``
      from the top); in it OpenEXR's ``faceAndPixelPosition`` and ``pixelPosition``.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim not in (2, 3):
        raise _invalid("image", f"expected (H, W) or (H, W, C), got shape {img.shape}")
    h, w = img.shape[:2]
    i0, j0, i1, j1, fx_, fy_, _ = _omni_coords(header, points, h, w)
    if img.ndim == 3:
        fx_, fy_ = fx_[:, None], fy_[:, None]
    out = ((img[j0, i0] * (1 - fx_) + img[j0, i1] * fx_) * (1 - fy_)
           + (img[j1, i0] * (1 - fx_) + img[j1, i1] * fx_) * fy_)
    return out


# The constants of umbra's moment reconstruction (src/bake/encode/fixed/moments.rs).
_MOMENT_BIAS = {4: 5e-7, 6: 5e-6}
_OVERESTIMATION = 0.25
_FAR_ROOT = 1e3


def _interpolated_share(z: np.ndarray, m: np.ndarray, x: float) -> float:
    """``sum_j q_j m_j`` for the polynomial ``q`` through ``(x, 1/4)`` and ``(z_i, [z_i < x])``
    (one query, any number of roots)."""
    atoms = np.concatenate([[x], z])
    d = len(z)
    dd = np.concatenate([[_OVERESTIMATION], (z < x).astype(np.float64)])
    for lvl in range(1, d + 1):
        for i in range(d, lvl - 1, -1):
            dd[i] = (dd[i] - dd[i - 1]) / (atoms[i] - atoms[i - lvl])
    poly = np.zeros(d + 1)
    poly[0] = dd[d]
    for i in range(d - 1, -1, -1):
        for j in range(d - i, 0, -1):
            poly[j] = poly[j - 1] - atoms[i] * poly[j]
        poly[0] = dd[i] - atoms[i] * poly[0]
    return float(np.sum(poly * m[:d + 1]))


def _fourier_tau(c: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Fejer-windowed Fourier optical depth at ``u`` (``c``: ``(K, 2N + 1)``)."""
    n = (c.shape[1] - 1) // 2
    tau = c[:, 0] * u
    for i in range(1, n + 1):
        w = 2 * np.pi * i
        f = 1.0 - i / (n + 1)
        tau = tau + f * (c[:, 2 * i - 1] * np.sin(w * u) + c[:, 2 * i] * (1 - np.cos(w * u))) / w
    return np.maximum(tau, 0.0)


def _moments_tau(c: np.ndarray, u: np.ndarray, k: int) -> np.ndarray:
    """Moment-bound optical depth ``b0 F(x)`` at ``u`` (``c``: ``(K, k + 1)``)."""
    b0 = c[:, 0]
    n = k // 2
    x = np.clip(2 * u - 1, -1.0, 1.0)
    beta = _MOMENT_BIAS[k]
    star = np.array([1.0 / (j + 1) if j % 2 == 0 else 0.0 for j in range(2 * n + 1)])
    m = np.empty((len(x), 2 * n + 1))
    m[:, 0] = 1.0
    m[:, 1:] = (1 - beta) * c[:, 1:2 * n + 1] + beta * star[1:]
    hankel = np.stack([np.stack([m[:, i + j] for j in range(n + 1)], -1) for i in range(n + 1)], -2)
    rhs = np.stack([x ** j for j in range(n + 1)], -1)
    with np.errstate(all="ignore"):
        coef = np.linalg.solve(hankel, rhs[..., None])[..., 0]
        if n == 2:
            a, b, cc = coef[:, 2], coef[:, 1], coef[:, 0]
            disc = np.maximum(b * b - 4 * a * cc, 0.0)
            q = -0.5 * (b + np.where(b >= 0, 1.0, -1.0) * np.sqrt(disc))
            roots = np.stack([q / a, cc / q], -1)
        else:
            # The largest root by the trigonometric solution, polished by Newton, then the
            # quadratic left from the constant term up (moments.rs's `cubic`).
            a3, a2, a1, a0 = coef[:, 3], coef[:, 2], coef[:, 1], coef[:, 0]
            b, cc, d = a2 / a3, a1 / a3, a0 / a3
            p = cc - b * b / 3
            q = 2 * b ** 3 / 27 - b * cc / 3 + d
            m3 = 2 * np.sqrt(np.maximum(-p / 3, 0.0))
            phi = np.arccos(np.clip(3 * q / (p * m3), -1, 1)) / 3
            trig = np.stack([m3 * np.cos(phi - 2 * np.pi * i / 3) - b / 3 for i in range(3)], -1)
            big = trig[np.arange(len(x)), np.argmax(np.abs(trig), axis=1)]
            r = np.where(p >= 0, np.cbrt(-q) - b / 3, big)
            for _ in range(2):
                f = ((a3 * r + a2) * r + a1) * r + a0
                df = (3 * a3 * r + 2 * a2) * r + a1
                r = np.where(df != 0, r - f / df, r)
            qc = -a0 / r
            qb = (qc - a1) / r
            qa = (qb - a2) / r
            disc = np.maximum(qb * qb - 4 * qa * qc, 0.0)
            qq = -0.5 * (qb + np.where(qb >= 0, 1.0, -1.0) * np.sqrt(disc))
            roots = np.stack([qq / qa, qc / qq, r], -1)
        z = np.concatenate([x[:, None], roots], -1)
        vals = np.concatenate([np.full((len(x), 1), _OVERESTIMATION),
                               (roots < x[:, None]).astype(np.float64)], -1)
        d = n
        dd = vals.copy()
        for lvl in range(1, d + 1):
            for i in range(d, lvl - 1, -1):
                dd[:, i] = (dd[:, i] - dd[:, i - 1]) / (z[:, i] - z[:, i - lvl])
        poly = np.zeros((len(x), d + 1))
        poly[:, 0] = dd[:, d]
        for i in range(d - 1, -1, -1):
            for j in range(d - i, 0, -1):
                poly[:, j] = poly[:, j - 1] - z[:, i] * poly[:, j]
            poly[:, 0] = dd[:, i] - z[:, i] * poly[:, 0]
        f = np.sum(poly * m[:, :d + 1], -1)
        # A root far outside [-1, 1] is dropped (its weight is of order |y|^-2n): those
        # queries one by one, the other roots interpolated.
        far = np.any(~(np.abs(roots) <= _FAR_ROOT), axis=1)
        for r in np.flatnonzero(far):
            keep = roots[r][np.abs(roots[r]) <= _FAR_ROOT]
            f[r] = _interpolated_share(keep, m[r], x[r])
    bad = ~np.isfinite(f)
    f = np.where(bad, (x >= m[:, 1]).astype(np.float64), np.clip(f, 0.0, 1.0))
    return np.where(b0 > 0, b0 * f, 0.0)


def _avsm_tau(c: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Node optical depth at ``u`` (``c``: ``(K, 2k)``, ``z0, tau0, z1, tau1, ...``)."""
    z, t = c[:, 0::2], c[:, 1::2]
    k = z.shape[1]
    idx = np.sum(z <= u[:, None], axis=1)
    rows = np.arange(len(u))
    hi = np.minimum(idx, k - 1)
    lo = np.maximum(idx - 1, 0)
    z0, z1, t0, t1 = z[rows, lo], z[rows, hi], t[rows, lo], t[rows, hi]
    with np.errstate(all="ignore"):
        w = np.clip(np.where(z1 > z0, (u - z0) / (z1 - z0), 1.0), 0.0, 1.0)
    tau = np.where(idx == 0, 0.0, np.where(idx >= k, t[:, -1], t0 + (t1 - t0) * w))
    return np.maximum(tau, 0.0)


def deep_transmittance(fmt: str, coefficients: Any, u: Any) -> np.ndarray:
    """``T`` of texels of a fixed-size deep map (``umbra bake --deep-format FORMAT``) at
    normalised depths ``u`` (``(z - near) / (far - near)``, ``near``/``far`` the header's
    ``umbra:deep_near``/``umbra:deep_far``): ``coefficients`` ``(K, C)`` are the texels'
    channels in the format's order (:func:`deep_lookup` gathers them by name), ``u`` ``(K,)``.
    The reconstructions, each written out in ``docs/deep_formats.md``:

    - ``fourier:K``: ``tau(u) = a0 u + sum_k f_k (a_k sin(w u) + b_k (1 - cos(w u))) / w``,
      ``w = 2 pi k``, ``f_k = 1 - k / (N + 1)`` (Fejer), ``N = (K - 1) / 2``;
    - ``moments:4|6``: ``tau = b0 F(2u - 1)``, ``F`` the Hamburger moment bound (moments biased
      toward the uniform distribution's, overestimation 1/4);
    - ``avsm:K``: ``tau`` linear between the nodes ``(z_i, tau_i)``, 0 before the first.

    ``T = exp(-tau)`` is in ``[0, 1]`` and never grows with depth."""
    c = np.atleast_2d(np.asarray(coefficients, dtype=np.float32)).astype(np.float64)
    uu = np.broadcast_to(np.asarray(u, dtype=np.float64), (c.shape[0],)).copy()
    name, _, k = str(fmt).partition(":")
    if name == "fourier":
        tau = _fourier_tau(c, np.clip(uu, 0.0, 1.0))
    elif name == "moments" and k in ("4", "6"):
        tau = _moments_tau(c, uu, int(k))
    elif name == "avsm":
        tau = _avsm_tau(c, uu)
    else:
        raise _invalid("format", f"{fmt!r}: expected fourier:K, moments:4, moments:6 or avsm:K")
    return np.exp(-tau)


def _channel_order(fmt: str) -> List[str]:
    name, _, k = fmt.partition(":")
    k = int(k)
    if name == "fourier":
        return ["a0"] + [f"{ab}{i}" for i in range(1, k // 2 + 1) for ab in "ab"]
    if name == "moments":
        return ["b0"] + [f"m{i}" for i in range(1, k + 1)]
    return [f"{zt}{i}" for i in range(k) for zt in ("z", "tau")]


def deep_lookup(image: Any, header: Dict[str, Any], points: Any) -> np.ndarray:
    """``T`` at world ``points`` from a fixed-size deep map (``umbra bake --deep-format``):
    the light's transmittance from the map's camera plane (orthographic) or pinhole
    (perspective) to each point, the map's texels around the point's projection
    reconstructed at the point's depth along their rays and blended bilinearly.

    ``image``: the pixels as read, ``(H, W, C)``, channels in the order of the header's
    ``channelnames``. ``header``: the EXR's attributes as OpenImageIO's ``spec.extra_attribs``
    give them (``umbra:deep_format``, ``umbra:deep_near``, ``umbra:deep_far``,
    ``umbra:camera_kind``, ``umbra:camera_origin``, ``umbra:camera_step_x``,
    ``umbra:camera_step_y``, ``umbra:camera_direction``; ``umbra:omni_x``/``_y``/``_z`` for
    an omnidirectional map) plus ``channelnames``. ``points``: ``(3,)`` or ``(K, 3)``. Returns
    ``(K,)``, or ``(K, 3)`` for a colour map (R, G, B).

    A point at pixel coordinates ``(i, j)`` (pixel ``(i, j)``'s ray starts at
    ``origin + i step_x + j step_y``) and distance ``t`` along the ray: orthographic
    ``i = v . s_x / |s_x|^2``, ``j = v . s_y / |s_y|^2``, ``t = v . d`` (``v = p - origin``);
    perspective ``v = k (d + i s_x + j s_y)`` with ``k = v . f`` (``f`` the unit forward axis,
    ``d . f = 1``), ``t = |v|``; cube and latlong maps place the direction from the light as
    :func:`sample_omni` does, ``t`` the distance from the light. ``u = (t - near) / (far -
    near)``; see
    :func:`deep_transmittance` for the formats."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3:
        raise _invalid("image", f"expected (H, W, C), got shape {img.shape}")
    names = list(header.get("channelnames", []))
    fmt = header.get("umbra:deep_format")
    if fmt is None or len(names) != img.shape[2]:
        raise _invalid("header", "not a fixed-size deep map read with its channelnames "
                       "(umbra:deep_format and one channel name per image channel)")
    kind = header.get("umbra:camera_kind")
    near, far = float(header["umbra:deep_near"]), float(header["umbra:deep_far"])
    h, w = img.shape[:2]
    if kind in ("cube", "latlong"):
        i0, j0, i1, j1, fx, fy, t = _omni_coords(header, points, h, w)
    elif kind in ("ortho", "perspective"):
        vec = lambda k: np.asarray(header[f"umbra:camera_{k}"], dtype=np.float64)
        o, sx, sy, d = vec("origin"), vec("step_x"), vec("step_y"), vec("direction")
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if p.ndim != 2 or p.shape[1] != 3:
            raise _invalid("points", f"expected (3,) or (K, 3), got shape {np.shape(points)}")
        v = p - o
        if kind == "ortho":
            dn = d / np.linalg.norm(d)
            i, j, t = v @ sx / (sx @ sx), v @ sy / (sy @ sy), v @ dn
        else:
            f = np.cross(sx, sy)
            f = f / np.linalg.norm(f)
            f = f if f @ d > 0 else -f
            k = v @ f / (d @ f)
            with np.errstate(all="ignore"):
                q = v / k[:, None] - d
            i, j, t = q @ sx / (sx @ sx), q @ sy / (sy @ sy), np.linalg.norm(v, axis=1)
        px, py = np.clip(i, 0, w - 1), np.clip(j, 0, h - 1)
        i0, j0 = np.floor(px).astype(np.int64), np.floor(py).astype(np.int64)
        i1, j1 = np.minimum(i0 + 1, w - 1), np.minimum(j0 + 1, h - 1)
        fx, fy = px - i0, py - j0
    else:
        raise _invalid("header", f"not an umbra map (camera kind {kind!r})")
    u = (t - near) / (far - near)
    layers = ["deepR", "deepG", "deepB"] if any(n.startswith("deepR.") for n in names) else ["deep"]
    order = _channel_order(fmt)
    out = []
    for layer in layers:
        cols = [names.index(f"{layer}.{c}") for c in order]
        at = lambda jj, ii: deep_transmittance(fmt, img[jj, ii][:, cols], u)
        out.append((at(j0, i0) * (1 - fx) + at(j0, i1) * fx) * (1 - fy)
                   + (at(j1, i0) * (1 - fx) + at(j1, i1) * fx) * fy)
    return out[0] if len(out) == 1 else np.stack(out, -1)


def job_status(
    path: PathLike,
    *,
    logs: Sequence[PathLike] = (),
    keep_unkeyed: bool = False,
    verify: bool = False,
) -> Dict[str, Any]:
    """Where a batch job stands, as ``umbra batch PATH --status --json`` reports it: lists
    ``done`` (output on disk carrying the task's key now), ``failed`` (with the ``error`` a log
    records), ``stale`` (an output baked with other settings or inputs, or without a key: the
    ``reason``) and ``missing``, one dict per task (``task``, ``input``, ``light``,
    ``output``). Reads the job's own log and ``logs`` (those shards or task runs wrote
    elsewhere); ``keep_unkeyed`` and ``verify`` as :func:`run_job`'s."""
    paths = [_path("logs", p) for p in logs]
    return json.loads(
        _umbra.job_status(_path("path", path), paths, bool(keep_unkeyed), bool(verify))
    )


def _user() -> str:
    """The user a farm job runs as, as pyoutline finds it (and the CLI): ``$USER``, ``$LOGNAME``,
    ``$LNAME``, ``$USERNAME``, else the password database's name for this process's uid."""
    for key in ("USER", "LOGNAME", "LNAME", "USERNAME"):
        name = os.environ.get(key)
        if name:
            return name
    try:
        import pwd
        return pwd.getpwuid(os.getuid()).pw_name
    except (ImportError, KeyError):
        return ""


def emit_job(
    path: PathLike,
    engine: str,
    *,
    umbra: Optional[PathLike] = None,
    directory: Optional[PathLike] = None,
    chunk: Optional[int] = None,
    show: Optional[str] = None,
    shot: Optional[str] = None,
) -> str:
    """The farm spec ``umbra batch PATH --emit ENGINE`` prints: ``"openjd"`` (an Open Job
    Description template; JSON, which is also YAML), ``"opencue"`` (an OpenCue job spec, the
    XML pyoutline writes) or ``"slurm"`` (an sbatch array script), for a pipeline to submit
    with the engine's own client. ``umbra``: the CLI the farm runs (default: ``umbra`` found on
    ``PATH``, made absolute); ``directory``: where the template will be written (default: the
    job file's; its path defaults are relative to it); ``chunk``: farm tasks of up to that many
    job tasks; ``show``, ``shot`` (OpenCue; default ``$SHOW``/``$SHOT``, else ``testing`` and
    ``default`` as pyoutline), the user as pyoutline finds it: ``$USER``, else ``$LOGNAME``,
    ``$LNAME``, ``$USERNAME``, else this uid's login name (as the CLI does)."""
    import shutil
    exe = _path("umbra", umbra) if umbra is not None else shutil.which("umbra")
    if exe is None:
        raise _invalid("umbra", "no umbra on PATH: give the path of the umbra CLI the farm runs")
    job = _path("path", path)
    where = _path("directory", directory) if directory is not None else os.path.dirname(
        os.path.abspath(job))
    n = None if chunk is None else _count("chunk", chunk)
    if str(engine) != "opencue":
        for name, given in (("show", show), ("shot", shot)):
            if given is not None:
                raise _invalid(name, "applies to the \"opencue\" engine")
    cue = (
        str(show if show is not None else os.environ.get("SHOW") or "testing"),
        str(shot if shot is not None else os.environ.get("SHOT") or "default"),
        _user(),
        os.getuid() if hasattr(os, "getuid") else None,
    )
    return _umbra.emit_job(job, str(engine), os.path.abspath(exe), where, n, cue)


def bake(
    input: PathLike,
    output: PathLike,
    *,
    grid: str = "density",
    light_dir: Optional[Vec3] = None,
    light_pos: Optional[Vec3] = None,
    light_angle: Optional[float] = None,
    light_radius: Optional[float] = None,
    light_samples: Optional[int] = None,
    light_max_samples: Optional[int] = None,
    ortho: bool = False,
    omni: Optional[str] = None,
    fov: Optional[float] = None,
    up: Optional[Vec3] = None,
    frame_box: Any = None,
    xform: Any = None,
    frame: Optional[float] = None,
    volume: Optional[Sequence[str]] = None,
    field: Optional[str] = None,
    light: Optional[str] = None,
    usd_out: Optional[PathLike] = None,
    camera: Union[None, Dict[str, Any], PathLike] = None,
    res: Union[None, int, str, Tuple[int, int]] = None,
    tile: Optional[int] = None,
    mipmap: bool = False,
    deep: bool = False,
    deep_error: Optional[float] = None,
    deep_format: Optional[str] = None,
    out_grid: Optional[str] = None,
    half: bool = False,
    preview: Optional[PathLike] = None,
    slices: Optional[int] = None,
    depths: Optional[Sequence[float]] = None,
    stderr: bool = False,
    receiver_depth: Optional[float] = None,
    target_error: Optional[float] = None,
    max_spp: int = 65536,
    interp: str = "trilinear",
    density_scale: float = 1.0,
    sigma_t: Optional[Vec3] = None,
    levelset: Optional[str] = None,
    estimator: str = "regular",
    samples: int = 64,
    seed: int = 0,
    step: Optional[float] = None,
    kernel: Optional[float] = None,
    points: Optional[float] = None,
    granularity: str = "leaf",
    global_majorant: bool = False,
    colour_walk: str = "auto",
    velocity: Optional[str] = None,
    shutter: Optional[Tuple[float, float]] = None,
    fps: Optional[float] = None,
    velocity_scale: Optional[float] = None,
    time_samples: Optional[int] = None,
    order: str = "auto",
    threads: int = 0,
    max_memory: Union[None, int, str] = None,
    force: bool = False,
    spp: Optional[int] = None,
    overwrite: Optional[bool] = None,
    progress: Optional[Callable[[int, int], Any]] = None,
) -> Dict[str, Any]:
    """Bake ``input`` (a ``.vdb`` file, a ``.toml`` scene or a USD stage: its volumes and the
    light ``light`` at time code ``frame``) to ``output`` exactly as
    ``umbra bake INPUT -o OUTPUT ...`` does, byte for byte: an OpenEXR map (flat, tiled with
    ``tile``/``mipmap``, deep with ``deep``/``deep_error``, at a fixed size per texel with
    ``deep_format`` (read it with :func:`deep_lookup`), with ``slices``/``depths`` and
    ``stderr`` channels, RGB with ``sigma_t`` or a scene's colours; toward a light with extent,
    ``light_angle`` or ``light_radius``, each texel the mean transmittance over the light at its
    receiver, ``receiver_depth``; each receiver's directions chosen to reach ``target_error``,
    default 5e-3, at most ``light_max_samples``, or exactly ``light_samples``), or, for an
    output ending in ``.vdb``, a transmittance volume
    (``out_grid``, ``half``).

    Every keyword is the command line's long flag with ``_`` for ``-`` (``--deep-error`` is
    ``deep_error``), with the same default and the same checks (a batch job's ``[bake]`` keys
    are the same names; ``umbra batch --schema`` describes them). ``spp`` and ``overwrite`` are
    older names of ``samples`` and ``force``. ``max_memory`` takes bytes or text such as
    ``"512M"``. Outputs are written atomically; an existing output is a :class:`FileError`
    unless ``force``.

    Returns what ``--json`` reports about the product: a map's camera dict (with ``deep``, the
    deep map's statistics, for a deep map; ``deep_format``, the format's errors and depth
    range, for a fixed-size one), or a transmittance volume's statistics
    (``voxels``, ``T_min``, ``T_max``, ``T_mean``, ...). Warnings (bad voxels, a camera that
    misses part of the volume) are Python warnings.

    ``progress(done, total)`` is called as the bake goes, from its threads (the GIL taken for
    each call): ``total`` units in all (pixels; a deep map's passes weighted by cost; a
    transmittance volume's voxels), ``done`` rising to it. A callback that raises is reported
    as an unraisable exception and the bake goes on.
    """
    if progress is not None and not callable(progress):
        raise _invalid("progress", "give a callable progress(done, total)")
    samples = _alias("samples", samples, "spp", spp, 64)
    force = _alias("force", force, "overwrite", overwrite, False)
    if isinstance(max_memory, (int, np.integer)) and not isinstance(max_memory, bool):
        max_memory = str(int(max_memory))
    summary, warns = _umbra.bake_file(
        _path("input", input),
        _path("output", output),
        _options(
            grid=grid, light_dir=light_dir, light_pos=light_pos, light_angle=light_angle,
            light_radius=light_radius, light_samples=light_samples,
            light_max_samples=light_max_samples, ortho=ortho, omni=omni,
            fov=fov, up=up,
            frame_box=frame_box, xform=xform, frame=frame,
            volume=None if volume is None else [str(v) for v in volume], field=field,
            light=light, usd_out=usd_out, camera=camera, res=res, tile=tile,
            mipmap=mipmap, deep=deep, deep_error=deep_error, deep_format=deep_format,
            out_grid=out_grid, half=half,
            preview=preview, slices=slices, depths=depths, stderr=stderr,
            receiver_depth=receiver_depth, target_error=target_error, max_spp=max_spp,
            interp=interp,
            density_scale=density_scale, sigma_t=sigma_t, levelset=levelset,
            **_estimator_options(locals()),
            order=order, threads=threads, max_memory=max_memory, force=force,
        ),
        progress,
    )
    _warn(warns)
    return json.loads(summary)


def usd_lights(path: PathLike, time: Optional[float] = None) -> Dict[str, Any]:
    """The UsdLux lights of a USD stage at time code ``time`` (default: its start), as umbra
    reads them: ``{"time", "up", "lights": [{"prim", "name", "type", "kind", ...,
    "shadow_enable", "linked"}]}``. A ``DistantLight`` is ``kind="directional"`` with ``dir``,
    the unit direction it travels (its world -Z), and ``angle``, its angular diameter in degrees
    (the schema's 0.53 when unauthored). A local light has ``pos`` (its world origin) and
    ``axes`` (the rows X, Y, Z of its world matrix) beside its kind and sizes:
    ``kind="sphere"`` (``radius``), ``"disk"`` (``radius``), ``"rect"`` (``width``,
    ``height``), ``"cylinder"`` (``radius``, ``length``; radius 0 for ``treatAsLine``), or
    ``"point"`` (``treatAsPoint``, or a shape of no size); a light umbra cannot trace (shaped,
    textured, a bad size: ``refused`` says why) or of another type has ``kind=None``.
    ``shadow_enable`` is its
    ``inputs:shadow:enable``, ``linked`` the visible volumes its ``collection:shadowLink``
    includes. ``up`` is the stage's up axis (docs/lights.md)."""
    t = None if time is None else float(time)
    return json.loads(_umbra.usd_lights_json(_path("path", path), t))


def usd_point_transmittance(
    stage: PathLike,
    prim: str,
    light: Optional[str] = None,
    frames: Optional[Sequence[float]] = None,
    *,
    volume: Optional[Sequence[str]] = None,
    field: Optional[str] = None,
    interp: str = "trilinear",
    density_scale: float = 1.0,
    estimator: str = "regular",
    samples: int = 1,
    seed: int = 0,
    step: Optional[float] = None,
    kernel: Optional[float] = None,
    points: Optional[float] = None,
    granularity: str = "leaf",
    global_majorant: bool = False,
    colour_walk: str = "auto",
    velocity: Optional[str] = None,
    shutter: Optional[Tuple[float, float]] = None,
    fps: Optional[float] = None,
    velocity_scale: Optional[float] = None,
    time_samples: Optional[int] = None,
    threads: int = 0,
    light_angle: Optional[float] = None,
    light_radius: Optional[float] = None,
    light_samples: Optional[int] = None,
    return_stderr: bool = False,
) -> Union[Dict[float, np.ndarray], Dict[float, Tuple[np.ndarray, np.ndarray]]]:
    """How much of a stage light reaches every point of a ``UsdGeom.Points`` prim (its
    ``points``) or a ``PointInstancer`` (its ``positions``), placed in the world by the prim's
    local-to-world at each time code of ``frames`` (default: the stage's start): what ``umbra
    query STAGE --positions PRIM --light LIGHT --frames ...`` answers, bit for bit. ``light`` is
    a prim path or name (default: the stage's only light); its shadow links are honoured.

    Returns ``{frame: T}``, ``T`` an (N,) float64 array in the prim's point order (N may change
    between frames: a warning says so); with ``return_stderr``, ``{frame: (T, std_err)}``. The
    estimator keywords are those of :meth:`Volume.transmittance`; point ``i`` uses ray id ``i``.

    ``light_angle`` (a ``DistantLight``'s angular diameter, degrees) or ``light_radius`` (a
    light at a position becomes a sphere light of that radius), with ``light_samples``
    directions per point (default 256): each point's mean T over the light with extent
    (``query --positions PRIM --light-angle A``; docs/lights.md), point ``i`` equal to
    ``umbra query STAGE --at P --light-angle A --ray-id i`` bit for bit. Without them the stage
    light's own extent applies (a ``DistantLight``'s angle, 0.53 degrees unless authored; a
    sphere's radius; disk, rect, cylinder); ``light_angle=0`` traces a sun as a point."""
    given = None if frames is None else [float(f) for f in frames]
    angle, radius, n = _extent(light_angle, light_radius, light_samples)
    doc, warns = _umbra.usd_points_json(
        _path("stage", stage),
        str(prim),
        None if light is None else str(light),
        given or [],
        _options(
            volume=None if volume is None else [str(v) for v in volume], field=field,
            interp=interp, density_scale=density_scale, **_estimator_options(locals()),
            threads=threads, light_angle=angle, light_radius=radius, light_samples=n,
        ),
    )
    _warn(warns)
    frames_ = json.loads(doc)["frames"]
    t = {f["frame"]: np.asarray(f["T"], dtype=np.float64) for f in frames_}
    if not return_stderr:
        return t
    return {f["frame"]: (t[f["frame"]], np.asarray(f["std_err"], dtype=np.float64)) for f in frames_}


def estimators() -> List[Dict[str, Any]]:
    """The estimator registry (``umbra estimators --json``): one dict per estimator with
    ``name``, ``kind`` (exact, unbiased, biased), ``deterministic``, ``params`` (name,
    default, range, unit), ``summary`` and ``budget``."""
    return json.loads(_umbra.estimators_json())


def write_exr(
    path: PathLike,
    image: Any,
    camera: Dict[str, Any],
    stderr: Any = None,
    overwrite: bool = False,
    *,
    tile: Optional[int] = None,
    mipmap: bool = False,
    force: bool = False,
) -> None:
    """Write ``image`` (the ``(H, W)`` float32 map of :meth:`Volume.bake`, row 0 at the top;
    ``(H, W, 3)`` for a colour scene) and its ``camera`` dict as the OpenEXR file ``umbra
    bake`` writes: the same channels (``T``, or ``R``/``G``/``B``; ``T.stderr`` with
    ``stderr``), the same ``worldToCamera``/``worldToNDC`` matrices and ``umbra:*``
    attributes, so ``umbra bake --camera`` and the CLI's readers take it. The file is written
    atomically; an existing file is an error unless ``force`` (or ``overwrite``, its older
    name).

    The image may have been changed (composited, denoised); its shape must stay the camera's.
    ``tile=N`` writes N x N tiles, ``mipmap=True`` (with ``tile``) adds box-filtered mip levels,
    as ``umbra bake --tile N --mipmap``.
    """
    if not isinstance(camera, dict):
        raise _invalid("camera", "expected the camera dict Volume.bake returns")
    w, h = camera.get("width"), camera.get("height")
    rgb = camera.get("channels", ["T"])[:1] == ["R"]
    want = (h, w, 3) if rgb else (h, w)

    def planes(name: str, a: Any) -> np.ndarray:
        arr = np.asarray(a)
        if arr.dtype.kind not in "fiu":
            raise _invalid(name, f"expected real numbers, got dtype {arr.dtype}")
        if arr.shape != want:
            raise _invalid(name, f"expected shape {want} for this camera, got {arr.shape}")
        arr = arr.astype(np.float32, copy=False)
        if rgb:
            arr = np.moveaxis(arr, 2, 0)
        return np.ascontiguousarray(arr).reshape(-1)

    t = planes("image", image)
    e = None if stderr is None else planes("stderr", stderr)
    _umbra.write_exr(
        _path("path", path),
        json.dumps(camera),
        t,
        e,
        3 if rgb else 1,
        bool(overwrite) or bool(force),
        None if tile is None else _count("tile", tile),
        bool(mipmap),
    )


class Volume:
    """A volume loaded for tracing: grid ``grid`` of a ``.vdb`` or ``.nvdb`` file (what
    ``--grid`` takes: a display name such as ``density[1]``; ``"[0]"``, ``"[1]"``, ... for the
    unnamed grids in file order, as Warp writes them; or the stored name), decoded whole.

    ``density_scale``: extinction ``mu_t = density_scale x value`` per world unit.
    ``interp``: ``"trilinear"`` (OpenVDB's BoxSampler, the default) or ``"nearest"``
    (PointSampler). ``xform``: a world-from-object 4x4 matrix (row-major, translation in the
    last column) placing the volume in the shot, as ``--xform``.

    NaN and negative voxels are traced as 0 (a ``RuntimeWarning`` says how many).
    """

    def __init__(
        self,
        path: PathLike,
        grid: str = "density",
        density_scale: float = 1.0,
        interp: str = "trilinear",
        xform: Any = None,
    ) -> None:
        args = (_path("path", path), str(grid), float(density_scale), str(interp), _xform(xform))
        self._v = _umbra.Volume.open(*args)
        self._args: Tuple[Any, ...] = ("grid", *args)
        _warn(self._v.warnings)

    @classmethod
    def from_scene(
        cls,
        path: PathLike,
        density_scale: float = 1.0,
        interp: str = "trilinear",
        xform: Any = None,
    ) -> "Volume":
        """A ``.toml`` scene file: several volumes (each with its transform and extinction
        colour), solids; an RGB scene gives (N, 3) transmittance and (H, W, 3) maps."""
        self = cls.__new__(cls)
        args = (_path("path", path), float(density_scale), str(interp), _xform(xform))
        self._v = _umbra.Volume.open_scene(*args)
        self._args = ("scene", *args)
        _warn(self._v.warnings)
        return self

    @classmethod
    def from_usd(
        cls,
        path: PathLike,
        time: Optional[float] = None,
        volumes: Optional[Sequence[str]] = None,
        field: str = "density",
        density_scale: float = 1.0,
        interp: str = "trilinear",
        xform: Any = None,
        light: Optional[str] = None,
    ) -> "Volume":
        """The volumes of a USD stage (``.usd``, ``.usda``, ``.usdc``, ``.usdz``) at time code
        ``time`` (default: the stage's start): every active, visible ``Volume`` prim, or the
        prim paths in ``volumes``; each one's ``field:<field>`` OpenVDB asset placed by the
        prim's world transform at that time. With ``light`` (a light prim path or name), only
        the volumes its ``collection:shadowLink`` includes (a light with
        ``inputs:shadow:enable = false`` is refused). The same scene ``umbra bake STAGE
        --frame T --light LIGHT`` traces."""
        self = cls.__new__(cls)
        vols = [] if volumes is None else [str(v) for v in volumes]
        t = None if time is None else float(time)
        args = (_path("path", path), t, vols, str(field), float(density_scale), str(interp),
                _xform(xform), None if light is None else str(light))
        self._v = _umbra.Volume.open_stage(*args)
        self._args = ("usd", *args)
        _warn(self._v.warnings)
        return self

    def __reduce__(self):
        # Pickled as what it was loaded from (multiprocessing, farm workers): unpickling loads
        # the file again.
        return (_reload, self._args)

    def __repr__(self) -> str:
        return (
            f"umbra.Volume({self.path!r}, grid={self.grid!r}, "
            f"density_scale={self.density_scale!r}, interp={self.interp!r})"
        )

    @property
    def path(self) -> str:
        """The file as given."""
        return str(self._v.path)

    @property
    def grid(self) -> str:
        """The grid(s) traced."""
        return self._v.grid

    @property
    def density_scale(self) -> float:
        return self._v.density_scale

    @property
    def interp(self) -> str:
        return self._v.interp

    @property
    def channels(self) -> int:
        """1 (grey) or 3 (an RGB scene)."""
        return self._v.channels

    @property
    def world_bbox(self) -> Optional[np.ndarray]:
        """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``: the world box of the active voxel
        centres (the corners of :attr:`index_bbox` through the transform, ``xform``
        included; a scene: over its volumes). ``None`` for an empty grid."""
        b = self._v.world_bbox()
        return None if b is None else np.array(b, dtype=np.float64)

    @property
    def index_bbox(self) -> Optional[np.ndarray]:
        """Inclusive index box of the active voxels, ``[[i0, j0, k0], [i1, j1, k1]]`` (int64),
        as ``umbra info`` and OpenVDB's ``evalActiveVoxelBoundingBox`` give it."""
        b = self._v.index_bbox()
        return None if b is None else np.array(b, dtype=np.int64)

    @property
    def voxel_size(self) -> np.ndarray:
        """World length of a voxel's three edges (the columns of :attr:`world_from_index`)."""
        m = self.world_from_index
        return np.linalg.norm(m[:3, :3], axis=0)

    @property
    def world_from_index(self) -> np.ndarray:
        """The 4x4 affine map from index to world space (``xform`` included), row-major,
        translation in the last column: ``world = M @ [i, j, k, 1]``."""
        return np.array(self._v.world_from_index(), dtype=np.float64)

    @property
    def active_voxels(self) -> int:
        """Active voxels (tiles count as the voxels they cover)."""
        return int(self._v.active_voxels())

    def transmittance(
        self,
        origins: Any,
        ends: Any,
        estimator: str = "regular",
        samples: int = 1,
        seed: int = 0,
        return_stderr: bool = False,
        *,
        ray_id: int = 0,
        step: Optional[float] = None,
        kernel: Optional[float] = None,
        points: Optional[float] = None,
        granularity: str = "leaf",
        global_majorant: bool = False,
        threads: int = 0,
        colour_walk: str = "auto",
        velocity: Optional[str] = None,
        shutter: Optional[Tuple[float, float]] = None,
        fps: Optional[float] = None,
        velocity_scale: Optional[float] = None,
        time_samples: Optional[int] = None,
    ):
        """Transmittance ``T = exp(-tau)`` along each segment ``origins[n] -> ends[n]`` (world
        points, (N, 3) arrays): an (N,) float64 array ((N, 3) for an RGB scene), and with
        ``return_stderr`` the tuple ``(T, stderr)`` (0 for deterministic estimators).

        ``estimator`` is any name of :func:`estimators` (``step``, ``kernel``, ``points``
        its parameters), ``samples`` independent samples per ray, ``seed`` the random
        streams: row ``n`` uses ray id ``ray_id + n``, so the answers equal ``umbra query
        --rays`` line for line, bit for bit. ``granularity`` (``"leaf"``, ``"lower"``,
        ``"upper"``) and ``global_majorant``: the null-collision estimators' majorants, as
        ``--granularity`` and ``--global-majorant``. ``threads``: 0 for every core.
        ``colour_walk`` (an RGB scene): ``"auto"``, ``"shared"`` or ``"split"``, as
        ``--colour-walk``. ``velocity`` (a vec3 grid of this volume's file) blurs the density
        over ``shutter`` (frames, default ``(-0.25, 0.25)``) at ``fps`` (24) with
        ``velocity_scale`` (1), as ``--velocity`` etc. (docs/motion.md; every call that takes
        an estimator takes them).
        """
        options = _estimator_options(locals())
        o, e = _segments(origins, ends)
        t, err, _, warns = self._v.trace(o, e, *_sampling(options, ray_id, threads))
        _warn(warns)
        return _finish(t, err, return_stderr)

    def optical_depth(self, origins: Any, ends: Any, *, threads: int = 0) -> np.ndarray:
        """The exact optical depth ``tau = integral of mu_t`` along each segment (regular
        tracking): an (N,) float64 array ((N, 3) for an RGB scene); ``inf`` through opaque
        voxels or a solid."""
        o, e = _segments(origins, ends)
        exact = dict(_ESTIMATOR_OPTIONS, estimator="regular")
        _, _, tau, warns = self._v.trace(o, e, *_sampling(exact, 0, threads))
        _warn(warns)
        return tau[:, 0] if tau.shape[1] == 1 else tau

    def transmittance_to_light(
        self,
        points: Any,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        estimator: str = "regular",
        samples: int = 1,
        seed: int = 0,
        return_stderr: bool = False,
        *,
        light_angle: Optional[float] = None,
        light_radius: Optional[float] = None,
        light_samples: Optional[int] = None,
        ray_id: int = 0,
        step: Optional[float] = None,
        kernel: Optional[float] = None,
        points_per_estimate: Optional[float] = None,
        granularity: str = "leaf",
        global_majorant: bool = False,
        threads: int = 0,
        colour_walk: str = "auto",
        velocity: Optional[str] = None,
        shutter: Optional[Tuple[float, float]] = None,
        fps: Optional[float] = None,
        velocity_scale: Optional[float] = None,
        time_samples: Optional[int] = None,
    ):
        """How much of a light reaches each point (what ``umbra query --at P`` answers):
        with ``light_dir`` (the direction the light travels) the ray from the point against it
        until it leaves every volume's box; with ``light_pos`` the segment to the light.
        ``points``: (N, 3) world points. Returns as :meth:`transmittance`; row ``n`` uses ray
        id ``ray_id + n`` (``--ray-id``). ``points_per_estimate`` is the jackknife's
        ``--points``; ``granularity``, ``global_majorant`` and ``colour_walk`` as in
        :meth:`transmittance`.

        A light with extent (``--light-angle``, ``--light-radius``, ``--light-samples``;
        docs/lights.md): ``light_angle`` (degrees, with ``light_dir``) makes the light a sun of
        that angular diameter, ``light_radius`` (with ``light_pos``) a sphere light;
        ``light_samples`` directions per point (default 256). Each row is then the mean T over
        the light with the replicates' error bar (``return_stderr``), row ``n`` with ray id
        ``ray_id + n`` as ``umbra query --at P --ray-id`` answers it, bit for bit. 0 is the
        point light exactly."""
        options = _estimator_options(locals(), points="points_per_estimate")
        p = _points("points", points)
        d, q = _vec3("light_dir", light_dir), _vec3("light_pos", light_pos)
        if (d is None) == (q is None):
            raise _invalid("light_dir", "give light_dir=(dx, dy, dz) or light_pos=(x, y, z), one of them")
        extent = _extent(light_angle, light_radius, light_samples)
        t, err, _, warns = self._v.trace_to_light(
            p, d, q, extent, *_sampling(options, ray_id, threads)
        )
        _warn(warns)
        return _finish(t, err, return_stderr)

    def transmittance_volume(
        self,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        *,
        light_angle: Optional[float] = None,
        light_radius: Optional[float] = None,
        light_samples: Optional[int] = None,
        estimator: str = "regular",
        samples: int = 64,
        seed: int = 0,
        threads: int = 0,
        step: Optional[float] = None,
        kernel: Optional[float] = None,
        points: Optional[float] = None,
        granularity: str = "leaf",
        global_majorant: bool = False,
        colour_walk: str = "auto",
        velocity: Optional[str] = None,
        shutter: Optional[Tuple[float, float]] = None,
        fps: Optional[float] = None,
        velocity_scale: Optional[float] = None,
        time_samples: Optional[int] = None,
    ) -> Tuple[np.ndarray, np.ndarray, Dict[str, Any]]:
        """``T = exp(-tau)`` toward a light at every active voxel (tiles count as the voxels they
        cover): what ``umbra bake FILE --light-dir D -o OUT.vdb`` stores, in memory.

        Give one of ``light_dir`` (a sun: the direction the light travels) or ``light_pos``
        (a point light). Each voxel's value is the transmittance from its centre (index point
        ``ijk`` in world space) toward the light. With the exact ``regular`` estimator and a
        sun along a lattice direction of the index grid (an axis, a diagonal, ``0.3,-1,0.2``),
        voxels on one line toward the light share its ray exactly; toward another sun a dense
        volume is swept a layer of voxel centres at a time (``"layers"``). Stochastic estimators use
        each voxel's index in the output as its ray id.

        Returns ``(ijk, T, stats)``: an (N, 3) int32 array of index coordinates and an (N,)
        float32 array of T, in output order (8^3 leaves by origin, voxels by offset), and a
        dict of counts and cost (``voxels``, ``leaves``, ``tile_leaves``, ``sharing``
        ``"lines"``/``"layers"``/``"rays"``, ``line_step``, ``rays``, ``lookups``, ``T_min``, ``T_max``,
        ``T_mean``, ``seconds``, ``ns_per_voxel``). World positions: ``world_from_index``
        applied to ``ijk``. A scene is refused (a transmittance volume is made from one grid).

        With ``light_angle`` (a sun's angular diameter, degrees, with ``light_dir``) or
        ``light_radius`` (a sphere light, with ``light_pos``) each voxel holds the mean T over
        the light from its centre (docs/lights.md), voxel ``k`` of the output with ray id ``k``
        (``umbra query --at CENTRE --ray-id k``, bit for bit as f32); ``light_samples``
        directions per voxel (default 256). The stats then add ``light_samples``,
        ``sampled_fraction`` and ``std_err_max``.
        """
        angle, radius, n = _extent(light_angle, light_radius, light_samples)
        ijk, t, stats, warns = self._v.transmittance_volume(
            _options(
                light_dir=light_dir, light_pos=light_pos, light_angle=angle,
                light_radius=radius, light_samples=n, **_estimator_options(locals()),
                threads=threads,
            )
        )
        _warn(warns)
        return ijk, t, json.loads(stats)

    def write_transmittance_volume(
        self,
        path: PathLike,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        *,
        light_angle: Optional[float] = None,
        light_radius: Optional[float] = None,
        light_samples: Optional[int] = None,
        out_grid: str = "transmittance",
        half: bool = False,
        force: bool = False,
        estimator: str = "regular",
        samples: int = 64,
        seed: int = 0,
        threads: int = 0,
        step: Optional[float] = None,
        kernel: Optional[float] = None,
        points: Optional[float] = None,
        granularity: str = "leaf",
        global_majorant: bool = False,
        colour_walk: str = "auto",
        velocity: Optional[str] = None,
        shutter: Optional[Tuple[float, float]] = None,
        fps: Optional[float] = None,
        velocity_scale: Optional[float] = None,
        time_samples: Optional[int] = None,
        grid: Optional[str] = None,
        overwrite: Optional[bool] = None,
    ) -> Dict[str, Any]:
        """Write :meth:`transmittance_volume` as the ``.vdb`` file ``umbra bake FILE ... -o
        PATH`` writes for this volume, byte for byte: one float grid named ``out_grid``
        (``--out-grid``) with the density's active voxels, background 1, the volume's
        transform (``xform`` included), ``umbra:*`` metadata naming the light, the estimator
        and the source file as this Volume was given it; ``half=True`` stores 16-bit floats
        (``--half``). The file is written atomically; an existing file is a
        :class:`FileError` unless ``force``. ``grid`` and ``overwrite`` are older names of
        ``out_grid`` and ``force``. Returns the stats dict of :meth:`transmittance_volume`.
        ``light_angle``, ``light_radius`` and ``light_samples`` as there (the light's extent
        recorded as ``umbra:light_extent``).
        """
        angle, radius, n = _extent(light_angle, light_radius, light_samples)
        out_grid = _alias("out_grid", out_grid, "grid", grid, "transmittance")
        force = _alias("force", force, "overwrite", overwrite, False)
        if not isinstance(out_grid, str):
            raise _invalid("out_grid", f"expected a grid name, got {out_grid!r}")
        stats, warns = self._v.write_transmittance_volume(
            _path("path", path),
            _options(
                light_dir=light_dir, light_pos=light_pos, light_angle=angle,
                light_radius=radius, light_samples=n, out_grid=out_grid, half=half,
                force=force, **_estimator_options(locals()), threads=threads,
            ),
        )
        _warn(warns)
        return json.loads(stats)

    def bake(
        self,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        res: Union[None, int, Tuple[int, int]] = None,
        estimator: str = "regular",
        samples: int = 64,
        seed: int = 0,
        up: Optional[Vec3] = None,
        *,
        ortho: bool = False,
        omni: Optional[str] = None,
        fov: Optional[float] = None,
        frame_box: Any = None,
        camera: Union[None, Dict[str, Any], PathLike] = None,
        target_error: Optional[float] = None,
        max_spp: int = 65536,
        stderr: bool = False,
        step: Optional[float] = None,
        kernel: Optional[float] = None,
        points: Optional[float] = None,
        granularity: str = "leaf",
        global_majorant: bool = False,
        colour_walk: str = "auto",
        velocity: Optional[str] = None,
        shutter: Optional[Tuple[float, float]] = None,
        fps: Optional[float] = None,
        velocity_scale: Optional[float] = None,
        time_samples: Optional[int] = None,
        order: str = "auto",
        threads: int = 0,
        spp: Optional[int] = None,
        return_stderr: Optional[bool] = None,
    ):
        """A transmittance (shadow) map seen from the light, as ``umbra bake`` makes it.

        The keywords are :func:`umbra.bake`'s (``umbra bake``'s flags with ``_`` for ``-``,
        the same defaults and checks); the file, grid, density scale, interpolation and
        ``xform`` are this Volume's. ``light_dir``: an orthographic map along the direction the
        light travels, framing the volume; ``light_pos``: a perspective map from the light
        (``ortho=True``: an orthographic one whose image plane passes through it; ``fov`` in
        degrees across the long side; ``omni="cube"`` or ``"latlong"``: every direction around
        it, :func:`sample_omni` reads it). ``res``: ``(W, H)``, or ``N`` pixels on the long side
        (default 1024). ``up``: the world direction up in the map. ``frame_box``: frame this
        world box ``[[x0, y0, z0], [x1, y1, z1]]`` instead of the volume's. ``camera``: reuse
        exactly an earlier map's camera (its dict, or the path of its EXR or JSON), so maps of
        a sequence line up pixel for pixel. ``target_error``/``max_spp``: adaptive sampling.
        ``spp`` and ``return_stderr`` are older names of ``samples`` and ``stderr``.

        Returns ``(image, camera)``: an (H, W) float32 array of T (row 0 the top row, as in the
        EXR; (H, W, 3) for an RGB scene) and the camera dict ``umbra bake --json`` prints
        (the camera, the light, the estimator and its settings; :func:`write_exr` takes it
        back). With ``stderr``: ``(image, stderr, camera)``.
        """
        samples = _alias("samples", samples, "spp", spp, 64)
        stderr = _alias("stderr", stderr, "return_stderr", return_stderr, False)
        out = self._v.bake(
            _options(
                light_dir=light_dir, light_pos=light_pos, res=res, up=up, ortho=ortho,
                omni=omni, fov=fov, frame_box=frame_box, camera=camera,
                target_error=target_error, max_spp=max_spp, stderr=stderr,
                **_estimator_options(locals()), order=order, threads=threads,
            )
        )
        return_stderr = bool(stderr)
        t, e, summary, warns = out
        _warn(warns)
        cam = json.loads(summary)
        h, w = cam["height"], cam["width"]

        def image(flat: np.ndarray) -> np.ndarray:
            c = flat.size // (w * h)
            a = flat.reshape(c, h, w)
            return a[0] if c == 1 else np.ascontiguousarray(np.moveaxis(a, 0, 2))

        if return_stderr:
            return image(t), image(e), cam
        return image(t), cam

    def write_deep_map(
        self,
        path: PathLike,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        res: Union[None, int, Tuple[int, int]] = None,
        estimator: str = "regular",
        samples: int = 64,
        seed: int = 0,
        up: Optional[Vec3] = None,
        *,
        ortho: bool = False,
        fov: Optional[float] = None,
        frame_box: Any = None,
        camera: Union[None, Dict[str, Any], PathLike] = None,
        deep_error: Optional[float] = None,
        deep_format: Optional[str] = None,
        force: bool = False,
        threads: int = 0,
        step: Optional[float] = None,
        kernel: Optional[float] = None,
        points: Optional[float] = None,
        granularity: str = "leaf",
        global_majorant: bool = False,
        colour_walk: str = "auto",
        velocity: Optional[str] = None,
        shutter: Optional[Tuple[float, float]] = None,
        fps: Optional[float] = None,
        velocity_scale: Optional[float] = None,
        time_samples: Optional[int] = None,
        order: str = "auto",
        spp: Optional[int] = None,
        overwrite: Optional[bool] = None,
    ) -> Tuple[Dict[str, Any], Dict[str, Any]]:
        """Write a deep shadow map: the deep OpenEXR file ``umbra bake FILE ... --deep
        [--deep-error E] -o PATH`` writes for this volume, byte for byte. Per pixel it holds
        the whole transmittance function along the pixel's ray (volumetric deep samples,
        ``A``/``Z``/``ZBack``; ``AR``/``AG``/``AB`` and ``A`` for an RGB scene), within
        ``deep_error`` in T at every depth (``--deep-error``, between 0 and 1; default 0.002).
        With ``deep_format`` (``fourier:K``, ``moments:4``, ``moments:6``, ``avsm:K``) it writes
        the fixed-size map of ``--deep-format`` instead (read it with :func:`deep_lookup`).

        The other keywords are :meth:`bake`'s (``camera=`` reuses an earlier map's camera,
        and :meth:`bake` takes the camera dict returned here). The file is written atomically;
        an existing file is a :class:`FileError` unless ``force`` (older name ``overwrite``).

        Returns ``(camera, deep)``: the camera dict :meth:`bake` returns, and the ``deep``
        object of ``umbra bake --deep --json`` (``max_error``, ``samples``,
        ``mean_samples_per_pixel``, ``max_samples_per_pixel``, ``empty_pixels``,
        ``profile_breakpoints``, ``coarse_cells``, ``rms_error``, ``seconds``), or with ``deep_format`` its
        ``deep_format`` object (``format``, ``channels``, ``bytes_per_texel``, ``max_error``,
        ``rms_error``, ``profile_error``, ``near``, ``far``, ``refined_texels``, ``seconds``).
        """
        samples = _alias("samples", samples, "spp", spp, 64)
        force = _alias("force", force, "overwrite", overwrite, False)
        summary, deep, warns = self._v.write_deep_map(
            _path("path", path),
            _options(
                light_dir=light_dir, light_pos=light_pos, res=res, up=up, ortho=ortho,
                fov=fov, frame_box=frame_box, camera=camera, deep_error=deep_error,
                deep_format=deep_format, force=force, threads=threads,
                **_estimator_options(locals()), order=order,
            ),
        )
        _warn(warns)
        return json.loads(summary), json.loads(deep)


def _reload(kind: str, *args: Any) -> Volume:
    """A pickled Volume, loaded again from its file."""
    v = Volume.__new__(Volume)
    opener = {"grid": _umbra.Volume.open, "scene": _umbra.Volume.open_scene,
              "usd": _umbra.Volume.open_stage}[kind]
    v._v = opener(*args)
    v._args = (kind, *args)
    return v
