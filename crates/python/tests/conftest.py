"""Shared scenes and paths of the Python tests (run from anywhere: paths are from this file)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import softbody

REPO = Path(__file__).resolve().parents[3]
SCENES = REPO / "scenes"

# A small cube on the ground: fast enough for every test, with contact, gravity and springs.
CUBE = """\
[simulation]
integrator = "symplectic-euler"
dt = 0.001
duration = 0.1
frame_rate = 50.0

[[body]]
name = "cube"
kind = "cuboid"
size = [0.2, 0.2, 0.2]
resolution = [3, 3, 3]
center = [0.0, 0.3, 0.0]
velocity = [0.5, 0.0, 0.0]
mass = 1.0
structural = { stiffness = 500.0, damping = 1.0 }
shear = { stiffness = 500.0, damping = 1.0 }

[[terrain]]
kind = "plane"
normal = [0.0, 1.0, 0.0]
friction = 0.3
"""


@pytest.fixture
def cube_file(tmp_path: Path) -> Path:
    path = tmp_path / "cube.toml"
    path.write_text(CUBE)
    return path


@pytest.fixture
def cube() -> softbody.Scene:
    return softbody.Scene.from_toml(CUBE, origin="cube.toml")


def require_gpu() -> bool:
    """CI sets SOFTBODY_REQUIRE_GPU=1 (it installs a software Vulkan adapter): then a missing
    adapter fails the GPU tests instead of skipping them, as for the Rust tests."""
    return os.environ.get("SOFTBODY_REQUIRE_GPU") == "1"
