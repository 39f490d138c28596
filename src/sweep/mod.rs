//! Parameter sweeps: one base scene run many times, each run with some of its values changed by
//! key path ([`Setting`]s), each run's frames in a file of its own and a line per run in a
//! manifest.
//!
//! A sweep file (TOML, paths in it relative to it):
//!
//! ```toml
//! scene = "../scenes/jelly-on-ground.toml"   # or an inline [scene] table
//! format = "npz"                              # each run's frames: jsonl, csv, npz, vtk, ply,
//!                                             # obj, or "none" (metrics only); default npz
//! metrics = ["final_kinetic_energy", "min_height"]   # default: every metric
//! backend = "cpu"                             # default cpu
//! threads = 1                                 # solver threads per run, default 1
//! set = { "simulation.duration" = 1.0 }       # settings of every run
//!
//! [grid]                                      # every combination (keys in sorted order,
//! "body[0].structural.stiffness" = [1000.0, 2000.0]  # the last varying fastest); or
//! "terrain[0].friction" = [0.2, 0.8]          # [[runs]] tables (a list), or [random]
//! ```
//!
//! `[random]` draws `runs` parameter sets from a seeded generator (PCG-64): `seed`, `runs`, and
//! `[random.parameters]` with `{ uniform = [lo, hi] }`, `{ log_uniform = [lo, hi] }` or
//! `{ choice = [a, b, …] }` per key. The plan — which run gets which values — is a function of
//! the file alone, so a re-run, a Slurm array task and a Ray worker agree on it.
//!
//! A run is a [`Job`]: self-contained (the base scene's text travels with it, so that a worker
//! on another machine needs no scene file), serialisable, and turned into a [`Record`] by
//! [`Job::run`]: its parameters, status (`ok`, `unstable`, `invalid` — the scene refused these
//! values — or `failed`: output or device), exit status (as the CLI's), metrics ([`Metric`])
//! and output file. The [`Manifest`] (`OUT/manifest.jsonl`) gets each record as its run ends,
//! so a sweep that is stopped loses only the runs under way; [`run_local`] on the same out
//! directory skips the runs recorded as finished (`ok`, `unstable`, `invalid`: the same values
//! give the same outcome, bit for bit) and runs the failed and missing ones again. A Slurm array
//! task (`--task-index`) writes `manifest-task-I.jsonl` instead, so tasks never share a file; the
//! next sweep without `--task-index` merges them into `manifest.jsonl`.

mod file;
mod job;
mod local;
mod manifest;
mod metrics;
mod plan;
#[cfg(test)]
mod tests;

use std::io;
use std::path::{Path, PathBuf};

use softbody_scene::error::Seg;
use softbody_scene::{KeyPath, SceneError};

use crate::output::Format;
use crate::{Backend, Setting};

pub use job::{Job, Record, Status};
pub use local::{Options, Outcome, run_local, task_runs};
pub use manifest::{MANIFEST, MANIFEST_VERSION, Manifest, read_manifest};
pub use metrics::Metric;

/// A run's parameters: key paths (as written) and their values, in the plan's order.
pub type Parameters = Vec<(String, toml::Value)>;

/// A sweep read from its file: the base scene, the settings common to every run, and the
/// parameters of each run.
#[derive(Debug, Clone)]
pub struct Sweep {
    file: PathBuf,
    scene_text: String,
    scene_origin: PathBuf,
    common: Parameters,
    runs: Vec<Parameters>,
    format: Option<Format>,
    backend: Backend,
    threads: usize,
    metrics: Vec<Metric>,
    identity: manifest::Identity,
}

/// Why a sweep cannot start.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// The sweep file or its base scene is not valid (located, as scene errors are).
    #[error(transparent)]
    File(#[from] SceneError),
    /// The out directory's manifest belongs to another sweep, or cannot be read.
    #[error("{}: {message}", path.display())]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Another process writes the out directory (or the same Slurm task's manifest).
    #[error(transparent)]
    Lock(#[from] crate::lock::LockError),
    /// The options of a local sweep are out of range (zero workers, a task past the count).
    #[error("{0}")]
    Options(String),
    /// The out directory or its manifest cannot be written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// The worker threads could not start.
    #[error("cannot start {workers} worker threads: {source}")]
    Threads {
        /// Threads asked for.
        workers: usize,
        /// Why.
        source: io::Error,
    },
}

impl SweepError {
    /// Whether the sweep's input is at fault (the sweep file, its scene, a manifest of another
    /// sweep, options out of range: exit status 2) rather than the file system or another
    /// process writing the out directory (1).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            SweepError::File(_) | SweepError::Manifest { .. } | SweepError::Options(_)
        )
    }
}

impl Sweep {
    /// The sweep file.
    pub fn file(&self) -> &Path {
        &self.file
    }

    /// Number of runs.
    pub fn len(&self) -> usize {
        self.runs.len()
    }

    /// Whether the sweep has no runs (never, once read: that is refused).
    pub fn is_empty(&self) -> bool {
        self.runs.is_empty()
    }

    /// Run `i`'s parameters.
    pub fn parameters(&self, i: usize) -> &[(String, toml::Value)] {
        &self.runs[i]
    }

    /// Solver threads per run.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Run `i`'s output file, relative to the out directory (`runs/run-000042.npz`), or `None`
    /// when the sweep writes metrics only.
    pub fn run_file(&self, i: usize) -> Option<String> {
        self.format
            .map(|f| format!("runs/run-{i:06}.{}", f.extension()))
    }

    /// Run `i` as a self-contained job writing its frames under `out`.
    pub fn job(&self, i: usize, out: &Path) -> Job {
        Job {
            run: i,
            scene_text: self.scene_text.clone(),
            scene_origin: self.scene_origin.clone(),
            common: self.common.clone(),
            parameters: self.runs[i].clone(),
            output: self.run_file(i).map(|f| out.join(f)),
            file: self.run_file(i),
            format: self.format.map(|f| f.name().to_owned()),
            metrics: self.metrics.clone(),
            backend: self.backend.name().to_owned(),
            threads: self.threads,
        }
    }
}

/// The settings of a run: the sweep's `set` (`common`), then the run's own `parameters`, each
/// named in messages by where the sweep file gives it.
fn to_settings(
    common: &[(String, toml::Value)],
    parameters: &[(String, toml::Value)],
    origin: &Path,
) -> Result<Vec<Setting>, SceneError> {
    let entries = |list: &'static str, values: &[(String, toml::Value)]| {
        values
            .iter()
            .map(move |(k, v)| {
                Setting::new(k, v.clone())
                    .map(|s| s.from_entry(list))
                    .map_err(|message| {
                        SceneError::Invalid(Box::new(softbody_scene::Diagnostic {
                            file: origin.to_owned(),
                            line: 0,
                            column: 0,
                            key: KeyPath(vec![Seg::Key(k.clone())]),
                            message,
                            source_line: String::new(),
                        }))
                    })
            })
            .collect::<Vec<_>>()
    };
    entries("set", common)
        .into_iter()
        .chain(entries("the run's parameters", parameters))
        .collect()
}
