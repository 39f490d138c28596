//! Reading a sweep file: its TOML (located errors, as a scene file's), the base scene it names
//! or holds, the run settings, and which of [grid], [[runs]] and [random] plans its runs.

use std::path::Path;

use serde::Deserialize;
use softbody_scene::{Invalid, KeyPath, SceneError};

use super::manifest::Identity;
use super::plan::{Keys, RandomFile, grid_runs, key, parameters, random_runs};
use super::{Metric, Sweep, SweepError, to_settings};
use crate::Backend;
use crate::output::Format;

/// The sweep file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepFile {
    scene: toml::Value,
    format: Option<String>,
    backend: Option<String>,
    threads: Option<usize>,
    metrics: Option<Vec<String>>,
    #[serde(default)]
    set: toml::Table,
    grid: Option<toml::Table>,
    runs: Option<Vec<toml::Table>>,
    random: Option<RandomFile>,
}

impl Sweep {
    /// Reads a sweep file (and its base scene).
    pub fn from_file(path: &Path) -> Result<Sweep, SweepError> {
        let text = std::fs::read_to_string(path).map_err(|cause| SceneError::Io {
            path: path.to_owned(),
            cause,
        })?;
        Sweep::from_toml(&text, path)
    }

    /// Parses sweep text; `origin` names it in messages and anchors the paths in it.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Sweep, SweepError> {
        let located = |key: KeyPath, message: String| -> SweepError {
            SweepError::File(Invalid::new(key, message).locate(origin, text))
        };
        // Located as a scene file's errors are: the same TOML, the same reporting.
        let file: SweepFile = toml::from_str(text)
            .map_err(|e| SweepError::File(softbody_scene::error::from_toml(origin, text, &e)))?;
        let base = origin.parent().unwrap_or(Path::new(""));
        let (scene_text, scene_origin) = match &file.scene {
            toml::Value::String(path) => {
                let path = base.join(path);
                let text = std::fs::read_to_string(&path).map_err(|cause| SceneError::Io {
                    path: path.clone(),
                    cause,
                })?;
                (text, path)
            }
            toml::Value::Table(t) => (
                toml::to_string(t).map_err(|e| located(key("scene"), e.to_string()))?,
                origin.to_owned(),
            ),
            _ => {
                return Err(located(
                    key("scene"),
                    "the base scene is a file name or a [scene] table".into(),
                ));
            }
        };
        let format = match file.format.as_deref() {
            None => Some(Format::Npz),
            Some("none") => None,
            Some(name) => Some(
                name.parse::<Format>()
                    .map_err(|e| located(key("format"), format!("{e}, or none")))?,
            ),
        };
        let backend = match file.backend.as_deref() {
            None => Backend::Cpu,
            Some(name) => name
                .parse()
                .map_err(|e: String| located(key("backend"), e))?,
        };
        let threads = file.threads.unwrap_or(1);
        if threads == 0 {
            return Err(located(key("threads"), "must be at least 1".into()));
        }
        let metrics = match &file.metrics {
            None => Metric::ALL.to_vec(),
            Some(names) => names
                .iter()
                .enumerate()
                .map(|(i, n)| {
                    n.parse::<Metric>()
                        .map_err(|e| located(key("metrics").index(i), e))
                })
                .collect::<Result<_, _>>()?,
        };
        let mut fixed = Keys::default();
        let common = parameters(&file.set, &key("set"), "set", &mut fixed)
            .map_err(|(k, m)| located(k, m))?;

        let kinds = [
            file.grid.is_some(),
            file.runs.is_some(),
            file.random.is_some(),
        ];
        let runs = match (&file.grid, &file.runs, &file.random) {
            _ if kinds.iter().filter(|k| **k).count() != 1 => {
                return Err(located(
                    KeyPath::root(),
                    "a sweep varies its parameters in exactly one of [grid], [[runs]] and \
                     [random]"
                        .into(),
                ));
            }
            (Some(grid), _, _) => grid_runs(grid, fixed).map_err(|(k, m)| located(k, m))?,
            (_, Some(list), _) => list
                .iter()
                .enumerate()
                .map(|(i, t)| parameters(t, &key("runs").index(i), "[[runs]]", &mut fixed.clone()))
                .collect::<Result<_, _>>()
                .map_err(|(k, m)| located(k, m))?,
            (_, _, Some(random)) => random_runs(random, fixed).map_err(|(k, m)| located(k, m))?,
            _ => unreachable!("one kind is present"),
        };
        if runs.is_empty() {
            return Err(located(KeyPath::root(), "the sweep has no runs".into()));
        }
        // The base scene with the common settings must load: a fault there is every run's.
        let (base, base_text) = crate::overrides::parse_with(
            &scene_text,
            &scene_origin,
            &to_settings(&common, &[], &scene_origin)?,
        )?;
        let identity = Identity {
            scene: Identity::scene_fingerprint(&base, &base_text),
            format: format.map(|f| f.name().to_owned()),
            metrics: metrics.iter().map(|m| m.name().to_owned()).collect(),
            backend: backend.name().to_owned(),
            threads,
        };
        Ok(Sweep {
            file: origin.to_owned(),
            scene_text,
            scene_origin,
            common,
            runs,
            format,
            backend,
            threads,
            metrics,
            identity,
        })
    }
}
