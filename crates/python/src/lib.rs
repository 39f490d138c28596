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

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use softbody::glam::DVec3;
use softbody::output::{Frame, FrameSink, Header};
use softbody::run::RunError;
use softbody::service::{self, ExitClass, Hooks, RunFailure, RunRequest, SceneSource};
use softbody::sweep::{Job, Manifest, Options, Record, Sweep};
use softbody::{Backend, Setting, Solver, StepError, toml};

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
fn scene_error(e: impl std::fmt::Display) -> PyErr {
    SceneError::new_err(e.to_string())
}

/// A solver error: an instability carries where it happened, and the CLI's advice for
/// `integrator`.
fn step_error(py: Python<'_>, e: StepError, integrator: softbody::Integrator) -> PyErr {
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

fn open_error(e: softbody::OpenError) -> PyErr {
    match &e {
        softbody::OpenError::Gpu(g) if g.no_usable_gpu() => DeviceError::new_err(e.to_string()),
        softbody::OpenError::Gpu(_) => SceneError::new_err(e.to_string()),
        softbody::OpenError::Threads { .. } => SoftbodyError::new_err(e.to_string()),
    }
}

/// A Python value as a TOML value: bool, int, float, str, lists and tuples, dicts with string
/// keys, NumPy arrays and scalars (through `tolist()` / `item()`), a `Scene` (its text, as a
/// table).
fn to_toml(value: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        return Ok(toml::Value::Integer(value.extract()?));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if value.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(value.extract()?));
    }
    if let Ok(scene) = value.cast::<Scene>() {
        let table: toml::Table = scene.get().text.parse().map_err(scene_error)?;
        return Ok(toml::Value::Table(table));
    }
    if let Ok(dict) = value.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in dict.iter() {
            let key: String = k.extract().map_err(|_| {
                PyTypeError::new_err(format!("a table's keys are strings, not {k}"))
            })?;
            table.insert(key, to_toml(&v)?);
        }
        return Ok(toml::Value::Table(table));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items: Vec<toml::Value> = value
            .try_iter()?
            .map(|v| to_toml(&v?))
            .collect::<PyResult<_>>()?;
        return Ok(toml::Value::Array(items));
    }
    // NumPy arrays and scalars (np.float32(1), np.int64(2), np.array([...])).
    for method in ["tolist", "item"] {
        if value.hasattr(method)? {
            let plain = value.call_method0(method)?;
            if !plain.is(value) {
                return to_toml(&plain);
            }
        }
    }
    Err(PyTypeError::new_err(format!(
        "{} has no TOML value (bool, int, float, str, list, dict)",
        value.repr()?
    )))
}

