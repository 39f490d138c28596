//! `softbody._native`: the Rust side of the Python package `softbody` (PyO3, NumPy through
//! rust-numpy). The package's `__init__.py` re-exports it and adds what is plain Python (the
//! `Trajectory` record, `load_scene`, the Ray executor).
//!
//! Everything that takes time — opening a solver, stepping, a whole run, a local sweep, one
//! sweep job — runs with the GIL released (`Python::detach`), so Python threads (and Ray's
//! worker machinery) go on meanwhile. A solver sits behind a `Mutex` that is only ever locked
//! with the GIL released: a thread waiting for it never holds the GIL the holder needs back.
//!
//! Arrays handed to Python are built once in Rust memory and given to NumPy without a copy
//! (`IntoPyArray`): a `positions` read is one copy of the solver's state (which the solver
//! reuses as its scratch, so it cannot be lent out), a trajectory is no copy at all past the
//! frames' own collection.

mod errors;
mod grad;
mod interrupt;
mod scene;
mod simulation;
mod sweep;
mod trajectory;

use pyo3::prelude::*;

use errors::{DeviceError, OutputError, SceneError, SoftbodyError, UnstableError};
use scene::Scene;
use simulation::Simulation;
use sweep::{SweepPlan, run_job, sweep_local};
use trajectory::run;

/// `softbody._native`.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("SoftbodyError", py.get_type::<SoftbodyError>())?;
    m.add("SceneError", py.get_type::<SceneError>())?;
    m.add("UnstableError", py.get_type::<UnstableError>())?;
    m.add("DeviceError", py.get_type::<DeviceError>())?;
    m.add("OutputError", py.get_type::<OutputError>())?;
    m.add_class::<Scene>()?;
    m.add_class::<Simulation>()?;
    m.add_class::<SweepPlan>()?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(grad::gradient, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_local, m)?)?;
    m.add_function(wrap_pyfunction!(run_job, m)?)?;
    Ok(())
}
