//! `softbody.run`: a whole run, its frames collected into a trajectory (a dict of NumPy arrays
//! named as the NPZ output names them).

use numpy::IntoPyArray;
use numpy::ndarray::{Array1, Array3};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use softbody::StepError;
use softbody::output::{Frame, FrameSink, Header};
use softbody::run::RunError;
use softbody::service::{self, ExitClass, Hooks, RunFailure, RunRequest, SceneSource};

use crate::errors::{DeviceError, SceneError, SoftbodyError, open_error, step_error};
use crate::grad::frame_vectors;
use crate::interrupt::{count_or_none, interruptible};
use crate::scene::scene_of;
use crate::simulation::{backend_of, pairs_array};

/// A run's frames collected in memory, for `run`.
#[derive(Default)]
struct Collect {
    header: Option<Header>,
    time: Vec<f64>,
    positions: Vec<f64>,
    velocities: Vec<f64>,
    energies: [Vec<f64>; 3],
}

impl FrameSink for Collect {
    fn header(&mut self, header: &Header) -> std::io::Result<()> {
        self.take_header(header.clone())
    }
    fn take_header(&mut self, header: Header) -> std::io::Result<()> {
        self.header = Some(header);
        Ok(())
    }
    fn frame(&mut self, f: &Frame<'_>) -> std::io::Result<()> {
        self.time.push(f.time);
        self.positions
            .extend(f.positions.iter().flat_map(|p| p.to_array()));
        self.velocities
            .extend(f.velocities.iter().flat_map(|v| v.to_array()));
        let e = f.energies;
        for (s, x) in self
            .energies
            .iter_mut()
            .zip([e.kinetic, e.gravitational, e.elastic])
        {
            s.push(x);
        }
        Ok(())
    }
    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Collect {
    /// The frames and the run's metadata as a dict of NumPy arrays and values, named as the
    /// NPZ output names them.
    fn into_dict<'py>(self, py: Python<'py>, scene_text: &str) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let header = self
            .header
            .ok_or_else(|| SoftbodyError::new_err("the run wrote no header"))?;
        let (f, n) = (self.time.len(), header.particles);
        let frames = |v: Vec<f64>| {
            Array3::from_shape_vec((f, n, 3), v)
                .expect("3 per particle per frame")
                .into_pyarray(py)
        };
        d.set_item("time", Array1::from(self.time).into_pyarray(py))?;
        d.set_item("positions", frames(self.positions))?;
        d.set_item("velocities", frames(self.velocities))?;
        let [kinetic, gravitational, elastic] = self.energies;
        d.set_item("energy_kinetic", Array1::from(kinetic).into_pyarray(py))?;
        d.set_item(
            "energy_gravitational",
            Array1::from(gravitational).into_pyarray(py),
        )?;
        d.set_item("energy_elastic", Array1::from(elastic).into_pyarray(py))?;
        d.set_item("dt", header.dt)?;
        d.set_item("frame_rate", header.frame_rate)?;
        d.set_item("integrator", &header.integrator)?;
        d.set_item("backend", &header.backend)?;
        d.set_item("device", &header.device)?;
        d.set_item("masses", Array1::from(header.masses).into_pyarray(py))?;
        d.set_item("springs", pairs_array(py, &header.springs))?;
        d.set_item("rest_lengths", Array1::from(header.rest).into_pyarray(py))?;
        d.set_item("stiffness", Array1::from(header.stiffness).into_pyarray(py))?;
        d.set_item("damping", Array1::from(header.damping).into_pyarray(py))?;
        let bodies = PyList::empty(py);
        for b in &header.bodies {
            bodies.append((b.name.as_str(), b.first, b.count))?;
        }
        d.set_item("bodies", bodies)?;
        d.set_item("scene_text", scene_text)?;
        Ok(d)
    }
}

/// Runs `scene` to its end and returns its frames as a dict (the GIL released meanwhile),
/// with `controls` ([F, N, 3] forces, frame f's held over its steps; the CPU backend) if
/// given. An instability raises UnstableError with the frames before it as `.trajectory`;
/// Ctrl-C raises KeyboardInterrupt.
#[pyfunction]
#[pyo3(signature = (scene, backend = "cpu", threads = None, controls = None))]
pub(crate) fn run<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyAny>,
    backend: &str,
    threads: Option<i64>,
    controls: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let scene = scene_of(scene)?;
    let backend = backend_of(backend)?;
    let threads = count_or_none("threads", threads, 1)?;
    let controls = controls
        .map(|u| frame_vectors(Some(u), "controls"))
        .transpose()?;
    let s = scene.get();
    let request = RunRequest {
        scene: SceneSource::Text {
            text: s.text.clone(),
            origin: s.origin.clone(),
        },
        backend,
        threads,
        controls: controls.map(Into::into),
        ..RunRequest::file(&s.origin)
    };
    let (outcome, collect) = interruptible(py, |stop| {
        let mut collect = Collect::default();
        let hooks = Hooks {
            observer: Some(&mut collect),
            stop: Some(stop),
            ..Hooks::default()
        };
        (service::execute(&request, hooks), collect)
    })?;
    match outcome.result {
        Ok(_) => collect.into_dict(py, &s.text),
        Err(RunFailure::Open(open)) => Err(open_error(open)),
        Err(RunFailure::Run(RunError::Unstable(i))) => {
            let err = step_error(py, StepError::Unstable(i), s.scene.simulation.integrator);
            if collect.header.is_some() {
                err.value(py)
                    .setattr("trajectory", collect.into_dict(py, &s.text)?)?;
            }
            Err(err)
        }
        Err(e) if e.class() == ExitClass::BadInput => Err(SceneError::new_err(e.to_string())),
        Err(e) => Err(DeviceError::new_err(e.to_string())),
    }
}
