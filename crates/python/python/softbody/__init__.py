"""softbody: mass-spring soft bodies, simulated in Rust (CPU f64 on all cores, or a GPU through
wgpu), with NumPy in and out.

    import softbody
    scene = softbody.load_scene("scenes/jelly-on-ground.toml", set={"body[0].mass": 10.0})
    sim = softbody.Simulation(scene)          # backend="cpu" | "gpu", threads=None
    sim.step(1000)                            # the GIL is released while it steps
    x = sim.positions                         # [N, 3] float64, metres
    traj = softbody.run(scene)                # every frame: traj.positions [F, N, 3], ...
    records = softbody.sweep("sweeps/jelly-stiffness-friction.toml")   # or executor="ray"
    g = softbody.gradient(scene, ["body[0].structural.stiffness"], target_com=(1, 0, 0))
    g = traj.backward(positions=dL_dx, wrt=["body[0].velocity"])      # any loss, [F, N, 3]

Errors are the library's, with the command line's messages: SceneError (a bad scene, setting
or sweep file), UnstableError (with .step, .time, .particle and, from run(), the frames before
it as .trajectory), DeviceError (no GPU adapter, a failed device), OutputError.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from ._native import (
    DeviceError,
    OutputError,
    Scene,
    SceneError,
    Simulation,
    SoftbodyError,
    SweepPlan,
    UnstableError,
)

__version__ = _native.__version__

__all__ = [
    "DeviceError",
    "OutputError",
    "Scene",
    "SceneError",
    "Simulation",
    "SoftbodyError",
    "SweepPlan",
    "Trajectory",
    "Gradient",
    "UnstableError",
    "gradient",
    "load_scene",
    "run",
    "sweep",
]

def __dir__() -> List[str]:
    # The package's names, not the modules it imports (numpy, os, dataclasses…).
    return sorted(__all__ + ["__version__"])


SceneSource = Union[Scene, str, "os.PathLike[str]", Mapping[str, Any]]


def load_scene(source: SceneSource, *, set: Optional[Mapping[str, Any]] = None) -> Scene:
    """A scene from a file path, a dict laid out as the TOML file, or a Scene, with `set`
    applied: ``{"body[0].structural.stiffness": 5000, "terrain[0].friction": 0.8}`` (key paths
    as the command line's ``--set``). TOML text goes through ``Scene.from_toml``."""
    settings = dict(set) if set else None
    if isinstance(source, Scene):
        return source.with_settings(settings) if settings else source
    if isinstance(source, Mapping):
        return Scene.from_dict(dict(source), set=settings)
    if isinstance(source, (str, os.PathLike)):
        return Scene.from_file(source, set=settings)
    raise TypeError("a scene is a path to a scene file, a dict, or a softbody.Scene")


@dataclass(frozen=True, repr=False)
class Trajectory:
    """Every frame of a run, and what the run was (the NPZ output's arrays, same names)."""

    time: np.ndarray  #: [F] s
    positions: np.ndarray  #: [F, N, 3] m
    velocities: np.ndarray  #: [F, N, 3] m/s
    energy_kinetic: np.ndarray  #: [F] J
    energy_gravitational: np.ndarray  #: [F] J
    energy_elastic: np.ndarray  #: [F] J
    dt: float
    frame_rate: float
    integrator: str
    backend: str
    device: str
    masses: np.ndarray  #: [N] kg
    springs: np.ndarray  #: [S, 2] uint32
    rest_lengths: np.ndarray  #: [S] m
    stiffness: np.ndarray  #: [S] N/m
    damping: np.ndarray  #: [S] N·s/m
    bodies: List[Tuple[str, int, int]] = field(default_factory=list)  #: (name, first, count)
    scene_text: str = ""
    scene: Optional[Scene] = None  #: the scene that ran (what backward() runs again)
    controls: Optional[np.ndarray] = None  #: [F, N, 3] N: the run's control forces, if any

    def backward(
        self,
        positions: Optional[Any] = None,
        velocities: Optional[Any] = None,
        *,
        wrt: Sequence[str] = (),
        threads: Optional[int] = None,
    ) -> "Gradient":
        """The gradient of any loss L of this run's frames, given its cotangents: `positions`
        = ∂L/∂x and `velocities` = ∂L/∂v, arrays [F, N, 3] (F the run's frames; either may be
        omitted). Returns ∂L/∂ each key of `wrt` (as ``--set`` names them) and the per-particle
        and per-spring gradients, and for a run with control forces their gradient
        (`Gradient.controls`, [F, N, 3]). The run is taken again on the CPU, with checkpoints
        (memory √T); it is the same run, bit for bit, on any thread count. The loss itself is
        the caller's (`loss` is None)."""
        if self.backend != "cpu":
            raise ValueError(
                f"gradients are computed on the CPU backend only; this run was on {self.backend}"
            )
        if self.scene is None:
            raise ValueError("this trajectory does not know its scene; run it with softbody.run")
        if positions is None and velocities is None:
            raise ValueError("give the cotangents: positions, velocities or both")
        return Gradient(
            **_native.gradient(
                self.scene,
                list(wrt),
                positions=positions,
                velocities=velocities,
                controls=self.controls,
                threads=threads,
            )
        )

    @property
    def energy_total(self) -> np.ndarray:
        return self.energy_kinetic + self.energy_gravitational + self.energy_elastic

    def __len__(self) -> int:
        return len(self.time)

    def __repr__(self) -> str:
        # The arrays' shapes, not their values (NumPy would print kilobytes of them).
        frames, particles = self.positions.shape[:2]
        span = f"t = {self.time[0]:g} to {self.time[-1]:g} s" if frames else "no frames"
        return (
            f"<softbody.Trajectory {frames} frames of {particles} particles, {span}, "
            f"{self.integrator} at dt = {self.dt:g} s on {self.backend}>"
        )


def _trajectory(
    d: Dict[str, Any], scene: Optional[Scene] = None, controls: Optional[np.ndarray] = None
) -> Trajectory:
    return Trajectory(**d, scene=scene, controls=controls)


@dataclass(frozen=True, repr=False)
class Gradient:
    """The gradient of a loss over a whole run (``softbody.gradient``, ``Trajectory.backward``)."""

    loss: Optional[float]  #: the loss (None for a loss given by its cotangents)
    gradient: Dict[str, Any]  #: ∂L/∂ each key: a float, or an array [3] for a vector key
    positions: np.ndarray  #: [N, 3] ∂L/∂ initial positions
    velocities: np.ndarray  #: [N, 3] ∂L/∂ initial velocities
    masses: np.ndarray  #: [N] ∂L/∂ each particle's mass
    stiffness: np.ndarray  #: [S] ∂L/∂ each spring's stiffness
    damping: np.ndarray  #: [S] ∂L/∂ each spring's damping
    steps: int
    peak_memory_bytes: int
    forward_seconds: float
    backward_seconds: float
    controls: Optional[np.ndarray] = None  #: [F, N, 3] ∂L/∂ each control force (None without)
    #: implicit Euler's steps where a contact turned from sticking to slipping, whose friction
    #: direction the gradient holds (docs/physics.md, "Kinks")
    turned_steps: int = 0

    def __repr__(self) -> str:
        keys = ", ".join(self.gradient)
        loss = "a loss given by its cotangents" if self.loss is None else f"loss {self.loss:g}"
        return f"<softbody.Gradient of {loss} over {self.steps} steps, with respect to {keys or 'no key'}>"


def gradient(
    scene: SceneSource,
    wrt: Sequence[str],
    *,
    target_com: Optional[Sequence[float]] = None,
    target_frames: Optional[Union[str, "os.PathLike[str]"]] = None,
    set: Optional[Mapping[str, Any]] = None,
    controls: Optional[Any] = None,
    threads: Optional[int] = None,
) -> Gradient:
    """The gradient of a built-in loss over the run of `scene` with respect to `wrt` (keys as
    ``--set`` names them: ``body[0].mass``, ``body[0].structural.stiffness``,
    ``body[0].velocity``, ``simulation.gravity``, ``terrain[0].friction``, …), on the CPU in
    f64 (the command line's ``softbody grad``). The loss is `target_com` (|c − target|², c the
    mass-weighted centre at the last frame) or `target_frames` (a .jsonl or .npz of a run of the
    same particles: the mean squared distance over the frames both have). `controls` are the
    run's control forces ([F, N, 3], as ``run`` takes them); their gradient is
    ``Gradient.controls``. For any other loss, ``softbody.run(scene).backward(...)``. The GIL
    is released; Ctrl-C raises KeyboardInterrupt."""
    if set:
        scene = load_scene(scene, set=set)
    com = None if target_com is None else [float(c) for c in target_com]
    return Gradient(
        **_native.gradient(
            scene,
            list(wrt),
            target_com=com,
            target_frames=target_frames,
            controls=_controls(controls),
            threads=threads,
        )
    )


def run(
    scene: SceneSource,
    backend: str = "cpu",
    threads: Optional[int] = None,
    *,
    set: Optional[Mapping[str, Any]] = None,
    integrator: Optional[str] = None,
    dt: Optional[float] = None,
    duration: Optional[float] = None,
    frame_rate: Optional[float] = None,
    controls: Optional[Any] = None,
) -> Trajectory:
    """Runs the scene to its end (its duration and frame rate) and returns every frame. The
    GIL is released while it runs. An instability raises UnstableError, whose `.trajectory`
    holds the frames before it; Ctrl-C raises KeyboardInterrupt.

    `controls` are external forces on the particles, an array [F, N, 3] in newtons for the
    run's F frames and N particles: frame f's act from its step to the next frame's (the last
    frame's on none), beside gravity, and pinned particles take none (the CPU backend). The
    trajectory keeps them, so that ``backward`` gives their gradient.

    `integrator`, `dt`, `duration` and `frame_rate` are the command line's ``--integrator``,
    ``--dt``, ``--duration`` and ``--fps``: the settings ``simulation.<name>``, applied after
    `set`."""
    options = {
        f"simulation.{key}": value
        for key, value in (
            ("integrator", integrator),
            ("dt", dt),
            ("duration", duration),
            ("frame_rate", frame_rate),
        )
        if value is not None
    }
    scene = load_scene(scene, set={**(set or {}), **options} or None)
    controls = _controls(controls)
    try:
        return _trajectory(_native.run(scene, backend, threads, controls), scene, controls)
    except UnstableError as e:
        partial = getattr(e, "trajectory", None)
        if isinstance(partial, dict):
            e.trajectory = _trajectory(partial, scene, controls)
        raise


def _controls(controls: Optional[Any]) -> Optional[np.ndarray]:
    # A copy the caller cannot change under the trajectory that keeps it.
    return None if controls is None else np.array(controls, dtype=np.float64, order="C")


def _default_out(spec: Union[str, "os.PathLike[str]", Mapping[str, Any]]) -> Path:
    if isinstance(spec, Mapping):
        return Path("out") / "sweep"
    return Path("out") / Path(spec).stem


def _progress_printer(enabled: bool) -> Optional[Callable[[int, int], None]]:
    if not enabled or not sys.stderr.isatty():
        return None

    def report(done: int, total: int) -> None:
        end = "\n" if done == total else ""
        print(f"\r{done}/{total} runs", end=end, file=sys.stderr, flush=True)

    return report


def sweep(
    spec: Union[str, "os.PathLike[str]", Mapping[str, Any]],
    *,
    out: Union[str, "os.PathLike[str]", None] = None,
    executor: str = "local",
    workers: Optional[int] = None,
    address: Optional[str] = None,
    task_index: Optional[int] = None,
    task_count: Optional[int] = None,
    batch: Optional[int] = None,
    progress: bool = True,
) -> List[Dict[str, Any]]:
    """Runs a parameter sweep (a sweep file, or a dict laid out as one: docs/guide/python-and-sweeps.md) into
    `out` (default ``out/<sweep file stem>``) and returns the manifest's records, in run order:
    ``{"run", "parameters", "status", "exit_status", "error"?, "metrics", "file", "seconds"}``.

    ``executor="local"`` runs on this machine's cores (`workers` at once, default all);
    ``executor="ray"`` runs each run as a Ray task on the cluster at `address` (``None``: the
    one ``ray.init()`` finds or starts; ``"local"``: a new one on this machine). Both write the
    same manifest, resume alike (finished runs are skipped, failed ones run again), and give
    the same records. `task_index` / `task_count` take one Slurm array task's share (local
    only). `batch` (Ray only, default 1) runs that many runs in each Ray task, one after the
    other, so that Ray schedules a task per `batch` runs (for many short runs on a cluster);
    the records and files are the same."""
    out_dir = Path(out) if out is not None else _default_out(spec)
    if batch is not None:
        if executor != "ray":
            raise ValueError("batch is for executor='ray'")
        if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
            raise ValueError(f"batch must be a whole number of runs, at least 1; got {batch!r}")
    if executor == "local":
        return _native.sweep_local(
            spec,
            out_dir,
            workers,
            task_index,
            task_count,
            _progress_printer(progress),
        )
    if executor == "ray":
        if task_index is not None or task_count is not None:
            raise ValueError("task_index and task_count are for local (Slurm) sweeps")
        from ._ray import sweep_on_ray

        return sweep_on_ray(spec, out_dir, address=address, batch=batch or 1, progress=progress)
    raise ValueError(f"unknown executor {executor!r}; expected 'local' or 'ray'")
