"""Simulation.step from Python on the standard benchmark cube, against `softbody bench`.

    python crates/python/benches/bench_step.py [--sizes 22] [--threads 2] [--repeat 3]

Builds the cube of src/benchmark.rs (n³ particles on a unit grid, 1 kg, structural, shear and
bending springs with k_s = 2000 N/m and k_d = 5 N·s/m, a ground plane with restitution 0.5, half
the largest stable symplectic-Euler step) as a dict, warms up as the bench does (a step, then
about 0.25 s of steps), then times about 1e7 particle-steps: once as one `step(n)` call, once as
`step(1)` in a Python loop (the per-call cost). Prints one JSON object per size and way.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import softbody

MU_MAX = 18.0  # as src/benchmark.rs
STIFFNESS, DAMPING = 2000.0, 5.0


def dt_max_symplectic(n: int) -> float:
    n3 = float(n) ** 3
    a = STIFFNESS * MU_MAX * n3
    b = 2.0 * DAMPING * MU_MAX * n3
    return (-b + math.sqrt(b * b + 16.0 * a)) / (2.0 * a)


def cube(n: int) -> softbody.Scene:
    dt = 0.5 * dt_max_symplectic(n)
    springs = {"stiffness": STIFFNESS, "damping": DAMPING}
    return softbody.Scene.from_dict(
        {
            "simulation": {
                "integrator": "symplectic-euler",
                "dt": dt,
                "duration": 1.0,
                "frame_rate": 1.0 / max(dt, 1.0 / 30.0),
                "gravity": [0.0, -9.81, 0.0],
                "contact_distance": 0.0,
            },
            "body": [
                {
                    "name": "cube",
                    "kind": "cuboid",
                    "size": [1.0, 1.0, 1.0],
                    "resolution": [n, n, n],
                    "center": [0.5, 1.0, 0.5],
                    "mass": 1.0,
                    "structural": springs,
                    "shear": springs,
                    "bending": springs,
                }
            ],
            "terrain": [{"kind": "plane", "point": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0], "restitution": 0.5}],
        }
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", default="22")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    for n in (int(s) for s in args.sizes.split(",")):
        scene = cube(n)
        particles = n**3
        for _ in range(args.repeat):
            sim = softbody.Simulation(scene, threads=args.threads)
            sim.step(1)
            t0 = time.perf_counter()
            pilot = 0
            while time.perf_counter() - t0 < 0.25:
                sim.step(1)
                pilot += 1
            steps = max(3, round(1e7 / particles))
            t0 = time.perf_counter()
            sim.step(steps)
            one_call = time.perf_counter() - t0
            t0 = time.perf_counter()
            for _ in range(steps):
                sim.step(1)
            loop = time.perf_counter() - t0
            for way, seconds in (("step(n)", one_call), ("step(1) loop", loop)):
                print(
                    json.dumps(
                        {
                            "n": n,
                            "way": way,
                            "device": sim.device,
                            "dt": scene.dt,
                            "particles": particles,
                            "springs": scene.springs,
                            "steps": steps,
                            "seconds": seconds,
                            "particle_steps_per_s": particles * steps / seconds,
                        }
                    ),
                    flush=True,
                )


if __name__ == "__main__":
    main()
