"""Simulation: stepping, NumPy state out and in, energies, determinism, instability, the GIL."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import softbody
from conftest import CUBE, SCENES, require_gpu


def test_step_positions_velocities_and_time(cube: softbody.Scene) -> None:
    sim = softbody.Simulation(cube, threads=1)
    assert (sim.steps, sim.time, sim.dt) == (0, 0.0, 0.001)
    x0 = sim.positions
    assert x0.shape == (27, 3) and x0.dtype == np.float64
    assert np.allclose(sim.velocities, [0.5, 0.0, 0.0])
    sim.step(50)
    assert sim.steps == 50 and sim.time == pytest.approx(0.05)
    x1 = sim.positions
    # Snapshots: the first read is not changed by the steps after it.
    assert not np.array_equal(x0, x1)
    assert np.array_equal(x0, softbody.Simulation(cube).positions)
    # Free fall then contact: everything moved down and along x.
    assert (x1[:, 0] > x0[:, 0]).all()
    assert x1[:, 1].min() >= -1e-9
    assert sim.masses.sum() == pytest.approx(1.0)
    assert sim.springs.shape == (158, 2) and sim.springs.dtype == np.uint32
    d = x0[sim.springs[:, 0]] - x0[sim.springs[:, 1]]
    assert np.allclose(np.linalg.norm(d, axis=1), sim.rest_lengths, rtol=1e-12)
    assert sim.backend == "cpu" and sim.device == "CPU, 1 thread"


def test_energies_match_the_run_output(cube: softbody.Scene) -> None:
    traj = softbody.run(cube, threads=1)
    sim = softbody.Simulation(cube, threads=1)
    steps = np.rint(traj.time / traj.dt).astype(int)
    for k, step in enumerate(steps):
        sim.step(int(step) - sim.steps)
        e = sim.energies()
        assert e["kinetic"] == traj.energy_kinetic[k]
        assert e["gravitational"] == traj.energy_gravitational[k]
        assert e["elastic"] == traj.energy_elastic[k]
        assert e["total"] == pytest.approx(traj.energy_total[k], rel=1e-15)
        assert np.array_equal(sim.positions, traj.positions[k])
        assert np.array_equal(sim.velocities, traj.velocities[k])


def test_trajectory_holds_frames_and_metadata(cube: softbody.Scene) -> None:
    t = softbody.run(cube)
    assert len(t) == 6
    assert t.positions.shape == (6, 27, 3) and t.velocities.shape == (6, 27, 3)
    assert np.allclose(t.time, [0.0, 0.02, 0.04, 0.06, 0.08, 0.1])
    assert (t.dt, t.frame_rate, t.integrator, t.backend) == (0.001, 50.0, "symplectic-euler", "cpu")
    assert t.masses.shape == (27,) and t.springs.shape == (158, 2)
    assert t.rest_lengths.shape == t.stiffness.shape == t.damping.shape == (158,)
    assert set(t.stiffness) == {500.0} and set(t.damping) == {1.0}
    assert t.bodies == [("cube", 0, 27)]
    assert softbody.Scene.from_toml(t.scene_text).particles == 27


def test_same_bits_whatever_the_threads(cube: softbody.Scene) -> None:
    runs = []
    for threads in (1, 2, 3):
        sim = softbody.Simulation(cube, threads=threads)
        sim.step(100)
        runs.append((sim.positions, sim.velocities))
    for x, v in runs[1:]:
        assert np.array_equal(x, runs[0][0]) and np.array_equal(v, runs[0][1])


def test_set_state_round_trips_and_checks_shapes(cube: softbody.Scene) -> None:
    sim = softbody.Simulation(cube)
    x = sim.positions + np.array([0.0, 1.0, 0.0])
    v = np.zeros((27, 3))
    sim.set_state(x, v)
    assert np.array_equal(sim.positions, x) and np.array_equal(sim.velocities, v)
    sim.set_state(x.tolist())  # any array-like; velocities kept
    assert np.array_equal(sim.velocities, v)
    with pytest.raises(ValueError, match=r"positions must have the shape \[27, 3\], not \[26, 3\]"):
        sim.set_state(x[:-1])
    # The moved-up cube falls from there: 1 m higher, so more gravitational energy.
    assert sim.energies()["gravitational"] == pytest.approx(softbody.Simulation(cube).energies()["gravitational"] + 9.81, rel=1e-12)


def test_instability_raises_with_where_it_happened() -> None:
    stiff = CUBE.replace("stiffness = 500.0", "stiffness = 1e7").replace("duration = 0.1", "duration = 2.0")
    scene = softbody.Scene.from_toml(stiff.replace('"symplectic-euler"', '"explicit-euler"'))
    sim = softbody.Simulation(scene)
    with pytest.raises(softbody.UnstableError) as e:
        sim.step(2000)
    assert e.value.step > 0 and e.value.time == pytest.approx(e.value.step * 0.001)
    assert 0 <= e.value.particle < 27
    assert "became unstable" in str(e.value) and "implicit-euler" in str(e.value)
    with pytest.raises(softbody.UnstableError) as e:
        softbody.run(scene)
    partial = e.value.trajectory
    assert isinstance(partial, softbody.Trajectory) and 0 < len(partial) < scene.frames
    assert np.isfinite(partial.positions).all()


def test_the_gil_is_released_while_stepping() -> None:
    jelly = softbody.load_scene(SCENES / "jelly-on-ground.toml")
    sim = softbody.Simulation(jelly, threads=1)
    ticks = 0
    stepping = threading.Event()
    done = threading.Event()

    def step() -> None:
        stepping.set()
        sim.step(4000)
        done.set()

    worker = threading.Thread(target=step)
    started = time.perf_counter()
    worker.start()
    stepping.wait()
    # Python work in this thread goes on while the other steps.
    while not done.is_set():
        ticks += 1
        time.sleep(0.001)
    worker.join()
    elapsed = time.perf_counter() - started
    assert sim.steps == 4000
    # Holding the GIL, the step would block this thread until it ends: a tick or two at most.
    # Released, this thread ticks every millisecond or so of the ~0.1 s of stepping.
    assert ticks >= 5, (ticks, elapsed)


def test_the_gpu_backend_runs_the_same_scene(cube: softbody.Scene) -> None:
    try:
        gpu = softbody.Simulation(cube, backend="gpu")
    except softbody.DeviceError as e:
        if require_gpu():
            raise
        pytest.skip(f"no GPU adapter: {e}")
    cpu = softbody.Simulation(cube)
    gpu.step(50)
    cpu.step(50)
    assert gpu.backend == "gpu"
    # f32 on the device against f64: micrometres apart after 50 steps.
    assert np.abs(gpu.positions - cpu.positions).max() < 1e-5


def test_bad_arguments_are_python_errors(cube: softbody.Scene) -> None:
    with pytest.raises(ValueError, match="unknown backend `tpu`"):
        softbody.Simulation(cube, backend="tpu")
    with pytest.raises(ValueError, match="threads must be at least 1"):
        softbody.Simulation(cube, threads=0)
    with pytest.raises(TypeError, match="a scene is"):
        softbody.Simulation(42)
