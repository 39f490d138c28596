"""Recover a jelly's stiffness and damping from a recorded motion with scipy.

The "recording" is a run of the scene with the true values (900 N/m, 2 N·s/m); the fit starts
3× off and minimises the mean squared distance to the recorded positions, its gradient from the
run's adjoint (softbody.gradient with target_frames), with scipy.optimize.minimize(jac=True) in
log-parameters (stiffness and damping stay positive and move by factors).

    python examples/python/fit_stiffness_damping.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import scipy.optimize

import softbody

SCENE = """\
[simulation]
integrator = "symplectic-euler"
dt = 1e-3
duration = 0.3
frame_rate = 100.0

[[body]]
kind = "cuboid"
size = [0.3, 0.3, 0.3]
resolution = [3, 3, 3]
center = [0.0, 0.25, 0.0]
velocity = [0.5, 0.0, 0.0]
mass = 2.7
structural = { stiffness = 900.0, damping = 2.0 }
shear = { stiffness = 700.0, damping = 1.5 }

[[terrain]]
kind = "plane"
normal = [0.0, 1.0, 0.0]
friction = 0.2
"""

KEYS = ["body[0].structural.stiffness", "body[0].structural.damping"]


def fit(recorded: Path, scene: softbody.Scene, start: np.ndarray) -> np.ndarray:
    def loss_and_gradient(u: np.ndarray):
        values = start * np.exp(u)
        g = softbody.gradient(
            scene, KEYS, target_frames=recorded, set=dict(zip(KEYS, map(float, values)))
        )
        # d/du of L(start·e^u) = dL/dθ · θ.
        return g.loss, np.array([g.gradient[k] for k in KEYS]) * values

    result = scipy.optimize.minimize(
        loss_and_gradient, np.zeros(len(KEYS)), jac=True, method="L-BFGS-B",
        options={"ftol": 1e-30, "gtol": 1e-30, "maxiter": 60},
    )
    return start * np.exp(result.x)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        scene_file = Path(tmp) / "jelly.toml"
        scene_file.write_text(SCENE)
        recorded = Path(tmp) / "recorded.npz"
        traj = softbody.run(scene_file)
        np.savez(recorded, time=traj.time, positions=traj.positions,
                 frame_rate=np.float64(traj.frame_rate))
        scene = softbody.load_scene(scene_file)
        fitted = fit(recorded, scene, np.array([2700.0, 6.0]))
        for key, value, truth in zip(KEYS, fitted, [900.0, 2.0]):
            print(f"{key} = {value:.9g} (recorded with {truth}, relative error {value / truth - 1:.1e})")


if __name__ == "__main__":
    main()
