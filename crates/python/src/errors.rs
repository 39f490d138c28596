//! The exceptions Python sees (`softbody.SoftbodyError` and its subclasses), and the
//! library's errors turned into them with the CLI's messages.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use softbody::StepError;

create_exception!(
    softbody,
    SoftbodyError,
    PyException,
    "Base class of softbody's errors."
);
create_exception!(
    softbody,
    SceneError,
    SoftbodyError,
    "A scene (or a setting, or a sweep file) that is not valid; the message is the CLI's."
);
create_exception!(
    softbody,
    UnstableError,
    SoftbodyError,
    "The simulation became unstable: `step`, `time`, `particle` say where."
);
create_exception!(
    softbody,
    DeviceError,
    SoftbodyError,
    "No usable GPU adapter, or the device failed."
);
create_exception!(
    softbody,
    OutputError,
    SoftbodyError,
    "A file could not be written (a run's frames, a sweep's manifest)."
);

/// A scene error as Python sees it: the library's message, unchanged.
pub(crate) fn scene_error(e: impl std::fmt::Display) -> PyErr {
    SceneError::new_err(e.to_string())
}

/// A solver error: an instability carries where it happened, and the CLI's advice for
/// `integrator`.
pub(crate) fn step_error(py: Python<'_>, e: StepError, integrator: softbody::Integrator) -> PyErr {
    match e {
        StepError::Unstable(i) => {
            let err = UnstableError::new_err(format!(
                "{i}; {}",
                softbody::Instability::advice(integrator)
            ));
            let value = err.value(py);
            let _ = value.setattr("step", i.step);
            let _ = value.setattr("time", i.time);
            let _ = value.setattr("particle", i.particle);
            err
        }
        StepError::Device(d) | StepError::Invalid(d) => DeviceError::new_err(d),
    }
}

pub(crate) fn open_error(e: softbody::OpenError) -> PyErr {
    match &e {
        softbody::OpenError::Gpu(g) if g.no_usable_gpu() => DeviceError::new_err(e.to_string()),
        softbody::OpenError::Gpu(_) => SceneError::new_err(e.to_string()),
        softbody::OpenError::Threads { .. } => SoftbodyError::new_err(e.to_string()),
    }
}
