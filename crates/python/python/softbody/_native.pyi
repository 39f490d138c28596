"""Type stubs of softbody._native (the Rust extension); softbody re-exports these."""

import os
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, "os.PathLike[str]"]
_Settings = Mapping[str, Any]

class SoftbodyError(Exception):
    """Base class of softbody's errors."""

class SceneError(SoftbodyError):
    """A scene, setting or sweep file that is not valid; the message is the CLI's."""

class UnstableError(SoftbodyError):
    """The simulation became unstable."""

    step: int
    time: float
    particle: int
    trajectory: Any  # softbody.Trajectory of the frames before it (from softbody.run)

class DeviceError(SoftbodyError):
    """No usable GPU adapter, or the device failed."""

class OutputError(SoftbodyError):
    """A file could not be written."""

class Scene:
    """A validated scene and the TOML text it was built from (settings written in)."""

    @staticmethod
    def from_file(path: _Path, *, set: Optional[_Settings] = None) -> Scene: ...
    @staticmethod
    def from_toml(text: str, *, origin: Optional[_Path] = None, set: Optional[_Settings] = None) -> Scene: ...
    @staticmethod
    def from_dict(table: Mapping[str, Any], *, origin: Optional[_Path] = None, set: Optional[_Settings] = None) -> Scene: ...
    def with_settings(self, set: _Settings) -> Scene: ...
    @property
    def text(self) -> str: ...
    @property
    def origin(self) -> str: ...
    @property
    def particles(self) -> int: ...
    @property
    def springs(self) -> int: ...
    @property
    def total_mass(self) -> float: ...
    @property
    def dt(self) -> float: ...
    @property
    def duration(self) -> float: ...
    @property
    def frame_rate(self) -> float: ...
    @property
    def integrator(self) -> str: ...
    @property
    def steps(self) -> int: ...
    @property
    def frames(self) -> int: ...

_SceneSource = Union[Scene, _Path, Mapping[str, Any]]

class Simulation:
    """A scene being stepped on a backend ("cpu": f64; "gpu": wgpu, f32)."""

    def __init__(self, scene: _SceneSource, backend: str = "cpu", threads: Optional[int] = None) -> None: ...
    def step(self, n: int = 1) -> None:
        """Takes n steps with the GIL released; raises UnstableError on divergence."""
    @property
    def positions(self) -> npt.NDArray[np.float64]:
        """[N, 3] metres: a snapshot."""
    @property
    def velocities(self) -> npt.NDArray[np.float64]:
        """[N, 3] m/s: a snapshot."""
    def set_state(self, positions: npt.ArrayLike, velocities: Optional[npt.ArrayLike] = None) -> None: ...
    def energies(self) -> Dict[str, float]:
        """{"kinetic", "gravitational", "elastic", "total"}, J."""
    @property
    def steps(self) -> int: ...
    @property
    def time(self) -> float: ...
    @property
    def dt(self) -> float: ...
    @property
    def scene(self) -> Scene: ...
    @property
    def backend(self) -> str: ...
    @property
    def device(self) -> str: ...
    @property
    def masses(self) -> npt.NDArray[np.float64]: ...
    @property
    def springs(self) -> npt.NDArray[np.uint32]: ...
    @property
    def rest_lengths(self) -> npt.NDArray[np.float64]: ...

def run(
    scene: _SceneSource,
    backend: str = "cpu",
    threads: Optional[int] = None,
    controls: Optional[Any] = None,
) -> Dict[str, Any]:
    """Every frame of a run and its metadata (softbody.run wraps it as a Trajectory)."""

def gradient(
    scene: _SceneSource,
    wrt: List[str],
    target_com: Optional[List[float]] = None,
    target_frames: Optional[_Path] = None,
    positions: Optional[Any] = None,
    velocities: Optional[Any] = None,
    controls: Optional[Any] = None,
    threads: Optional[int] = None,
) -> Dict[str, Any]:
    """A run's gradient with respect to scene keys (softbody.gradient and Trajectory.backward
    wrap it as a Gradient)."""

_SweepSource = Union[_Path, Mapping[str, Any]]

def sweep_local(
    sweep: _SweepSource,
    out: _Path,
    workers: Optional[int] = None,
    task_index: Optional[int] = None,
    task_count: Optional[int] = None,
    progress: Optional[Callable[[int, int], None]] = None,
) -> List[Dict[str, Any]]: ...

class SweepPlan:
    """A sweep's plan and manifest for executors that run jobs elsewhere (Ray)."""

    def __init__(self, sweep: _SweepSource, out: _Path) -> None: ...
    def __len__(self) -> int: ...
    @property
    def threads(self) -> int: ...
    @property
    def manifest(self) -> str: ...
    def pending(self) -> List[str]: ...
    def record(self, record: str) -> None: ...
    def records(self) -> List[Dict[str, Any]]: ...

def run_job(job: str, output: Optional[_Path] = None) -> str: ...
