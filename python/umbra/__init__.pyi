"""Type stubs of umbra's Python module (see the docstrings in umbra/__init__.py)."""

import os
from typing import Any, Callable, Dict, List, Literal, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

__version__: str

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

PathLike = Union[str, os.PathLike[str]]
Vec3 = Union[Sequence[float], npt.NDArray[np.floating[Any]]]
_Points = npt.ArrayLike
"""An (N, 3) array of finite world points (float or integer dtype)."""
_Camera = Dict[str, Any]
"""The camera dict of a baked map: what ``umbra bake --json`` prints about the map."""

class Error(Exception):
    """Base class of every umbra error; ``str(e)`` is the CLI's message."""

class FileError(Error, OSError):
    """A file could not be read or written."""

class InvalidArgument(Error, ValueError):
    """An argument is out of range, of the wrong shape or dtype, or names nothing."""

def info(path: PathLike, grid: Optional[str] = None) -> List[Dict[str, Any]]: ...
def estimators() -> List[Dict[str, Any]]: ...
def usd_lights(path: PathLike, time: Optional[float] = None) -> Dict[str, Any]: ...
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
) -> Union[Dict[float, np.ndarray], Dict[float, Tuple[np.ndarray, np.ndarray]]]: ...
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
    frame_box: Optional[npt.ArrayLike] = None,
    xform: Optional[npt.ArrayLike] = None,
    frame: Optional[float] = None,
    volume: Optional[Sequence[str]] = None,
    field: Optional[str] = None,
    light: Optional[str] = None,
    usd_out: Optional[PathLike] = None,
    camera: Union[None, _Camera, PathLike] = None,
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
) -> Dict[str, Any]: ...
def run_job(
    path: PathLike,
    *,
    task: Optional[int] = ...,
    shard: Optional[Tuple[int, int]] = ...,
    force: bool = ...,
    log: Optional[PathLike] = ...,
    jobs: int = ...,
    progress: Optional[Callable[[int, int], Any]] = ...,
    keep_unkeyed: bool = ...,
    verify: bool = ...,
) -> Dict[str, Any]: ...
def sample_omni(
    image: npt.ArrayLike, header: Dict[str, Any], points: npt.ArrayLike
) -> npt.NDArray[np.float64]: ...
def deep_transmittance(
    fmt: str, coefficients: npt.ArrayLike, u: npt.ArrayLike
) -> npt.NDArray[np.float64]: ...
def deep_lookup(
    image: npt.ArrayLike, header: Dict[str, Any], points: npt.ArrayLike
) -> npt.NDArray[np.float64]: ...
def job_status(
    path: PathLike,
    *,
    logs: Sequence[PathLike] = ...,
    keep_unkeyed: bool = ...,
    verify: bool = ...,
) -> Dict[str, Any]: ...
def emit_job(
    path: PathLike,
    engine: str,
    *,
    umbra: Optional[PathLike] = ...,
    directory: Optional[PathLike] = ...,
    chunk: Optional[int] = ...,
    show: Optional[str] = ...,
    shot: Optional[str] = ...,
) -> str: ...
def write_exr(
    path: PathLike,
    image: npt.ArrayLike,
    camera: _Camera,
    stderr: Optional[npt.ArrayLike] = None,
    overwrite: bool = False,
    *,
    tile: Optional[int] = None,
    mipmap: bool = False,
    force: bool = False,
) -> None: ...

class Volume:
    def __init__(
        self,
        path: PathLike,
        grid: str = "density",
        density_scale: float = 1.0,
        interp: Literal["trilinear", "nearest"] = "trilinear",
        xform: Optional[npt.ArrayLike] = None,
    ) -> None: ...
    @classmethod
    def from_scene(
        cls,
        path: PathLike,
        density_scale: float = 1.0,
        interp: Literal["trilinear", "nearest"] = "trilinear",
        xform: Optional[npt.ArrayLike] = None,
    ) -> "Volume": ...
    @classmethod
    def from_usd(
        cls,
        path: PathLike,
        time: Optional[float] = None,
        volumes: Optional[Sequence[str]] = None,
        field: str = "density",
        density_scale: float = 1.0,
        interp: Literal["trilinear", "nearest"] = "trilinear",
        xform: Optional[npt.ArrayLike] = None,
        light: Optional[str] = None,
    ) -> "Volume": ...
    @property
    def path(self) -> str: ...
    @property
    def grid(self) -> str: ...
    @property
    def density_scale(self) -> float: ...
    @property
    def interp(self) -> str: ...
    @property
    def channels(self) -> int: ...
    @property
    def world_bbox(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def index_bbox(self) -> Optional[npt.NDArray[np.int64]]: ...
    @property
    def voxel_size(self) -> npt.NDArray[np.float64]: ...
    @property
    def world_from_index(self) -> npt.NDArray[np.float64]: ...
    @property
    def active_voxels(self) -> int: ...
    @overload
    def transmittance(
        self,
        origins: _Points,
        ends: _Points,
        estimator: str = "regular",
        samples: int = 1,
        seed: int = 0,
        return_stderr: Literal[False] = False,
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
    ) -> npt.NDArray[np.float64]: ...
    @overload
    def transmittance(
        self,
        origins: _Points,
        ends: _Points,
        estimator: str = "regular",
        samples: int = 1,
        seed: int = 0,
        *,
        return_stderr: Literal[True],
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
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    def optical_depth(
        self, origins: _Points, ends: _Points, *, threads: int = 0
    ) -> npt.NDArray[np.float64]: ...
    @overload
    def transmittance_to_light(
        self,
        points: _Points,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        estimator: str = "regular",
        samples: int = 1,
        seed: int = 0,
        return_stderr: Literal[False] = False,
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
    ) -> npt.NDArray[np.float64]: ...
    @overload
    def transmittance_to_light(
        self,
        points: _Points,
        light_dir: Optional[Vec3] = None,
        light_pos: Optional[Vec3] = None,
        estimator: str = "regular",
        samples: int = 1,
        seed: int = 0,
        *,
        return_stderr: Literal[True],
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
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
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
    ) -> Tuple[npt.NDArray[np.int32], npt.NDArray[np.float32], Dict[str, Any]]: ...
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
    ) -> Dict[str, Any]: ...
    @overload
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
        frame_box: Optional[npt.ArrayLike] = None,
        camera: Union[None, _Camera, PathLike] = None,
        target_error: Optional[float] = None,
        max_spp: int = 65536,
        stderr: Literal[False] = False,
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
        return_stderr: Optional[Literal[False]] = None,
    ) -> Tuple[npt.NDArray[np.float32], _Camera]: ...
    @overload
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
        frame_box: Optional[npt.ArrayLike] = None,
        camera: Union[None, _Camera, PathLike] = None,
        target_error: Optional[float] = None,
        max_spp: int = 65536,
        stderr: Literal[True],
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
    ) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], _Camera]: ...
    @overload
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
        frame_box: Optional[npt.ArrayLike] = None,
        camera: Union[None, _Camera, PathLike] = None,
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
        return_stderr: Literal[True],
    ) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], _Camera]: ...
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
        frame_box: Optional[npt.ArrayLike] = None,
        camera: Union[None, _Camera, PathLike] = None,
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
    ) -> Tuple[_Camera, Dict[str, Any]]: ...
