//! `gradient`: the gradient of a run's loss with respect to scene keys (the library's
//! `softbody::grad`), for the built-in losses or any loss given by its cotangents.

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use softbody::glam::DVec3;
use softbody::grad::{Derivative, GradError, GradReport, GradRequest, Target};

use crate::errors::{SceneError, SoftbodyError, UnstableError};
use crate::interrupt::{count_or_none, interruptible};
use crate::scene::scene_of;

/// [F, N, 3] float64 values from any array-like, frame-major.
pub(crate) fn frame_vectors(value: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<Vec<DVec3>> {
    let Some(value) = value else {
        return Ok(Vec::new());
    };
    let np = value.py().import("numpy")?;
    let array = np.call_method1("ascontiguousarray", (value, "float64"))?;
    let array: PyReadonlyArray3<f64> = array.extract().map_err(|_| {
        PyValueError::new_err(format!("{what} must be an [F, N, 3] array of numbers"))
    })?;
    if array.shape()[2] != 3 {
        return Err(PyValueError::new_err(format!(
            "{what} must have the shape [F, N, 3], not {:?}",
            array.shape()
        )));
    }
    Ok(array
        .as_slice()?
        .chunks_exact(3)
        .map(|c| DVec3::new(c[0], c[1], c[2]))
        .collect())
}

fn vectors<'py>(py: Python<'py>, v: &[DVec3]) -> Bound<'py, PyAny> {
    let flat: Vec<f64> = v.iter().flat_map(|p| p.to_array()).collect();
    Array2::from_shape_vec((v.len(), 3), flat)
        .expect("3 per vector")
        .into_pyarray(py)
        .into_any()
}

fn grad_error(e: GradError) -> PyErr {
    match e {
        GradError::Input(_) | GradError::Scene(_) => SceneError::new_err(e.to_string()),
        GradError::Unstable(_) => UnstableError::new_err(e.to_string()),
        e => SoftbodyError::new_err(e.to_string()),
    }
}

fn report_dict<'py>(
    py: Python<'py>,
    report: GradReport,
    loss: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("loss", loss.then_some(report.loss))?;
    let gradient = PyDict::new(py);
    for (key, value) in &report.gradient {
        match value {
            Derivative::Scalar(x) => gradient.set_item(key, *x)?,
            Derivative::Vector(v) => {
                gradient.set_item(key, Array1::from(v.to_array().to_vec()).into_pyarray(py))?
            }
        }
    }
    d.set_item("gradient", gradient)?;
    let b = report.backward;
    d.set_item("positions", vectors(py, &b.x0))?;
    d.set_item("velocities", vectors(py, &b.v0))?;
    d.set_item("masses", Array1::from(report.mass).into_pyarray(py))?;
    d.set_item(
        "stiffness",
        Array1::from(b.gradient.stiffness).into_pyarray(py),
    )?;
    d.set_item("damping", Array1::from(b.gradient.damping).into_pyarray(py))?;
    let n = b.x0.len();
    let controls = (!b.controls.is_empty()).then(|| {
        let flat: Vec<f64> = b.controls.iter().flat_map(|u| u.to_array()).collect();
        Array3::from_shape_vec((flat.len() / (3 * n), n, 3), flat)
            .expect("F × N forces")
            .into_pyarray(py)
    });
    d.set_item("controls", controls)?;
    d.set_item("steps", b.steps)?;
    d.set_item("peak_memory_bytes", b.peak_memory_bytes)?;
    d.set_item("forward_seconds", b.forward_seconds)?;
    d.set_item("backward_seconds", b.backward_seconds)?;
    d.set_item("turned_steps", b.turned_steps)?;
    Ok(d)
}

/// The gradient of a loss over the run of `scene` with respect to `wrt` (keys as `--set`
/// names them), on the CPU in f64, the GIL released meanwhile; Ctrl-C raises
/// KeyboardInterrupt at the next checkpoint segment. The loss is one of `target_com`,
/// `target_frames` (a path), or the cotangents `positions` / `velocities` ([F, N, 3]) of any;
/// `controls` ([F, N, 3]) are the run's control forces, whose gradient comes back too.
#[pyfunction]
#[pyo3(signature = (scene, wrt, target_com = None, target_frames = None, positions = None, velocities = None, controls = None, threads = None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn gradient<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyAny>,
    wrt: Vec<String>,
    target_com: Option<[f64; 3]>,
    target_frames: Option<std::path::PathBuf>,
    positions: Option<&Bound<'py, PyAny>>,
    velocities: Option<&Bound<'py, PyAny>>,
    controls: Option<&Bound<'py, PyAny>>,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    let scene = scene_of(scene)?;
    let controls = controls
        .map(|u| frame_vectors(Some(u), "controls"))
        .transpose()?
        .map(Into::into);
    let threads = count_or_none("threads", threads, 1)?;
    let cotangent = positions.is_some() || velocities.is_some();
    let target = match (target_com, target_frames, cotangent) {
        (Some(c), None, false) => Target::Com(DVec3::from_array(c)),
        (None, Some(f), false) => Target::Frames(f),
        (None, None, true) => Target::Cotangents {
            positions: frame_vectors(positions, "positions")?,
            velocities: frame_vectors(velocities, "velocities")?,
        },
        _ => {
            return Err(PyValueError::new_err(
                "give one loss: target_com, target_frames, or the cotangents positions / velocities",
            ));
        }
    };
    let s = scene.get();
    let request = GradRequest {
        scene: s.origin.clone(),
        text: Some(s.text.clone()),
        wrt,
        target,
        threads,
        controls,
        ..GradRequest::default()
    };
    let result = interruptible(py, |stop| {
        softbody::grad::gradient_until(&request, Some(stop))
    })?;
    report_dict(py, result.map_err(grad_error)?, !cotangent)
}
