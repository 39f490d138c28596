//! Ctrl-C while Rust works: Python runs its signal handlers only on the main thread and only
//! when it holds the GIL, which a step, a run or a sweep has released. So the work goes to a
//! thread of its own while the calling thread wakes every [`POLL`] to run the handlers; a
//! `KeyboardInterrupt` (or any exception a handler raises) sets the work's stop flag, the work
//! ends after its complete frames, and the exception is raised.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

/// How often the calling thread looks for signals: well under a person's patience, well over
/// the cost of taking the GIL (microseconds).
const POLL: Duration = Duration::from_millis(50);

/// Runs `work(stop)` on a thread of its own with the GIL released, checking for signals every
/// [`POLL`]; a signal's exception sets `stop` and is returned once `work` has ended.
pub(crate) fn interruptible<T: Send>(
    py: Python<'_>,
    work: impl FnOnce(&AtomicBool) -> T + Send,
) -> PyResult<T> {
    let stop = AtomicBool::new(false);
    let mut raised = None;
    let caller = std::thread::current();
    let result = std::thread::scope(|scope| -> PyResult<T> {
        let worker = std::thread::Builder::new()
            .name("softbody".into())
            .spawn_scoped(scope, || {
                let result = work(&stop);
                // The caller need not sleep out its poll once the work is done.
                caller.unpark();
                result
            })
            .map_err(|e| PyOSError::new_err(format!("cannot start a thread: {e}")))?;
        while !worker.is_finished() {
            py.detach(|| std::thread::park_timeout(POLL));
            if raised.is_none()
                && let Err(e) = py.check_signals()
            {
                stop.store(true, Ordering::Relaxed);
                raised = Some(e);
            }
        }
        worker
            .join()
            .map_err(|_| PyRuntimeError::new_err("the work panicked"))
    })?;
    match raised {
        Some(e) => Err(e),
        None => Ok(result),
    }
}

/// A count given from Python (`threads`, `workers`, `n`): a whole number at least `min`, said
/// in Python's terms (`ValueError`) rather than as an `OverflowError` of a negative number.
pub(crate) fn count(name: &str, value: i64, min: i64) -> PyResult<usize> {
    if value < min {
        return Err(PyValueError::new_err(format!(
            "{name} must be at least {min}, not {value}"
        )));
    }
    usize::try_from(value)
        .map_err(|_| PyValueError::new_err(format!("{name} is too large: {value}")))
}

/// An optional count (`None` keeps the default).
pub(crate) fn count_or_none(name: &str, value: Option<i64>, min: i64) -> PyResult<Option<usize>> {
    value.map(|v| count(name, v, min)).transpose()
}
