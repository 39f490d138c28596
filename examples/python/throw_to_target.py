"""Find the throw that lands a jelly at a target: the initial velocity whose run ends with the
jelly's centre of mass at `TARGET`, by Newton-like steps on the adjoint's gradient
(softbody.gradient with target_com, with respect to body[0].velocity).

    python examples/python/throw_to_target.py
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

import softbody

SCENE = {
    "simulation": {"integrator": "rk4", "dt": 1e-3, "duration": 0.6, "frame_rate": 50.0},
    "body": [{
        "kind": "cuboid", "size": [0.3, 0.3, 0.3], "resolution": [3, 3, 3],
        "center": [0.0, 0.5, 0.0], "velocity": [1.0, 1.0, 0.0], "mass": 2.7,
        "structural": {"stiffness": 900.0, "damping": 2.0},
        "shear": {"stiffness": 700.0, "damping": 1.5},
    }],
    "terrain": [{"kind": "plane", "normal": [0.0, 1.0, 0.0], "friction": 0.5}],
}
TARGET = (1.2, 0.15, 0.3)


def main() -> None:
    scene = softbody.load_scene(SCENE)

    def loss_and_gradient(v: np.ndarray):
        g = softbody.gradient(scene, ["body[0].velocity"], target_com=TARGET,
                              set={"body[0].velocity": [float(x) for x in v]})
        return g.loss, g.gradient["body[0].velocity"]

    result = scipy.optimize.minimize(loss_and_gradient, np.array([1.0, 1.0, 0.0]), jac=True,
                                     method="L-BFGS-B", options={"ftol": 1e-20, "gtol": 1e-14})
    print(f"throw with velocity {result.x} m/s: the centre ends {np.sqrt(result.fun):.2e} m "
          f"from {TARGET} after {result.nit} iterations")


if __name__ == "__main__":
    main()
