"""The Ray executor against a local Ray cluster started by the test (``ray.init`` with two CPUs:
a head node, its raylet and workers on this machine): a small bounded sweep, whose records and
files must be the local executor's, and resuming."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import softbody
from conftest import CUBE

ray = pytest.importorskip("ray")

SWEEP = """\
format = "npz"
metrics = ["frames", "final_kinetic_energy", "max_speed", "center_displacement"]
[random]
runs = 6
seed = 3
[random.parameters]
"body[0].mass" = { uniform = [0.5, 2.0] }
"terrain[0].friction" = { choice = [0.0, 0.5, 1.0] }
"""


@pytest.fixture(scope="module")
def cluster():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def strip(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


def test_a_sweep_on_ray_gives_the_local_records_and_files(tmp_path: Path, cluster) -> None:
    (tmp_path / "cube.toml").write_text(CUBE)
    spec = tmp_path / "sweep.toml"
    spec.write_text('scene = "cube.toml"\n' + SWEEP)
    local = softbody.sweep(spec, out=tmp_path / "local", progress=False)
    on_ray = softbody.sweep(spec, out=tmp_path / "ray", executor="ray", progress=False)
    assert [r["status"] for r in on_ray] == ["ok"] * 6
    assert strip(on_ray) == strip(local)
    for r in on_ray:
        a, b = np.load(tmp_path / "local" / r["file"]), np.load(tmp_path / "ray" / r["file"])
        for name in ("positions", "velocities", "energy_kinetic", "masses"):
            assert np.array_equal(a[name], b[name]), name
    lines = (tmp_path / "ray" / "manifest.jsonl").read_text().splitlines()
    assert len(lines) == 1 + 6

    # Resuming on Ray: a missing record runs again, the rest are skipped.
    kept = [l for l in lines if json.loads(l).get("run") != 4]
    (tmp_path / "ray" / "manifest.jsonl").write_text("\n".join(kept) + "\n")
    before = {r["run"]: r["seconds"] for r in on_ray}
    again = softbody.sweep(spec, out=tmp_path / "ray", executor="ray", progress=False)
    assert strip(again) == strip(local)
    changed = [r["run"] for r in again if r["seconds"] != before[r["run"]]]
    assert changed == [4]


def test_batches_of_runs_per_task_give_the_same_records_and_files(tmp_path: Path, cluster) -> None:
    (tmp_path / "cube.toml").write_text(CUBE)
    spec = tmp_path / "sweep.toml"
    spec.write_text('scene = "cube.toml"\n' + SWEEP)
    one = softbody.sweep(spec, out=tmp_path / "one", executor="ray", progress=False)
    # Six runs in tasks of four and two.
    batched = softbody.sweep(spec, out=tmp_path / "four", executor="ray", batch=4, progress=False)
    assert [r["status"] for r in batched] == ["ok"] * 6
    assert strip(batched) == strip(one)
    for r in batched:
        assert (tmp_path / "one" / r["file"]).read_bytes() == (tmp_path / "four" / r["file"]).read_bytes()
    assert len((tmp_path / "four" / "manifest.jsonl").read_text().splitlines()) == 1 + 6
