"""The package at its edges: Ctrl-C while Rust works, counts out of range, states that are not
states, messages in Python's terms, and what `dir` and `repr` show."""

from __future__ import annotations

import _thread
import json
import threading
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import pytest

import softbody
from conftest import CUBE

# Long enough that nothing but the interrupt ends it within the test's patience.
ENDLESS = CUBE.replace("duration = 0.1", "duration = 100000.0").replace(
    "frame_rate = 50.0", "frame_rate = 1.0"
)


@pytest.fixture
def ctrl_c() -> Iterator[Callable[[float], None]]:
    """`ctrl_c(after)` presses Ctrl-C `after` seconds from now (a SIGINT as Python sees it)."""
    timers = []

    def press(after: float) -> None:
        timer = threading.Timer(after, _thread.interrupt_main)
        timers.append(timer)
        timer.start()

    yield press
    for t in timers:
        t.cancel()


def test_ctrl_c_interrupts_step_after_whole_steps(ctrl_c: Callable[[float], None]) -> None:
    sim = softbody.Simulation(softbody.Scene.from_toml(ENDLESS), threads=1)
    ctrl_c(0.3)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        sim.step(10**12)
    # Chunks grow to ~20 ms of work: the interrupt is seen within a few of them.
    assert time.monotonic() - started < 0.3 + 1.0
    taken = sim.steps
    assert 0 < taken < 10**12
    assert np.isfinite(sim.positions).all()
    # The simulation goes on from where it stopped, as if never interrupted.
    sim.step(10)
    again = softbody.Simulation(softbody.Scene.from_toml(ENDLESS), threads=1)
    again.step(taken + 10)
    assert np.array_equal(sim.positions, again.positions)


def test_ctrl_c_interrupts_run(ctrl_c: Callable[[float], None]) -> None:
    ctrl_c(0.3)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        softbody.run(softbody.Scene.from_toml(ENDLESS), threads=1)
    assert time.monotonic() - started < 0.3 + 1.0


def test_ctrl_c_interrupts_a_sweep_which_keeps_only_finished_runs(
    tmp_path: Path, ctrl_c: Callable[[float], None]
) -> None:
    (tmp_path / "cube.toml").write_text(ENDLESS)
    spec = tmp_path / "sweep.toml"
    spec.write_text(
        'scene = "cube.toml"\nformat = "none"\n[grid]\n"body[0].mass" = [1.0, 2.0]\n'
    )
    ctrl_c(0.3)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        softbody.sweep(spec, out=tmp_path / "out", workers=2, progress=False)
    assert time.monotonic() - started < 0.3 + 1.0
    lines = (tmp_path / "out" / "manifest.jsonl").read_text().splitlines()
    assert len(lines) == 1, "the header alone: the runs under way are not records"
    assert json.loads(lines[0])["runs"] == 2


@pytest.mark.parametrize(
    "call",
    [
        lambda s: softbody.Simulation(s, threads=-1),
        lambda s: softbody.Simulation(s, threads=0),
        lambda s: softbody.Simulation(s).step(-1),
        lambda s: softbody.run(s, threads=0),
        lambda s: softbody.run(s, threads=-2),
    ],
)
def test_counts_out_of_range_are_value_errors(cube: softbody.Scene, call) -> None:
    with pytest.raises(ValueError, match="must be at least"):
        call(cube)


def test_sweep_counts_out_of_range_are_value_errors(tmp_path: Path) -> None:
    (tmp_path / "cube.toml").write_text(CUBE)
    spec = tmp_path / "sweep.toml"
    spec.write_text('scene = "cube.toml"\nformat = "none"\n[grid]\n"body[0].mass" = [1.0, 2.0]\n')
    for kwargs, says in [
        ({"workers": 0}, "workers must be at least 1"),
        ({"task_index": 0, "task_count": 0}, "task_count must be at least 1"),
        ({"task_index": -1}, "task_index must be at least 0"),
        ({"task_index": 2}, "task index 2 names no run"),
        ({"task_index": 3, "task_count": 2}, "not below the task count 2"),
        ({"task_count": 2}, "task_count takes a task_index"),
    ]:
        with pytest.raises(ValueError, match=says):
            softbody.sweep(spec, out=tmp_path / "out", progress=False, **kwargs)
    assert not (tmp_path / "out" / "manifest-task-2.jsonl").exists()


def test_set_state_refuses_what_is_not_a_state_and_keeps_the_old(cube: softbody.Scene) -> None:
    sim = softbody.Simulation(cube, threads=1)
    x, v = sim.positions, sim.velocities
    bad = x.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"positions\[4\] is not finite"):
        sim.set_state(bad)
    huge = x * 1e300
    with pytest.raises(ValueError, match="energy is not a finite number"):
        sim.set_state(huge)
    with pytest.raises(ValueError, match=r"velocities\[0\] is not finite"):
        sim.set_state(x, np.full_like(v, np.inf))
    assert np.array_equal(sim.positions, x) and np.array_equal(sim.velocities, v)
    sim.step(1)  # and it still steps


def test_messages_speak_python() -> None:
    # Settings from `set=` are named as such, not as the command line's --set.
    with pytest.raises(softbody.SceneError) as e:
        softbody.Scene.from_toml(CUBE, origin="cube.toml", set={"body[0].mass": -2.0})
    assert str(e.value).endswith("(from set: body[0].mass = -2.0)")
    # A dict's errors name its keys, not lines of a TOML rendering the caller never saw.
    d = {
        "simulation": {"dt": "fast", "duration": 0.1, "frame_rate": 50.0},
        "body": [{"kind": "particles", "positions": [[0.0, 1.0, 0.0]], "masses": [1.0]}],
    }
    with pytest.raises(softbody.SceneError) as e:
        softbody.Scene.from_dict(d)
    assert str(e.value) == (
        '<dict>: simulation.dt: invalid type: string "fast", expected a number'
    )


def test_run_takes_the_command_lines_options(cube: softbody.Scene) -> None:
    by_name = softbody.run(cube, threads=1, integrator="rk4", dt=0.0005, duration=0.04, frame_rate=100.0)
    by_set = softbody.run(
        cube,
        threads=1,
        set={
            "simulation.integrator": "rk4",
            "simulation.dt": 0.0005,
            "simulation.duration": 0.04,
            "simulation.frame_rate": 100.0,
        },
    )
    assert by_name.integrator == "rk4" and len(by_name) == 5
    assert np.array_equal(by_name.positions, by_set.positions)


def test_dir_and_repr_show_the_package_not_its_imports(cube: softbody.Scene) -> None:
    names = dir(softbody)
    assert "Simulation" in names and "run" in names
    assert not {"np", "os", "sys", "dataclass", "field"} & set(names)
    traj = softbody.run(cube, threads=1)
    text = repr(traj)
    assert text == (
        "<softbody.Trajectory 6 frames of 27 particles, t = 0 to 0.1 s, "
        "symplectic-euler at dt = 0.001 s on cpu>"
    )
