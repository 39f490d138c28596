//! `softbody.Simulation`: a scene stepped on a backend, its state as NumPy arrays.

use std::sync::Mutex;
use std::time::{Duration, Instant};

use numpy::ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use softbody::glam::DVec3;
use softbody::{Backend, Solver, StepError};

use crate::errors::{open_error, step_error};
use crate::interrupt::{count, count_or_none};
use crate::scene::{Scene, scene_of};

pub(crate) fn backend_of(name: &str) -> PyResult<Backend> {
    name.parse().map_err(PyValueError::new_err)
}

/// Positions or velocities as an [N, 3] float64 array: one copy, handed to NumPy as is.
fn vectors<'py>(py: Python<'py>, v: &[DVec3]) -> Bound<'py, PyAny> {
    let flat: Vec<f64> = v.iter().flat_map(|p| p.to_array()).collect();
    Array2::from_shape_vec((v.len(), 3), flat)
        .expect("3 per vector")
        .into_pyarray(py)
        .into_any()
}

/// [N, 3] float64 values from any array-like.
fn vectors_from(value: &Bound<'_, PyAny>, n: usize, what: &str) -> PyResult<Vec<DVec3>> {
    let np = value.py().import("numpy")?;
    let array = np.call_method1("ascontiguousarray", (value, "float64"))?;
    let array: PyReadonlyArray2<f64> = array
        .extract()
        .map_err(|_| PyValueError::new_err(format!("{what} must be an [N, 3] array of numbers")))?;
    if array.shape() != [n, 3] {
        return Err(PyValueError::new_err(format!(
            "{what} must have the shape [{n}, 3], not {:?}",
            array.shape()
        )));
    }
    let flat = array.as_slice()?;
    Ok(flat
        .chunks_exact(3)
        .map(|c| DVec3::new(c[0], c[1], c[2]))
        .collect())
}

/// Why `step` stopped early.
enum Halt {
    Step(StepError),
    Signal(PyErr),
}

/// A scene being stepped on a backend.
#[pyclass(module = "softbody")]
pub(crate) struct Simulation {
    solver: Mutex<Box<dyn Solver>>,
    scene: Py<Scene>,
    dt: f64,
    particles: usize,
    integrator: softbody::Integrator,
}

impl Simulation {
    /// Runs `f` on the solver with the GIL released (the lock is taken there: see the module
    /// doc).
    fn with<T: Send>(&self, py: Python<'_>, f: impl FnOnce(&mut dyn Solver) -> T + Send) -> T {
        py.detach(|| {
            let mut solver = self.solver.lock().unwrap_or_else(|e| e.into_inner());
            f(solver.as_mut())
        })
    }
}

#[pymethods]
impl Simulation {
    /// Opens `scene` (a Scene, a path or a dict) on `backend` ("cpu": f64, all cores or
    /// `threads`; "gpu": wgpu, f32).
    #[new]
    #[pyo3(signature = (scene, backend = "cpu", threads = None))]
    fn new(
        py: Python<'_>,
        scene: &Bound<'_, PyAny>,
        backend: &str,
        threads: Option<i64>,
    ) -> PyResult<Simulation> {
        let scene = scene_of(scene)?;
        let backend = backend_of(backend)?;
        let threads = count_or_none("threads", threads, 1)?;
        let s = &scene.get().scene;
        let solver = py
            .detach(|| softbody::open(s, backend, threads))
            .map_err(open_error)?;
        let (dt, particles) = (s.simulation.dt, solver.model().len());
        Ok(Simulation {
            solver: Mutex::new(solver),
            dt,
            particles,
            integrator: s.simulation.integrator,
            scene,
        })
    }

    /// Takes `n` steps (the GIL released meanwhile). Raises UnstableError where the state
    /// stops being finite, and KeyboardInterrupt on Ctrl-C after a whole number of steps
    /// (`steps` says how many were taken).
    #[pyo3(signature = (n = 1))]
    fn step(&self, py: Python<'_>, n: i64) -> PyResult<()> {
        // In chunks that grow to ~CHUNK of work, the signals checked between them: no thread
        // of its own (as `interruptible` takes), since `step(1)` in a loop must stay cheap.
        // Stepping in chunks is stepping: the solvers advance one step at a time.
        const CHUNK: Duration = Duration::from_millis(20);
        let mut left = count("n", n, 0)? as u64;
        let halted = self.with(py, |s| -> Result<(), Halt> {
            let mut chunk = 1u64;
            while left > 0 {
                let k = chunk.min(left);
                let started = Instant::now();
                s.advance(k).map_err(Halt::Step)?;
                left -= k;
                if left > 0 {
                    if let Err(e) = Python::attach(|py| py.check_signals()) {
                        let _ = s.sync();
                        return Err(Halt::Signal(e));
                    }
                    if started.elapsed() < CHUNK {
                        chunk = chunk.saturating_mul(2);
                    }
                }
            }
            s.sync().map_err(Halt::Step)
        });
        match halted {
            Ok(()) => Ok(()),
            Err(Halt::Step(e)) => Err(step_error(py, e, self.integrator)),
            Err(Halt::Signal(e)) => Err(e),
        }
    }

