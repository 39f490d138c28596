"""softbody.sweep on the local cores: records, files read back by NumPy, resuming, Slurm tasks,
errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import softbody
from conftest import CUBE


def sweep_file(tmp_path: Path, body: str) -> Path:
    (tmp_path / "cube.toml").write_text(CUBE)
    path = tmp_path / "sweep.toml"
    path.write_text('scene = "cube.toml"\n' + body)
    return path


GRID = """\
format = "npz"
metrics = ["frames", "final_kinetic_energy", "min_height", "final_center"]
[grid]
"body[0].mass" = [1.0, 2.0, -1.0]
"terrain[0].friction" = [0.1, 0.9]
"""


def test_a_grid_sweep_records_every_run_and_its_frames(tmp_path: Path) -> None:
    out = tmp_path / "out"
    records = softbody.sweep(sweep_file(tmp_path, GRID), out=out, workers=2, progress=False)
    assert [r["run"] for r in records] == list(range(6))
    assert [r["status"] for r in records] == ["ok"] * 4 + ["invalid"] * 2
    assert [r["exit_status"] for r in records] == [0] * 4 + [2] * 2
    assert records[3]["parameters"] == {"body[0].mass": 2.0, "terrain[0].friction": 0.9}
    assert "must be greater than zero, not -1" in records[4]["error"]
    assert records[4]["file"] is None and records[4]["metrics"]["frames"] == 0
    for r in records[:4]:
        assert r["metrics"]["frames"] == 6
        # The run's frames, read back by NumPy, are what it ran with and what the record says.
        d = np.load(out / r["file"])
        assert d["positions"].shape == (6, 27, 3)
        assert str(d["integrator"]) == "symplectic-euler" and float(d["dt"]) == 0.001
        assert d["masses"].sum() == pytest.approx(r["parameters"]["body[0].mass"])
        assert d["energy_kinetic"][-1] == r["metrics"]["final_kinetic_energy"]
        assert d["positions"][:, :, 1].min() == r["metrics"]["min_height"]
        center = (d["masses"][:, None] * d["positions"][-1]).sum(axis=0) / d["masses"].sum()
        assert np.allclose(center, r["metrics"]["final_center"], rtol=1e-12, atol=1e-15)
        text = str(d["scene_text"])
        assert f"friction = {r['parameters']['terrain[0].friction']}" in text
    # The manifest holds the same records (in the order the runs ended).
    lines = (out / "manifest.jsonl").read_text().splitlines()
    assert json.loads(lines[0])["runs"] == 6
    assert sorted((json.loads(l) for l in lines[1:]), key=lambda r: r["run"]) == records


def test_a_sweep_run_again_skips_the_finished_runs(tmp_path: Path) -> None:
    path = sweep_file(tmp_path, GRID.replace('"npz"', '"none"'))
    out = tmp_path / "out"
    first = softbody.sweep(path, out=out, progress=False)
    # Drop run 1's record and pretend run 2 failed: those two run again, nothing else.
    lines = (out / "manifest.jsonl").read_text().splitlines()
    kept = [lines[0]]
    for line in lines[1:]:
        r = json.loads(line)
        if r["run"] == 1:
            continue
        if r["run"] == 2:
            r["status"], r["exit_status"], r["seconds"] = "failed", 1, -1.0
        kept.append(json.dumps(r))
    (out / "manifest.jsonl").write_text("\n".join(kept) + "\n")
    calls = []
    again = softbody.sweep(path, out=out, progress=True)
    second = softbody._native.sweep_local(path, out, None, None, None, lambda d, t: calls.append((d, t)))
    assert calls == [(0, 0)], "nothing left to run the third time"
    for a, b in zip(first, again):
        assert {k: v for k, v in a.items() if k != "seconds"} == {k: v for k, v in b.items() if k != "seconds"}
    assert again[2]["seconds"] >= 0.0, "run 2 ran again"
    assert [r["seconds"] for r in again] == [r["seconds"] for r in second]


def test_slurm_tasks_and_dict_specs(tmp_path: Path) -> None:
    (tmp_path / "cube.toml").write_text(CUBE)
    spec = {
        "scene": str(tmp_path / "cube.toml"),
        "format": "none",
        "metrics": ["final_time"],
        "runs": [{"body[0].mass": 1.5}, {"body[0].mass": 2.5}, {"simulation.duration": 0.05}],
    }
    out = tmp_path / "out"
    for task in range(3):
        records = softbody.sweep(spec, out=out, task_index=task, progress=False)
        assert sorted(r["run"] for r in records) == list(range(task + 1))
        assert (out / f"manifest-task-{task}.jsonl").is_file()
    merged = softbody.sweep(spec, out=out, progress=False)
    assert [r["metrics"]["final_time"] for r in merged] == [0.1, 0.1, 0.04]  # 50 frames/s: the last frame of 0.05 s is at 0.04 s
    assert len((out / "manifest.jsonl").read_text().splitlines()) == 1 + 3


def test_a_bad_sweep_raises_scene_error_with_its_line(tmp_path: Path) -> None:
    path = sweep_file(tmp_path, '[grid]\n"body[0].mass" = 2.0\n')
    with pytest.raises(softbody.SceneError) as e:
        softbody.sweep(path, out=tmp_path / "out")
    assert str(e.value).startswith(f"{path}:3:18: grid.body[0].mass: a grid parameter takes a non-empty list")
    with pytest.raises(ValueError, match="unknown executor"):
        softbody.sweep(path, executor="dask")
    with pytest.raises(ValueError, match="batch is for executor='ray'"):
        softbody.sweep(path, out=tmp_path / "out", batch=2)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="batch must be a whole number of runs"):
            softbody.sweep(path, out=tmp_path / "out", executor="ray", batch=bad)
    assert not (tmp_path / "out").exists()
