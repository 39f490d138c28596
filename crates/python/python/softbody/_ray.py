"""The Ray executor of softbody.sweep: each run of the plan a Ray task.

The driver opens the sweep's plan and manifest (``SweepPlan``: resuming as the local executor
does), submits one task per `batch` pending runs (one by default) — their jobs, JSON strings
carrying the base scene's text, so a worker needs no scene file — and appends the records to the
manifest as their task ends (``ray.wait``), in the order tasks end and within a task in run
order. A task of several runs pays Ray's scheduling once for all of them (for many short runs on
a cluster); a task that fails as a whole (its worker lost) is retried as a whole, and since runs
are deterministic its records are the same. Single-file outputs (npz, jsonl, csv) come back to the
driver as bytes and are written into the out directory there, so workers need no shared file
system; series outputs (vtk, ply, obj) are written by the worker in place and need one.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

from . import _native

# Formats whose output is one file: shipped back to the driver as bytes.
_SINGLE_FILE = {"npz", "jsonl", "csv"}


def _run_job(job: str) -> Tuple[str, Optional[bytes]]:
    """Runs one job on a worker: its record (JSON) and, for a single-file format, the file's
    bytes (the record's `file` is where the driver puts them)."""
    spec = json.loads(job)
    if spec.get("format") not in _SINGLE_FILE or not spec.get("output"):
        return _native.run_job(job), None
    with tempfile.TemporaryDirectory(prefix="softbody-ray-") as tmp:
        local = Path(tmp) / Path(spec["output"]).name
        record = _native.run_job(job, str(local))
        data = local.read_bytes() if local.exists() else None
        return record, data


def _run_jobs(jobs: List[str]) -> List[Tuple[str, Optional[bytes]]]:
    """Runs a batch of jobs on a worker, one after the other: `_run_job`'s results, in order."""
    return [_run_job(job) for job in jobs]


def _put(path: Path, data: bytes) -> None:
    """Writes `data` to `path` as softbody writes files: beside it, then renamed into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, staged = tempfile.mkstemp(prefix=".softbody-ray-", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(staged, path)
    except BaseException:
        if os.path.exists(staged):
            os.unlink(staged)
        raise


def sweep_on_ray(
    spec: Union[str, "os.PathLike[str]", Mapping[str, Any]],
    out: Path,
    *,
    address: Optional[str] = None,
    batch: int = 1,
    progress: bool = True,
) -> List[Dict[str, Any]]:
    try:
        import ray
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise _native.SoftbodyError(
            "executor='ray' needs Ray: pip install 'ray>=2.9' (or ./crates/python[ray])"
        ) from e
    plan = _native.SweepPlan(spec, out)
    pending = plan.pending()
    if not ray.is_initialized():
        if address == "local":
            ray.init(include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
    remote = ray.remote(num_cpus=plan.threads, max_retries=2)(_run_jobs)
    refs = [remote.remote(pending[i : i + batch]) for i in range(0, len(pending), batch)]
    total, done = len(pending), 0
    show = progress and sys.stderr.isatty()
    while refs:
        ready, refs = ray.wait(refs, num_returns=min(len(refs), 16), timeout=None)
        for ref in ready:
            for record_json, data in ray.get(ref):
                record = json.loads(record_json)
                if data is not None and record.get("file"):
                    _put(out / record["file"], data)
                plan.record(record_json)
                done += 1
        if show:
            print(f"\r{done}/{total} runs on Ray", end="\n" if not refs else "", file=sys.stderr, flush=True)
    return plan.records()