/// `{"body[0].mass": 2.0, ...}` as settings.
fn settings(set: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<Setting>> {
    let Some(set) = set else {
        return Ok(Vec::new());
    };
    set.iter()
        .map(|(k, v)| {
            let key: String = k.extract()?;
            Setting::new(&key, to_toml(&v)?).map_err(SceneError::new_err)
        })
        .collect()
}

/// A validated scene and the text it was built from (settings written in).
#[pyclass(frozen, module = "softbody")]
struct Scene {
    scene: softbody::Scene,
    /// The scene's TOML (the file's, or with settings: the document re-written).
    text: String,
    /// Where it came from: messages, and mesh paths relative to it.
    origin: PathBuf,
}

impl Scene {
    fn build(text: &str, origin: &Path, set: Vec<Setting>) -> PyResult<Scene> {
        let scene = softbody::scene_from_toml(text, origin, &set).map_err(scene_error)?;
        let text = softbody::scene_text(text, origin, &set).map_err(scene_error)?;
        Ok(Scene {
            scene,
            text,
            origin: origin.to_owned(),
        })
    }
}

#[pymethods]
impl Scene {
    /// Loads a scene file, `set` applied (`{"body[0].mass": 2.0}`, key paths as `--set`).
    #[staticmethod]
    #[pyo3(signature = (path, *, set = None))]
    fn from_file(path: PathBuf, set: Option<&Bound<'_, PyDict>>) -> PyResult<Scene> {
        let text = std::fs::read_to_string(&path)
            .map_err(|e| SceneError::new_err(format!("{}: cannot read: {e}", path.display())))?;
        Scene::build(&text, &path, settings(set)?)
    }

    /// Parses scene TOML; `origin` names it in messages and anchors mesh paths.
    #[staticmethod]
    #[pyo3(signature = (text, *, origin = None, set = None))]
    fn from_toml(
        text: &str,
        origin: Option<PathBuf>,
        set: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Scene> {
        let origin = origin.unwrap_or_else(|| PathBuf::from("<string>"));
        Scene::build(text, &origin, settings(set)?)
    }

    /// A scene from a dict laid out as the TOML file (`{"simulation": {...}, "body": [...]}`).
    #[staticmethod]
    #[pyo3(signature = (table, *, origin = None, set = None))]
    fn from_dict(
        table: &Bound<'_, PyDict>,
        origin: Option<PathBuf>,
        set: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Scene> {
        let value = to_toml(table.as_any())?;
        let text = toml::to_string(&value).map_err(scene_error)?;
        let origin = origin.unwrap_or_else(|| PathBuf::from("<dict>"));
        Scene::build(&text, &origin, settings(set)?)
    }

    /// This scene with more settings applied.
    fn with_settings(&self, set: &Bound<'_, PyDict>) -> PyResult<Scene> {
        Scene::build(&self.text, &self.origin, settings(Some(set))?)
    }

    /// The scene's TOML text (settings written in).
    #[getter]
    fn text(&self) -> &str {
        &self.text
    }

    /// Where the scene came from.
    #[getter]
    fn origin(&self) -> PathBuf {
        self.origin.clone()
    }

    /// Number of particles N.
    #[getter]
    fn particles(&self) -> u64 {
        self.scene.particle_count()
    }

    /// Number of springs S.
    #[getter]
    fn springs(&self) -> u64 {
        self.scene.spring_counts().total()
    }

    /// Total mass, kg.
    #[getter]
    fn total_mass(&self) -> f64 {
        self.scene.total_mass()
    }

    /// Time step, s.
    #[getter]
    fn dt(&self) -> f64 {
        self.scene.simulation.dt
    }

    /// Simulated time of a run, s.
    #[getter]
    fn duration(&self) -> f64 {
        self.scene.simulation.duration
    }

    /// Frames per simulated second.
    #[getter]
    fn frame_rate(&self) -> f64 {
        self.scene.simulation.frame_rate
    }

    /// The integrator's name.
    #[getter]
    fn integrator(&self) -> &'static str {
        self.scene.simulation.integrator.name()
    }

    /// Steps of a run.
    #[getter]
    fn steps(&self) -> u64 {
        self.scene.simulation.steps()
    }

    /// Frames of a run.
    #[getter]
    fn frames(&self) -> u64 {
        self.scene.simulation.frame_count()
    }

    fn __repr__(&self) -> String {
        format!(
            "<softbody.Scene {}: {} particles, {} springs, {} at dt = {} s for {} s>",
            self.origin.display(),
            self.particles(),
            self.springs(),
            self.integrator(),
            self.dt(),
            self.duration()
        )
    }
}

/// A scene argument: a `Scene`, a path, or a dict.
fn scene_of(scene: &Bound<'_, PyAny>) -> PyResult<Py<Scene>> {
    if let Ok(s) = scene.cast::<Scene>() {
        return Ok(s.clone().unbind());
    }
    let py = scene.py();
    let built = if let Ok(dict) = scene.cast::<PyDict>() {
        Scene::from_dict(dict, None, None)?
    } else if let Ok(path) = scene.extract::<PathBuf>() {
        Scene::from_file(path, None)?
    } else {
        return Err(PyTypeError::new_err(
            "a scene is a softbody.Scene, a path to a scene file, or a dict",
        ));
    };
    Py::new(py, built)
}

fn backend_of(name: &str) -> PyResult<Backend> {
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

/// A scene being stepped on a backend.
#[pyclass(module = "softbody")]
struct Simulation {
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
        threads: Option<usize>,
    ) -> PyResult<Simulation> {
        let scene = scene_of(scene)?;
        let backend = backend_of(backend)?;
        if threads == Some(0) {
            return Err(PyValueError::new_err("threads must be at least 1"));
        }
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
    /// stops being finite.
    #[pyo3(signature = (n = 1))]
    fn step(&self, py: Python<'_>, n: u64) -> PyResult<()> {
        self.with(py, |s| s.advance(n).and_then(|()| s.sync()))
            .map_err(|e| step_error(py, e, self.integrator))
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
        self.with(py, |s| {
            let mut state = s.state()?.clone();
            state.x = x;
            if let Some(v) = v {
                state.v = v;
            }
            s.set_state(&state)
        })
        .map_err(|e| step_error(py, e, self.integrator))
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

fn pairs_array<'py>(py: Python<'py>, pairs: &[[u32; 2]]) -> Bound<'py, PyAny> {
    let flat: Vec<u32> = pairs.iter().flatten().copied().collect();
    Array2::from_shape_vec((pairs.len(), 2), flat)
        .expect("2 per spring")
        .into_pyarray(py)
        .into_any()
}

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

/// Runs `scene` to its end and returns its frames as a dict (the GIL released meanwhile).
/// An instability raises UnstableError with the frames before it as `.trajectory`.
#[pyfunction]
#[pyo3(signature = (scene, backend = "cpu", threads = None))]
fn run<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyAny>,
    backend: &str,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let scene = scene_of(scene)?;
    let backend = backend_of(backend)?;
    let s = scene.get();
    let request = RunRequest {
        scene: SceneSource::Text {
            text: s.text.clone(),
            origin: s.origin.clone(),
        },
        backend,
        threads,
        ..RunRequest::file(&s.origin)
    };
    let (outcome, collect) = py.detach(|| {
        let mut collect = Collect::default();
        let hooks = Hooks {
            observer: Some(&mut collect),
            ..Hooks::default()
        };
        (service::execute(&request, hooks), collect)
    });
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
fn sweep_local<'py>(
    py: Python<'py>,
    sweep: &Bound<'py, PyAny>,
    out: PathBuf,
    workers: Option<usize>,
    task_index: Option<usize>,
    task_count: Option<usize>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let sweep = sweep_of(sweep)?;
    let options = Options {
        workers,
        task: task_index.map(|i| (i, task_count.unwrap_or(1).max(1))),
    };
    let report = |done: usize, total: usize| {
        if let Some(cb) = &progress {
            Python::attach(|py| {
                if let Err(e) = cb.call1(py, (done, total)) {
                    e.print(py);
                }
            });
        }
    };
    py.detach(|| softbody::sweep::run_local(&sweep, &out, &options, &report))
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
struct SweepPlan {
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
fn run_job(py: Python<'_>, job: &str, output: Option<PathBuf>) -> PyResult<String> {
    let mut job: Job =
        serde_json::from_str(job).map_err(|e| SceneError::new_err(format!("not a job: {e}")))?;
    if output.is_some() {
        job.output = output;
    }
    let record = py.detach(|| job.run());
    serde_json::to_string(&record).map_err(|e| SoftbodyError::new_err(e.to_string()))
}

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
    m.add_function(wrap_pyfunction!(sweep_local, m)?)?;
    m.add_function(wrap_pyfunction!(run_job, m)?)?;
    Ok(())
}
