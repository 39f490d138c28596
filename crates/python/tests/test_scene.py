"""Scenes from a file, a TOML string or a dict; settings; errors with the CLI's messages."""

from __future__ import annotations

from pathlib import Path

import pytest

import softbody
from conftest import CUBE, SCENES


def test_file_string_and_dict_give_the_same_scene(cube_file: Path) -> None:
    a = softbody.load_scene(cube_file)
    b = softbody.Scene.from_toml(CUBE)
    table = {
        "simulation": {"integrator": "symplectic-euler", "dt": 0.001, "duration": 0.1, "frame_rate": 50.0},
        "body": [
            {
                "name": "cube",
                "kind": "cuboid",
                "size": [0.2, 0.2, 0.2],
                "resolution": [3, 3, 3],
                "center": [0.0, 0.3, 0.0],
                "velocity": [0.5, 0.0, 0.0],
                "mass": 1.0,
                "structural": {"stiffness": 500.0, "damping": 1.0},
                "shear": {"stiffness": 500.0, "damping": 1.0},
            }
        ],
        "terrain": [{"kind": "plane", "normal": [0.0, 1.0, 0.0], "friction": 0.3}],
    }
    c = softbody.load_scene(table)
    for s in (a, b, c):
        assert (s.particles, s.springs, s.total_mass) == (27, 54 + 104, 1.0)
        assert (s.dt, s.duration, s.frame_rate, s.integrator) == (0.001, 0.1, 50.0, "symplectic-euler")
        assert (s.steps, s.frames) == (100, 6)
    # The same scene runs to the same bits whichever way it came.
    x = [softbody.run(s, threads=1).positions for s in (a, b, c)]
    assert (x[0] == x[1]).all() and (x[0] == x[2]).all()


def test_settings_change_values_and_the_text_says_so() -> None:
    s = softbody.load_scene(SCENES / "jelly-on-ground.toml", set={"body[0].mass": 10.0, "simulation.integrator": "rk4"})
    assert s.total_mass == 10.0
    assert s.integrator == "rk4"
    assert 'integrator = "rk4"' in s.text
    # with_settings on top; NumPy scalars and lists are values too.
    import numpy as np

    t = s.with_settings({"simulation.gravity": np.array([0.0, -1.62, 0.0]), "body[0].mass": np.float32(2.5)})
    assert t.total_mass == 2.5
    again = softbody.Scene.from_toml(t.text)
    assert again.total_mass == 2.5 and again.integrator == "rk4"


def test_a_bad_setting_raises_scene_error_with_the_cli_message() -> None:
    path = SCENES / "jelly-on-ground.toml"
    with pytest.raises(softbody.SceneError) as e:
        softbody.load_scene(path, set={"body[0].mass": -2.0})
    assert str(e.value) == f"{path}: body[0].mass: must be greater than zero, not -2 (from set: body[0].mass = -2.0)"
    with pytest.raises(softbody.SceneError, match=r"body has 1 entries \(body\[0\] to body\[0\]\)"):
        softbody.load_scene(path, set={"body[3].mass": 1.0})
    with pytest.raises(softbody.SceneError, match="is not a key path"):
        softbody.load_scene(path, set={"body[0]mass": 1.0})
    with pytest.raises(TypeError, match="has no TOML value"):
        softbody.load_scene(path, set={"body[0].mass": object()})


def test_a_bad_scene_is_located_like_the_file() -> None:
    bad = CUBE.replace("mass = 1.0", "mass = -1.0")
    with pytest.raises(softbody.SceneError) as e:
        softbody.Scene.from_toml(bad, origin="bad.toml")
    line = bad.splitlines().index("mass = -1.0") + 1
    assert str(e.value).startswith(f"bad.toml:{line}:8: body[0].mass: must be greater than zero, not -1")
    with pytest.raises(softbody.SceneError, match="cannot read"):
        softbody.Scene.from_file("/nonexistent/scene.toml")
    assert issubclass(softbody.SceneError, softbody.SoftbodyError)
