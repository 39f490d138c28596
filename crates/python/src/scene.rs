//! `softbody.Scene`: a validated scene from a file, TOML text or a dict, with settings; Python
//! values as TOML values.

use std::path::{Path, PathBuf};

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use softbody::{Setting, toml};

use crate::errors::{SceneError, scene_error};

/// A Python value as a TOML value: bool, int, float, str, lists and tuples, dicts with string
/// keys, NumPy arrays and scalars (through `tolist()` / `item()`), a `Scene` (its text, as a
/// table).
pub(crate) fn to_toml(value: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
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
            Setting::new(&key, to_toml(&v)?)
                .map(|s| s.from_entry("set"))
                .map_err(SceneError::new_err)
        })
        .collect()
}

/// A validated scene and the text it was built from (settings written in).
#[pyclass(frozen, module = "softbody")]
pub(crate) struct Scene {
    pub(crate) scene: softbody::Scene,
    /// The scene's TOML (the file's, or with settings: the document re-written).
    pub(crate) text: String,
    /// Where it came from: messages, and mesh paths relative to it.
    pub(crate) origin: PathBuf,
}

impl Scene {
    fn build(text: &str, origin: &Path, set: Vec<Setting>) -> PyResult<Scene> {
        Scene::parse(text, origin, set).map_err(scene_error)
    }

    fn parse(text: &str, origin: &Path, set: Vec<Setting>) -> Result<Scene, softbody::SceneError> {
        let scene = softbody::scene_from_toml(text, origin, &set)?;
        let text = softbody::scene_text(text, origin, &set)?;
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
        Scene::parse(&text, &origin, settings(set)?).map_err(|e| match e {
            // The TOML is the package's rendering of the dict, which the caller never saw: the
            // key path says where, a line of it would not.
            softbody::SceneError::Invalid(mut d) => {
                (d.line, d.column) = (0, 0);
                d.source_line.clear();
                scene_error(softbody::SceneError::Invalid(d))
            }
            e => scene_error(e),
        })
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
pub(crate) fn scene_of(scene: &Bound<'_, PyAny>) -> PyResult<Py<Scene>> {
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