    /// Positions, [N, 3] float64, m: a snapshot (later steps do not change it).
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let x = self
            .with(py, |s| s.state().map(|st| st.x.clone()))
            .map_err(|e| step_error(py, e, self.integrator))?;
        Ok(vectors(py, &x))
    }

    /// Velocities, [N, 3] float64, m/s: a snapshot.
    #[getter]
    fn velocities<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let v = self
            .with(py, |s| s.state().map(|st| st.v.clone()))
            .map_err(|e| step_error(py, e, self.integrator))?;
        Ok(vectors(py, &v))
    }

    /// Replaces the state: positions [N, 3] and velocities [N, 3] (default: the current ones).
    #[pyo3(signature = (positions, velocities = None))]
    fn set_state(
        &self,
        py: Python<'_>,
        positions: &Bound<'_, PyAny>,
        velocities: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let x = vectors_from(positions, self.particles, "positions")?;
        let v = velocities
            .map(|v| vectors_from(v, self.particles, "velocities"))
            .transpose()?;
        for (what, values) in [("positions", Some(&x)), ("velocities", v.as_ref())] {
            if let Some(i) = values.and_then(|v| v.iter().position(|p| !p.is_finite())) {
                return Err(PyValueError::new_err(format!(
                    "{what}[{i}] is not finite: {}",
                    values.expect("found in it")[i]
                )));
            }
        }
        // Finite values whose energy is not (|x| near 1e300 in a spring's square) would make
        // the next step's instability look like dt's fault: refused here, the state kept.
        self.with(py, |s| {
            let old = s.state()?.clone();
            let mut state = old.clone();
            state.x = x;
            if let Some(v) = v {
                state.v = v;
            }
            s.set_state(&state)?;
            let e = s.energies()?;
            if e.total().is_finite() {
                return Ok(Ok(()));
            }
            s.set_state(&old)?;
            Ok(Err(PyValueError::new_err(format!(
                "the state's energy is not a finite number (kinetic {:e} J, gravitational {:e} \
                 J, elastic {:e} J): positions or velocities too large",
                e.kinetic, e.gravitational, e.elastic
            ))))
        })
        .map_err(|e| match e {
            // The GPU refuses values past f32's range: the caller's values, not the device.
            StepError::Invalid(why) => PyValueError::new_err(why),
            e => step_error(py, e, self.integrator),
        })?
    }

    /// Energies now, J: {"kinetic", "gravitational", "elastic", "total"}.
    fn energies<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let e = self
            .with(py, |s| s.energies())
            .map_err(|e| step_error(py, e, self.integrator))?;
        let d = PyDict::new(py);
        d.set_item("kinetic", e.kinetic)?;
        d.set_item("gravitational", e.gravitational)?;
        d.set_item("elastic", e.elastic)?;
        d.set_item("total", e.total())?;
        Ok(d)
    }

    /// Steps taken.
    #[getter]
    fn steps(&self, py: Python<'_>) -> u64 {
        self.with(py, |s| s.steps_taken())
    }

    /// Simulated time, s (steps × dt).
    #[getter]
    fn time(&self, py: Python<'_>) -> f64 {
        self.steps(py) as f64 * self.dt
    }

    /// Time step, s.
    #[getter]
    fn dt(&self) -> f64 {
        self.dt
    }

    /// The scene.
    #[getter]
    fn scene(&self, py: Python<'_>) -> Py<Scene> {
        self.scene.clone_ref(py)
    }

    /// "cpu" or "gpu".
    #[getter]
    fn backend(&self, py: Python<'_>) -> &'static str {
        self.with(py, |s| s.backend())
    }

    /// What runs it ("CPU, 2 threads", the adapter).
    #[getter]
    fn device(&self, py: Python<'_>) -> String {
        self.with(py, |s| s.device())
    }

    /// Particle masses, [N] float64, kg.
    #[getter]
    fn masses<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let m = self.with(py, |s| s.model().mass.clone());
        Array1::from(m).into_pyarray(py).into_any()
    }

    /// The particles each spring joins, [S, 2] uint32.
    #[getter]
    fn springs<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let pairs = self.with(py, |s| s.model().springs().pairs());
        pairs_array(py, &pairs)
    }

    /// Rest lengths, [S] float64, m.
    #[getter]
    fn rest_lengths<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let r = self.with(py, |s| s.model().springs().rest.clone());
        Array1::from(r).into_pyarray(py).into_any()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "<softbody.Simulation {} particles on {}, t = {} s>",
            self.particles,
            self.device(py),
            self.time(py)
        )
    }
}

pub(crate) fn pairs_array<'py>(py: Python<'py>, pairs: &[[u32; 2]]) -> Bound<'py, PyAny> {
    let flat: Vec<u32> = pairs.iter().flatten().copied().collect();
    Array2::from_shape_vec((pairs.len(), 2), flat)
        .expect("2 per spring")
        .into_pyarray(py)
        .into_any()
}
