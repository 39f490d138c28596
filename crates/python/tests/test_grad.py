"""softbody.gradient and Trajectory.backward: the library's adjoint from Python, against central
differences of runs, against each other, and its refusals; the scipy fit example's law."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import softbody
from conftest import REPO

TARGET = (0.4, 0.2, -0.1)


def com_loss(scene: softbody.Scene, set=None) -> float:
    traj = softbody.run(scene, set=set)
    m = traj.masses
    c = (m[:, None] * traj.positions[-1]).sum(axis=0) / m.sum()
    return float(((c - np.array(TARGET)) ** 2).sum())


def test_gradient_is_the_derivative_of_the_run(cube: softbody.Scene) -> None:
    keys = ["body[0].structural.stiffness", "terrain[0].friction", "body[0].velocity"]
    g = softbody.gradient(cube, keys, target_com=TARGET, threads=1)
    assert g.loss == pytest.approx(com_loss(cube), rel=1e-12)
    # Central differences with δ = 1e-6 of the value: truncation ~δ², rounding ~1e-13·L/δ.
    for key, value in [("body[0].structural.stiffness", 500.0), ("terrain[0].friction", 0.3)]:
        d = 1e-6 * value
        fd = (com_loss(cube, {key: value + d}) - com_loss(cube, {key: value - d})) / (2 * d)
        assert g.gradient[key] == pytest.approx(fd, rel=1e-6, abs=1e-13 * g.loss / d), key
    v = g.gradient["body[0].velocity"]
    assert v.shape == (3,)
    assert g.positions.shape == (27, 3) and g.stiffness.shape == g.damping.shape
    assert g.steps == 100 and g.peak_memory_bytes > 0


def test_backward_with_a_losss_cotangents_is_the_built_in_gradient(cube: softbody.Scene) -> None:
    # L = |c − target|² at the last frame, given as ∂L/∂x = 2(c − target)·m_i/M there.
    traj = softbody.run(cube)
    m = traj.masses
    c = (m[:, None] * traj.positions[-1]).sum(axis=0) / m.sum()
    dx = np.zeros_like(traj.positions)
    dx[-1] = 2.0 * (c - np.array(TARGET)) * (m / m.sum())[:, None]
    keys = ["body[0].velocity", "body[0].shear.damping"]
    given = traj.backward(positions=dx, wrt=keys)
    built_in = softbody.gradient(cube, keys, target_com=TARGET)
    assert given.loss is None
    for key in keys:
        np.testing.assert_allclose(given.gradient[key], built_in.gradient[key], rtol=1e-12)
    np.testing.assert_allclose(given.velocities, built_in.velocities, rtol=1e-12, atol=1e-300)


def test_implicit_euler_has_its_gradient_in_flight_and_in_contact(cube: softbody.Scene) -> None:
    implicit = {"simulation.integrator": "implicit-euler"}
    # Its bottom face on the ground: in contact from the first step (the Rust adjoint tests
    # check such runs against differences); the loss is the plain run's.
    grounded = {**implicit, "body[0].center": [0.0, 0.1, 0.0]}
    g = softbody.gradient(cube, ["body[0].mass"], target_com=TARGET, set=grounded, threads=1)
    assert g.loss == pytest.approx(com_loss(cube, grounded), rel=1e-12)
    assert np.isfinite(g.gradient["body[0].mass"])
    # From 0.2 m up the cube falls 4.9 cm in the run's 0.1 s: no contact.
    keys = ["body[0].structural.stiffness", "body[0].velocity"]
    g = softbody.gradient(cube, keys, target_com=TARGET, set=implicit, threads=1)
    assert g.loss == pytest.approx(com_loss(cube, implicit), rel=1e-12)
    # The springs' forces and blocks cancel in the sum of the system's rows, so the centre's
    # velocity gains h g a step whatever the springs do, and c moves by h v' a step:
    # ∂c/∂v₀ = T = 0.1 s and ∂L/∂v₀ = 2(c − target)·T, to the CG's tolerance (1e-8; 100×
    # it, as the Rust tests allow).
    traj = softbody.run(cube, set=implicit)
    m = traj.masses
    c = (m[:, None] * traj.positions[-1]).sum(axis=0) / m.sum()
    np.testing.assert_allclose(
        g.gradient["body[0].velocity"], 2.0 * (c - np.array(TARGET)) * 0.1, rtol=1e-6
    )


def test_control_forces_move_the_run_and_backward_gives_their_gradient(cube: softbody.Scene) -> None:
    free = softbody.run(cube)
    frames, n = free.positions.shape[:2]
    rng = np.random.default_rng(7)
    u = 0.05 * rng.standard_normal((frames, n, 3))
    pushed = softbody.run(cube, controls=u)
    np.testing.assert_array_equal(pushed.controls, u)
    # Frame 0's forces act over the first frame's steps: its end moves, the start does not.
    np.testing.assert_array_equal(pushed.positions[0], free.positions[0])
    assert np.abs(pushed.positions[1] - free.positions[1]).max() > 0.0
    # L = ½ Σ |x|² at the last frame.
    dx = np.zeros_like(pushed.positions)
    dx[-1] = pushed.positions[-1]
    g = pushed.backward(positions=dx)
    assert g.controls.shape == (frames, n, 3)
    assert not g.controls[-1].any()  # the last frame's forces act in no step
    # Central differences along a random direction, as the Rust tests take them (δ = 1e-6 N on
    # forces of 0.05 N, in flight: no contact's branch to cross; truncation ~δ²).
    d = rng.standard_normal((frames, n, 3))
    delta = 1e-6

    def loss(s: float) -> float:
        x = softbody.run(cube, controls=u + s * d).positions[-1]
        return 0.5 * float((x**2).sum())

    fd = (loss(delta) - loss(-delta)) / (2 * delta)
    assert float((g.controls * d).sum()) == pytest.approx(fd, rel=1e-6)
    # The built-in loss takes them too.
    com = softbody.gradient(cube, ["body[0].mass"], target_com=TARGET, controls=u)
    assert com.controls.shape == (frames, n, 3)
    assert softbody.gradient(cube, ["body[0].mass"], target_com=TARGET).controls is None
    with pytest.raises(softbody.SceneError, match="GPU"):
        softbody.run(cube, backend="gpu", controls=u)
    with pytest.raises(softbody.SceneError, match=f"for {frames} frames of {n} particles"):
        softbody.run(cube, controls=u[:-1])


def test_refusals(cube: softbody.Scene) -> None:
    with pytest.raises(softbody.SceneError, match="body\\[N\\].structural.stiffness"):
        softbody.gradient(cube, ["body[0].size"], target_com=TARGET)
    with pytest.raises(ValueError, match="one loss"):
        softbody.gradient(cube, ["body[0].mass"])
    traj = softbody.run(cube)
    with pytest.raises(ValueError, match="cotangents"):
        traj.backward(wrt=["body[0].mass"])
    with pytest.raises(softbody.SceneError, match="frames"):
        traj.backward(positions=np.zeros((2, 27, 3)), wrt=["body[0].mass"])


@pytest.mark.skipif(importlib.util.find_spec("scipy") is None, reason="scipy is not installed")
def test_the_scipy_example_recovers_stiffness_and_damping_from_3x_off(tmp_path) -> None:
    spec = importlib.util.spec_from_file_location(
        "fit_example", REPO / "examples" / "python" / "fit_stiffness_damping.py"
    )
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    scene_file = tmp_path / "jelly.toml"
    scene_file.write_text(example.SCENE)
    traj = softbody.run(scene_file)
    np.savez(tmp_path / "recorded.npz", time=traj.time, positions=traj.positions,
             frame_rate=np.float64(traj.frame_rate))
    fitted = example.fit(tmp_path / "recorded.npz", softbody.load_scene(scene_file),
                         np.array([2700.0, 6.0]))
    np.testing.assert_allclose(fitted, [900.0, 2.0], rtol=1e-6)
