//! Sweeps from Python: `sweep_local` on this machine's cores, and for an executor that runs the
//! jobs elsewhere (Ray) `SweepPlan` (the pending jobs, the manifest) and `run_job`.

use std::path::PathBuf;

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use softbody::sweep::{Job, Manifest, Options, Record, Sweep};
use softbody::toml;

use crate::errors::{OutputError, SceneError, SoftbodyError, scene_error};
use crate::interrupt::{count_or_none, interruptible};
use crate::scene::to_toml;

/// A sweep argument: a path to a sweep file, or a dict laid out as one (its paths relative to
/// the current directory).
fn sweep_of(sweep: &Bound<'_, PyAny>) -> PyResult<Sweep> {
    let result = if let Ok(dict) = sweep.cast::<PyDict>() {
        let text = toml::to_string(&to_toml(dict.as_any())?).map_err(scene_error)?;
        let origin = std::env::current_dir()
            .unwrap_or_default()
            .join("<sweep>.toml");
        Sweep::from_toml(&text, &origin)
    } else {
        let path: PathBuf = sweep.extract().map_err(|_| {
            PyTypeError::new_err("a sweep is a path to a sweep file, or a dict laid out as one")
        })?;
        Sweep::from_file(&path)
    };
    result.map_err(sweep_error)
}

fn sweep_error(e: softbody::sweep::SweepError) -> PyErr {
    if let softbody::sweep::SweepError::Options(why) = e {
        return PyValueError::new_err(why);
    }
    if e.is_bad_input() {
        SceneError::new_err(e.to_string())
    } else {
        OutputError::new_err(e.to_string())
    }
}

fn records_list<'py>(py: Python<'py>, records: &[Record]) -> PyResult<Bound<'py, PyAny>> {
    let json = py.import("json")?;
    let text = serde_json::to_string(records).map_err(|e| SoftbodyError::new_err(e.to_string()))?;
    json.call_method1("loads", (text,))
}

/// Runs a sweep on the local cores into `out` (GIL released); returns every record of the
/// manifest, in run order. `progress(done, total)` is called as runs end.
#[pyfunction]
#[pyo3(signature = (sweep, out, workers = None, task_index = None, task_count = None, progress = None))]
pub(crate) fn sweep_local<'py>(
    py: Python<'py>,
    sweep: &Bound<'py, PyAny>,
    out: PathBuf,
    workers: Option<i64>,
    task_index: Option<i64>,
    task_count: Option<i64>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let sweep = sweep_of(sweep)?;
    let (workers, task_index, task_count) = (
        count_or_none("workers", workers, 1)?,
        count_or_none("task_index", task_index, 0)?,
        count_or_none("task_count", task_count, 1)?,
    );
    if task_count.is_some() && task_index.is_none() {
        return Err(PyValueError::new_err("task_count takes a task_index"));
    }
    let report = |done: usize, total: usize| {
        if let Some(cb) = &progress {
            Python::attach(|py| {
                if let Err(e) = cb.call1(py, (done, total)) {
                    e.print(py);
                }
            });
        }
    };
    interruptible(py, |stop| {
        let options = Options {
            workers,
            task: task_index.map(|i| (i, task_count.unwrap_or(1))),
            stop: Some(stop),
        };
        softbody::sweep::run_local(&sweep, &out, &options, &report)
    })?
    .map_err(sweep_error)?;
    // The records of the manifest as written (one per run that has one).
    let records = py
        .detach(|| softbody::sweep::read_manifest(&sweep, &out))
        .map_err(sweep_error)?;
    records_list(py, &records)
}

/// A sweep's plan and manifest for an executor that runs the jobs elsewhere (Ray): the jobs
/// not yet finished, and the manifest their records go to.
#[pyclass(module = "softbody")]
pub(crate) struct SweepPlan {
    sweep: Sweep,
    out: PathBuf,
    manifest: Manifest,
}

#[pymethods]
impl SweepPlan {
    #[new]
    fn new(py: Python<'_>, sweep: &Bound<'_, PyAny>, out: PathBuf) -> PyResult<SweepPlan> {
        let sweep = sweep_of(sweep)?;
        let manifest = py
            .detach(|| Manifest::open(&sweep, &out, None))
            .map_err(sweep_error)?;
        Ok(SweepPlan {
            sweep,
            out,
            manifest,
        })
    }

    /// Number of runs in the plan.
    fn __len__(&self) -> usize {
        self.sweep.len()
    }

    /// Solver threads per run.
    #[getter]
    fn threads(&self) -> usize {
        self.sweep.threads()
    }

    /// The manifest's path.
    #[getter]
    fn manifest(&self) -> PathBuf {
        self.manifest.path().to_owned()
    }

    /// The jobs of the runs not finished, as JSON (self-contained: the scene's text travels
    /// with each).
    fn pending(&self) -> PyResult<Vec<String>> {
        (0..self.sweep.len())
            .filter(|&i| !self.manifest.finished(i))
            .map(|i| {
                serde_json::to_string(&self.sweep.job(i, &self.out))
                    .map_err(|e| SoftbodyError::new_err(e.to_string()))
            })
            .collect()
    }

    /// Appends a record (JSON, from `run_job`) to the manifest.
    fn record(&self, py: Python<'_>, record: &str) -> PyResult<()> {
        let record: Record = serde_json::from_str(record)
            .map_err(|e| SoftbodyError::new_err(format!("not a sweep record: {e}")))?;
        py.detach(|| self.manifest.append(record))
            .map_err(|e| OutputError::new_err(format!("{}: {e}", self.manifest.path().display())))
    }

    /// Every record, in run order.
    fn records<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        records_list(py, &self.manifest.records())
    }
}

/// Runs one sweep job (JSON, from `SweepPlan.pending`), its output to `output` when given
/// (else the job's own path); returns its record as JSON. The GIL is released meanwhile.
#[pyfunction]
#[pyo3(signature = (job, output = None))]
pub(crate) fn run_job(py: Python<'_>, job: &str, output: Option<PathBuf>) -> PyResult<String> {
    let mut job: Job =
        serde_json::from_str(job).map_err(|e| SceneError::new_err(format!("not a job: {e}")))?;
    if output.is_some() {
        job.output = output;
    }
    let record = py.detach(|| job.run());
    serde_json::to_string(&record).map_err(|e| SoftbodyError::new_err(e.to_string()))
}
