//! One run of a sweep as a self-contained [`Job`], and the [`Record`] it turns into.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value as Json};

use super::metrics::Accumulator;
use super::{Metric, Parameters, to_settings};
use crate::Backend;
use crate::output::Format;
use crate::service::{self, Destination, ExitClass, Hooks, RunRequest, SceneSource};

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Every frame written.
    Ok,
    /// The simulation became unstable; the frames before it are written (exit status 3).
    Unstable,
    /// The scene refused these parameters (exit status 2); nothing written.
    Invalid,
    /// The output could not be written (1) or the device failed (4): worth running again.
    Failed,
}

impl Status {
    /// Whether a sweep run again skips the run: the same values would give the same outcome.
    pub fn finished(self) -> bool {
        self != Status::Failed
    }
}

/// One line of the manifest: what a run was and how it ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// The run's number in the plan.
    pub run: usize,
    /// Its parameters, `key path: value`.
    pub parameters: Map<String, Json>,
    /// How it ended.
    pub status: Status,
    /// The exit status `softbody run` would have given it (0, 1, 2, 3 or 4).
    pub exit_status: u8,
    /// The error's message, when it did not end `ok`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The metrics asked for, by name (null where there were no frames).
    pub metrics: Map<String, Json>,
    /// Its frames, relative to the out directory (null without output or when nothing was
    /// written).
    pub file: Option<String>,
    /// Wall time of the run, s.
    pub seconds: f64,
}

/// One run of a sweep, self-contained: serialise it (JSON) to run it elsewhere.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Job {
    /// The run's number in the plan.
    pub run: usize,
    /// The base scene's text.
    pub scene_text: String,
    /// Where it came from (messages; mesh paths are relative to it).
    pub scene_origin: PathBuf,
    /// Settings of every run, applied first.
    pub common: Parameters,
    /// This run's parameters.
    pub parameters: Parameters,
    /// Where its frames go; `None`: metrics only.
    pub output: Option<PathBuf>,
    /// The output's name in the record (relative to the out directory).
    pub file: Option<String>,
    /// Output format name.
    pub format: Option<String>,
    /// Metrics to compute.
    pub metrics: Vec<Metric>,
    /// `cpu` or `gpu`.
    pub backend: String,
    /// Solver threads.
    pub threads: usize,
}

impl Job {
    /// The parameters as the manifest lists them.
    pub fn parameter_map(&self) -> Map<String, Json> {
        parameter_map(&self.parameters)
    }

    /// Runs the job: its frames to its output, its record returned. Never panics on a bad
    /// scene or value: those are records too.
    pub fn run(&self) -> Record {
        self.run_until(None).expect("nothing stops it")
    }

    /// [`Job::run`], stopped after its complete frames when `stop` is set: then `None`, no
    /// record (the run is not an outcome of its values).
    pub fn run_until(&self, stop: Option<&AtomicBool>) -> Option<Record> {
        let started = Instant::now();
        let mut record = Record {
            run: self.run,
            parameters: self.parameter_map(),
            status: Status::Ok,
            exit_status: 0,
            error: None,
            metrics: Map::new(),
            file: None,
            seconds: 0.0,
        };
        let end = |mut record: Record, status: Status, exit: u8, error: String| {
            // Every record names every metric (no frames: 0 frames, the rest null), so the
            // manifest reads as one table.
            if record.metrics.is_empty() {
                let none = Accumulator::default();
                record.metrics = self
                    .metrics
                    .iter()
                    .map(|m| (m.name().to_owned(), none.value(*m)))
                    .collect();
            }
            record.status = status;
            record.exit_status = exit;
            record.error = Some(error);
            record.seconds = started.elapsed().as_secs_f64();
            record
        };
        let origin = &self.scene_origin;
        let settings = match to_settings(&self.common, &self.parameters, origin) {
            Ok(s) => s,
            Err(e) => return Some(end(record, Status::Invalid, 2, e.to_string())),
        };
        let (backend, format) = match (
            self.backend.parse::<Backend>(),
            self.format.as_deref().map(str::parse::<Format>).transpose(),
        ) {
            (Ok(b), Ok(f)) => (b, f),
            (Err(e), _) | (_, Err(e)) => return Some(end(record, Status::Invalid, 2, e)),
        };
        let request = RunRequest {
            scene: SceneSource::Text {
                text: self.scene_text.clone(),
                origin: origin.clone(),
            },
            settings,
            backend,
            threads: Some(self.threads),
            destination: match (format, &self.output) {
                (Some(format), Some(path)) => Destination::File {
                    format,
                    path: path.clone(),
                },
                _ => Destination::None,
            },
            checkpoint: None,
            controls: None,
        };
        let mut metrics = Accumulator::new(self.metrics.contains(&Metric::MaxStrain));
        let outcome = service::execute(
            &request,
            Hooks {
                observer: Some(&mut metrics),
                stop,
                ..Hooks::default()
            },
        );
        record.metrics = self
            .metrics
            .iter()
            .map(|m| (m.name().to_owned(), metrics.value(*m)))
            .collect();
        if outcome.kept {
            record.file = self.file.clone();
        }
        record.seconds = started.elapsed().as_secs_f64();
        match &outcome.result {
            Ok(_) => Some(record),
            Err(e) if e.class() == ExitClass::Stopped => None,
            Err(e) => {
                let class = e.class();
                let status = match class {
                    ExitClass::Unstable => Status::Unstable,
                    ExitClass::BadInput => Status::Invalid,
                    _ => Status::Failed,
                };
                Some(end(record, status, class.status(), e.message()))
            }
        }
    }
}

pub(super) fn parameter_map(parameters: &[(String, toml::Value)]) -> Map<String, Json> {
    parameters
        .iter()
        .map(|(k, v)| {
            let json = serde_json::to_value(v).unwrap_or(Json::Null);
            (k.clone(), json)
        })
        .collect()
}
