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

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use glam::DVec3;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value as Json};
use softbody_scene::error::Seg;
use softbody_scene::{Invalid, KeyPath, SceneError};

use crate::output::{Format, Frame, FrameSink, Header};
use crate::service::{self, Destination, ExitClass, Hooks, RunRequest, SceneSource};
use crate::{Backend, Setting};

/// The manifest's file name in the out directory.
pub const MANIFEST: &str = "manifest.jsonl";

/// Version of the manifest's header line (`softbody_sweep`).
pub const MANIFEST_VERSION: u32 = 1;

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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RandomFile {
    runs: usize,
    seed: u64,
    parameters: toml::Table,
}

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
    /// sweep: exit status 2) rather than the file system (1).
    pub fn is_bad_input(&self) -> bool {
        matches!(self, SweepError::File(_) | SweepError::Manifest { .. })
    }
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
        let file: SweepFile = toml::from_str(text).map_err(|e| {
            // Located as a scene file's errors are: the same TOML, the same reporting.
            let key = e
                .span()
                .map(|s| softbody_scene::error::key_at(text, s.start))
                .unwrap_or_default();
            located(key, e.message().trim().to_owned())
        })?;
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
        let common = parameters(&file.set, &key("set")).map_err(|(k, m)| located(k, m))?;

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
            (Some(grid), _, _) => grid_runs(grid).map_err(|(k, m)| located(k, m))?,
            (_, Some(list), _) => list
                .iter()
                .enumerate()
                .map(|(i, t)| parameters(t, &key("runs").index(i)))
                .collect::<Result<_, _>>()
                .map_err(|(k, m)| located(k, m))?,
            (_, _, Some(random)) => random_runs(random).map_err(|(k, m)| located(k, m))?,
            _ => unreachable!("one kind is present"),
        };
        if runs.is_empty() {
            return Err(located(KeyPath::root(), "the sweep has no runs".into()));
        }
        let sweep = Sweep {
            file: origin.to_owned(),
            scene_text,
            scene_origin,
            common,
            runs,
            format,
            backend,
            threads,
            metrics,
        };
        // The base scene with the common settings must load: a fault there is every run's.
        crate::scene_from_toml(
            &sweep.scene_text,
            &sweep.scene_origin,
            &sweep.settings(&[])?,
        )?;
        Ok(sweep)
    }

    /// The common settings followed by `parameters`, as [`Setting`]s.
    fn settings(&self, parameters: &[(String, toml::Value)]) -> Result<Vec<Setting>, SceneError> {
        to_settings(self.common.iter().chain(parameters), &self.scene_origin)
    }

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

fn key(name: &str) -> KeyPath {
    KeyPath::root().key(name)
}

/// A table of `key path = value` pairs as parameters, each key checked.
fn parameters(table: &toml::Table, at: &KeyPath) -> Result<Parameters, (KeyPath, String)> {
    table
        .iter()
        .map(|(k, v)| match Setting::new(k, v.clone()) {
            Ok(_) => Ok((k.clone(), v.clone())),
            Err(e) => Err((at.key(k), e)),
        })
        .collect()
}

/// Every combination of the grid's values, the last key varying fastest.
fn grid_runs(grid: &toml::Table) -> Result<Vec<Parameters>, (KeyPath, String)> {
    let mut axes = Vec::new();
    for (k, v) in grid {
        let at = key("grid").key(k);
        Setting::new(k, v.clone()).map_err(|e| (at.clone(), e))?;
        match v {
            toml::Value::Array(values) if !values.is_empty() => axes.push((k, values)),
            _ => {
                return Err((
                    at,
                    "a grid parameter takes a non-empty list of values".into(),
                ));
            }
        }
    }
    let mut runs: Vec<Parameters> = vec![Vec::new()];
    for (k, values) in axes {
        runs = runs
            .into_iter()
            .flat_map(|run| {
                values.iter().map(move |v| {
                    let mut run = run.clone();
                    run.push((k.clone(), v.clone()));
                    run
                })
            })
            .collect();
    }
    Ok(runs)
}

/// `runs` parameter sets drawn from the seeded generator, run by run, key by key (sorted).
fn random_runs(random: &RandomFile) -> Result<Vec<Parameters>, (KeyPath, String)> {
    enum Draw<'a> {
        Uniform(f64, f64),
        LogUniform(f64, f64),
        Choice(&'a [toml::Value]),
    }
    let mut draws = Vec::new();
    for (k, v) in &random.parameters {
        let at = key("random").key("parameters").key(k);
        Setting::new(k, toml::Value::Integer(0)).map_err(|e| (at.clone(), e))?;
        let bad = || {
            (
                at.clone(),
                "a random parameter is { uniform = [lo, hi] }, { log_uniform = [lo, hi] } (0 < \
                 lo) or { choice = [a, b, …] }"
                    .to_owned(),
            )
        };
        let range = |v: &toml::Value| -> Option<(f64, f64)> {
            let a = v.as_array()?;
            let num = |x: &toml::Value| x.as_float().or_else(|| x.as_integer().map(|i| i as f64));
            match a.as_slice() {
                [lo, hi] => {
                    let (lo, hi) = (num(lo)?, num(hi)?);
                    (lo.is_finite() && hi.is_finite() && lo <= hi).then_some((lo, hi))
                }
                _ => None,
            }
        };
        let table = v.as_table().filter(|t| t.len() == 1).ok_or_else(bad)?;
        let (kind, arg) = table.iter().next().expect("one entry");
        let draw = match kind.as_str() {
            "uniform" => range(arg).map(|(lo, hi)| Draw::Uniform(lo, hi)),
            "log_uniform" => range(arg)
                .filter(|(lo, _)| *lo > 0.0)
                .map(|(lo, hi)| Draw::LogUniform(lo, hi)),
            "choice" => arg
                .as_array()
                .filter(|a| !a.is_empty())
                .map(|a| Draw::Choice(a)),
            _ => None,
        };
        draws.push((k, draw.ok_or_else(bad)?));
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(random.seed);
    let runs = (0..random.runs)
        .map(|_| {
            draws
                .iter()
                .map(|(k, draw)| {
                    let value = match draw {
                        Draw::Uniform(lo, hi) => {
                            toml::Value::Float(lo + (hi - lo) * rng.random::<f64>())
                        }
                        Draw::LogUniform(lo, hi) => {
                            let (a, b) = (lo.ln(), hi.ln());
                            toml::Value::Float((a + (b - a) * rng.random::<f64>()).exp())
                        }
                        Draw::Choice(values) => values[rng.random_range(0..values.len())].clone(),
                    };
                    ((*k).clone(), value)
                })
                .collect()
        })
        .collect();
    Ok(runs)
}

fn to_settings<'a>(
    parameters: impl IntoIterator<Item = &'a (String, toml::Value)>,
    origin: &Path,
) -> Result<Vec<Setting>, SceneError> {
    parameters
        .into_iter()
        .map(|(k, v)| {
            Setting::new(k, v.clone()).map_err(|message| {
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
        .collect()
}

/// A summary number of a run, computed from its frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// Frames written.
    Frames,
    /// Time of the last frame, s.
    FinalTime,
    /// Kinetic energy at the last frame, J.
    FinalKineticEnergy,
    /// Elastic energy at the last frame, J.
    FinalElasticEnergy,
    /// Total energy (kinetic + gravitational + elastic) at the last frame, J.
    FinalTotalEnergy,
    /// Largest kinetic energy of any frame, J.
    MaxKineticEnergy,
    /// Speed of the fastest particle at the last frame, m/s.
    FinalMaxSpeed,
    /// Speed of the fastest particle at any frame, m/s.
    MaxSpeed,
    /// Lowest y of any particle at any frame, m.
    MinHeight,
    /// Centre of mass at the last frame, `[x, y, z]` m.
    FinalCenter,
    /// Distance of the centre of mass at the last frame from the first frame's, m.
    CenterDisplacement,
    /// Largest |ℓ − r| / r of any spring at any frame.
    MaxStrain,
}

impl Metric {
    /// Every metric, in the order the manifest lists them.
    pub const ALL: [Metric; 12] = [
        Metric::Frames,
        Metric::FinalTime,
        Metric::FinalKineticEnergy,
        Metric::FinalElasticEnergy,
        Metric::FinalTotalEnergy,
        Metric::MaxKineticEnergy,
        Metric::FinalMaxSpeed,
        Metric::MaxSpeed,
        Metric::MinHeight,
        Metric::FinalCenter,
        Metric::CenterDisplacement,
        Metric::MaxStrain,
    ];

    /// The metric's name in sweep files and manifests.
    pub fn name(self) -> &'static str {
        match self {
            Metric::Frames => "frames",
            Metric::FinalTime => "final_time",
            Metric::FinalKineticEnergy => "final_kinetic_energy",
            Metric::FinalElasticEnergy => "final_elastic_energy",
            Metric::FinalTotalEnergy => "final_total_energy",
            Metric::MaxKineticEnergy => "max_kinetic_energy",
            Metric::FinalMaxSpeed => "final_max_speed",
            Metric::MaxSpeed => "max_speed",
            Metric::MinHeight => "min_height",
            Metric::FinalCenter => "final_center",
            Metric::CenterDisplacement => "center_displacement",
            Metric::MaxStrain => "max_strain",
        }
    }
}

impl std::str::FromStr for Metric {
    type Err = String;
    fn from_str(s: &str) -> Result<Metric, String> {
        Metric::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Metric::ALL.iter().map(|m| m.name()).collect();
                format!("unknown metric `{s}`; expected one of {}", names.join(", "))
            })
    }
}

/// The metrics' running values over a run's frames.
#[derive(Default)]
struct Accumulator {
    masses: Vec<f64>,
    springs: Vec<[u32; 2]>,
    rest: Vec<f64>,
    frames: u64,
    final_time: f64,
    final_energies: Option<softbody_scene::Energies>,
    max_kinetic: f64,
    final_max_speed: f64,
    max_speed: f64,
    min_height: f64,
    first_center: Option<DVec3>,
    final_center: DVec3,
    max_strain: f64,
    /// Whether strains are wanted (they cost a pass over the springs per frame).
    strain: bool,
}

/// The metrics watch the run as the service's observer.
impl FrameSink for Accumulator {
    fn header(&mut self, h: &Header) -> io::Result<()> {
        Accumulator::header(self, h);
        Ok(())
    }
    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        Accumulator::frame(self, f);
        Ok(())
    }
    fn finish(&mut self) -> io::Result<()> {
        Ok(())
    }
    fn wants_springs(&self) -> bool {
        self.strain
    }
}

impl Accumulator {
    fn header(&mut self, h: &Header) {
        self.masses = h.masses.clone();
        if self.strain {
            self.springs = h.springs.clone();
            self.rest = h.rest.clone();
        }
        self.min_height = f64::INFINITY;
    }

    fn frame(&mut self, f: &Frame<'_>) {
        self.frames += 1;
        self.final_time = f.time;
        self.final_energies = Some(f.energies);
        self.max_kinetic = self.max_kinetic.max(f.energies.kinetic);
        let speed = f.velocities.iter().map(|v| v.length()).fold(0.0, f64::max);
        self.final_max_speed = speed;
        self.max_speed = self.max_speed.max(speed);
        let low = f
            .positions
            .iter()
            .map(|x| x.y)
            .fold(f64::INFINITY, f64::min);
        self.min_height = self.min_height.min(low);
        let mass: f64 = self.masses.iter().sum();
        let moment = f
            .positions
            .iter()
            .zip(&self.masses)
            .fold(DVec3::ZERO, |s, (x, m)| s + *x * *m);
        let center = if mass > 0.0 {
            moment / mass
        } else {
            DVec3::ZERO
        };
        self.first_center.get_or_insert(center);
        self.final_center = center;
        for ([a, b], r) in self.springs.iter().zip(&self.rest) {
            let length = (f.positions[*a as usize] - f.positions[*b as usize]).length();
            if *r > 0.0 {
                self.max_strain = self.max_strain.max(((length - r) / r).abs());
            }
        }
    }

    fn value(&self, metric: Metric) -> Json {
        let e = self.final_energies.unwrap_or_default();
        let number = |x: f64| serde_json::Number::from_f64(x).map_or(Json::Null, Json::Number);
        if self.frames == 0 {
            return if metric == Metric::Frames {
                0.into()
            } else {
                Json::Null
            };
        }
        match metric {
            Metric::Frames => self.frames.into(),
            Metric::FinalTime => number(self.final_time),
            Metric::FinalKineticEnergy => number(e.kinetic),
            Metric::FinalElasticEnergy => number(e.elastic),
            Metric::FinalTotalEnergy => number(e.total()),
            Metric::MaxKineticEnergy => number(self.max_kinetic),
            Metric::FinalMaxSpeed => number(self.final_max_speed),
            Metric::MaxSpeed => number(self.max_speed),
            Metric::MinHeight => number(self.min_height),
            Metric::FinalCenter => Json::Array(
                self.final_center
                    .to_array()
                    .into_iter()
                    .map(number)
                    .collect(),
            ),
            Metric::CenterDisplacement => number(
                (self.final_center - self.first_center.unwrap_or(self.final_center)).length(),
            ),
            Metric::MaxStrain => number(self.max_strain),
        }
    }
}

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
        let settings = match to_settings(self.common.iter().chain(&self.parameters), origin) {
            Ok(s) => s,
            Err(e) => return end(record, Status::Invalid, 2, e.to_string()),
        };
        let (backend, format) = match (
            self.backend.parse::<Backend>(),
            self.format.as_deref().map(str::parse::<Format>).transpose(),
        ) {
            (Ok(b), Ok(f)) => (b, f),
            (Err(e), _) | (_, Err(e)) => return end(record, Status::Invalid, 2, e),
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
        };
        let mut metrics = Accumulator {
            strain: self.metrics.contains(&Metric::MaxStrain),
            ..Accumulator::default()
        };
        let outcome = service::execute(
            &request,
            Hooks {
                observer: Some(&mut metrics),
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
            Ok(_) => record,
            Err(e) => {
                let class = e.class();
                let status = match class {
                    ExitClass::Unstable => Status::Unstable,
                    ExitClass::BadInput => Status::Invalid,
                    _ => Status::Failed,
                };
                end(record, status, class.status(), e.message())
            }
        }
    }
}

fn parameter_map(parameters: &[(String, toml::Value)]) -> Map<String, Json> {
    parameters
        .iter()
        .map(|(k, v)| {
            let json = serde_json::to_value(v).unwrap_or(Json::Null);
            (k.clone(), json)
        })
        .collect()
}

/// The manifest's first line.
#[derive(Serialize, Deserialize)]
struct ManifestHeader {
    softbody_sweep: u32,
    sweep: String,
    runs: usize,
}

/// A sweep's manifest in its out directory: the records found there, and the file that new
/// records are appended to as runs end.
pub struct Manifest {
    path: PathBuf,
    file: Mutex<File>,
    records: Mutex<BTreeMap<usize, Record>>,
}

impl Manifest {
    /// Opens the manifest of `sweep` in `out` (made if missing): reads the records of
    /// `manifest.jsonl` and of every `manifest-task-*.jsonl` there, checks that they belong to
    /// this sweep (the same parameters for the same run number), keeps one per run (a
    /// finished one over a failed one, else the last), and opens for appending
    /// `manifest.jsonl`, rewritten with the finished records kept, or with `task` Some(i) the task's own
    /// `manifest-task-i.jsonl`, which no other task writes.
    pub fn open(sweep: &Sweep, out: &Path, task: Option<usize>) -> Result<Manifest, SweepError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |source| SweepError::Io { path, source }
        };
        std::fs::create_dir_all(out).map_err(io(out))?;
        let mut records = collect(sweep, out)?;
        let path = match task {
            Some(i) => out.join(format!("manifest-task-{i}.jsonl")),
            None => out.join(MANIFEST),
        };
        let file = if task.is_some() {
            let mut f = OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .map_err(io(&path))?;
            if f.metadata().map_err(io(&path))?.len() == 0 {
                writeln!(f, "{}", header_line(sweep)).map_err(io(&path))?;
            }
            f
        } else {
            // Rewritten whole beside and renamed over, so a crash leaves the old or the new;
            // without the failed records, whose runs this sweep runs again and records anew.
            records.retain(|_, r| r.status.finished());
            let staged = out.join(".manifest.jsonl.part");
            let mut text = header_line(sweep);
            text.push('\n');
            for r in records.values() {
                text.push_str(&serde_json::to_string(r).expect("records serialise"));
                text.push('\n');
            }
            std::fs::write(&staged, text).map_err(io(&staged))?;
            std::fs::rename(&staged, &path).map_err(io(&path))?;
            OpenOptions::new()
                .append(true)
                .open(&path)
                .map_err(io(&path))?
        };
        Ok(Manifest {
            path,
            file: Mutex::new(file),
            records: Mutex::new(records),
        })
    }

    /// The file records are appended to.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether run `i` has a finished record.
    pub fn finished(&self, i: usize) -> bool {
        let records = self.records.lock().expect("not poisoned");
        records.get(&i).is_some_and(|r| r.status.finished())
    }

    /// Appends a record (one write of one line, flushed) and keeps it.
    pub fn append(&self, record: Record) -> io::Result<()> {
        let mut line = serde_json::to_string(&record).map_err(io::Error::other)?;
        line.push('\n');
        {
            let mut file = self.file.lock().expect("not poisoned");
            file.write_all(line.as_bytes())?;
            file.flush()?;
        }
        self.records
            .lock()
            .expect("not poisoned")
            .insert(record.run, record);
        Ok(())
    }

    /// Every record, in run order.
    pub fn records(&self) -> Vec<Record> {
        let records = self.records.lock().expect("not poisoned");
        records.values().cloned().collect()
    }
}

/// The records of `out`'s manifests (`manifest.jsonl`, then every `manifest-task-*.jsonl`),
/// checked against `sweep`, one per run: a finished one over a failed one, else the last.
fn collect(sweep: &Sweep, out: &Path) -> Result<BTreeMap<usize, Record>, SweepError> {
    let mut files = vec![out.join(MANIFEST)];
    let mut tasks: Vec<PathBuf> = match std::fs::read_dir(out) {
        Ok(entries) => entries.filter_map(|e| e.ok().map(|e| e.path())).collect(),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Vec::new(),
        Err(source) => {
            return Err(SweepError::Io {
                path: out.to_owned(),
                source,
            });
        }
    };
    tasks.retain(|p| {
        p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with("manifest-task-") && n.ends_with(".jsonl"))
    });
    tasks.sort();
    files.extend(tasks);
    let mut records: BTreeMap<usize, Record> = BTreeMap::new();
    for file in &files {
        for record in read_records(file)? {
            let expected = sweep
                .runs
                .get(record.run)
                .map(|p| parameter_map(p))
                .filter(|p| *p == record.parameters);
            if expected.is_none() {
                return Err(SweepError::Manifest {
                    path: file.clone(),
                    message: format!(
                        "run {} there has other parameters than in {} ({}): the manifest is \
                         another sweep's; give this one another out directory",
                        record.run,
                        sweep.file.display(),
                        Json::Object(record.parameters.clone())
                    ),
                });
            }
            let keep = match records.get(&record.run) {
                Some(old) => !old.status.finished() || record.status.finished(),
                None => true,
            };
            if keep {
                records.insert(record.run, record);
            }
        }
    }
    Ok(records)
}

/// Every record of `sweep` in `out` (its manifest and its Slurm tasks' manifests), one per
/// run that has one, in run order.
pub fn read_manifest(sweep: &Sweep, out: &Path) -> Result<Vec<Record>, SweepError> {
    Ok(collect(sweep, out)?.into_values().collect())
}

fn header_line(sweep: &Sweep) -> String {
    let sweep_file = std::path::absolute(&sweep.file).unwrap_or_else(|_| sweep.file.clone());
    serde_json::to_string(&ManifestHeader {
        softbody_sweep: MANIFEST_VERSION,
        sweep: sweep_file.display().to_string(),
        runs: sweep.len(),
    })
    .expect("the header serialises")
}

/// The records of a manifest file (none when it does not exist). A last line without its
/// newline is what a killed sweep leaves mid-write: it is dropped, and its run runs again.
fn read_records(path: &Path) -> Result<Vec<Record>, SweepError> {
    let file = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(SweepError::Io {
                path: path.to_owned(),
                source,
            });
        }
    };
    let mut records = Vec::new();
    let mut reader = BufReader::new(file);
    let mut line = String::new();
    let mut number = 0;
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .map_err(|source| SweepError::Io {
                path: path.to_owned(),
                source,
            })?;
        if n == 0 || !line.ends_with('\n') {
            break;
        }
        number += 1;
        if line.trim().is_empty() || line.starts_with("{\"softbody_sweep\"") {
            continue;
        }
        let record: Record = serde_json::from_str(&line).map_err(|e| SweepError::Manifest {
            path: path.to_owned(),
            message: format!("line {number} is not a sweep record: {e}"),
        })?;
        records.push(record);
    }
    Ok(records)
}

/// Which runs a local sweep takes, and with how many workers.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options {
    /// Runs at once (default: all cores, divided by the threads per run).
    pub workers: Option<usize>,
    /// A Slurm array task: `(index, count)` runs the runs `i` with `i % count == index`
    /// (count 1: the run `index` alone), recording them in the task's own manifest.
    pub task: Option<(usize, usize)>,
}

/// What a sweep did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Outcome {
    /// Runs this invocation was to take (the plan, or the task's share).
    pub planned: usize,
    /// Of those, already finished in the manifest and skipped.
    pub skipped: usize,
    /// Run now and ended `ok`.
    pub ok: usize,
    /// Run now and ended `unstable`.
    pub unstable: usize,
    /// Run now and ended `invalid`.
    pub invalid: usize,
    /// Run now and ended `failed`.
    pub failed: usize,
}

/// The runs this invocation takes under `task` (see [`Options::task`]).
pub fn task_runs(len: usize, task: Option<(usize, usize)>) -> Vec<usize> {
    match task {
        None => (0..len).collect(),
        Some((index, 1)) => (index < len).then_some(index).into_iter().collect(),
        Some((index, count)) => (0..len).filter(|i| i % count == index).collect(),
    }
}

/// Runs the sweep on this machine's cores into `out`: the runs not yet finished there, as many
/// at once as `options.workers`, each record appended to the manifest as its run ends;
/// `progress` hears (runs done, runs to do).
pub fn run_local(
    sweep: &Sweep,
    out: &Path,
    options: &Options,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Outcome, SweepError> {
    let manifest = Manifest::open(sweep, out, options.task.map(|(i, _)| i))?;
    let planned = task_runs(sweep.len(), options.task);
    let todo: Vec<usize> = planned
        .iter()
        .copied()
        .filter(|&i| !manifest.finished(i))
        .collect();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let workers = options
        .workers
        .unwrap_or((cores / sweep.threads).max(1))
        .max(1);
    let done = AtomicUsize::new(0);
    let next = AtomicUsize::new(0);
    let counts = Mutex::new(Outcome {
        planned: planned.len(),
        skipped: planned.len() - todo.len(),
        ..Outcome::default()
    });
    let write_error: Mutex<Option<io::Error>> = Mutex::new(None);
    progress(0, todo.len());
    // Plain threads taking the next run from a counter, not a rayon pool: each run steps in
    // its solver's own pool, and a rayon worker blocked in another pool's `install` steals
    // work from its own meanwhile — another run, whose solver blocks in turn — so the runs
    // nested on one stack until it overflowed (a 1,000-run sweep did).
    let worker = || {
        loop {
            let k = next.fetch_add(1, Ordering::Relaxed);
            let Some(&i) = todo.get(k) else { break };
            let record = sweep.job(i, out).run();
            {
                let mut c = counts.lock().expect("not poisoned");
                match record.status {
                    Status::Ok => c.ok += 1,
                    Status::Unstable => c.unstable += 1,
                    Status::Invalid => c.invalid += 1,
                    Status::Failed => c.failed += 1,
                }
            }
            if let Err(e) = manifest.append(record) {
                write_error.lock().expect("not poisoned").get_or_insert(e);
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, todo.len());
        }
    };
    std::thread::scope(|scope| -> Result<(), SweepError> {
        for w in 0..workers.min(todo.len()) {
            std::thread::Builder::new()
                .name(format!("sweep-{w}"))
                .spawn_scoped(scope, worker)
                .map_err(|source| SweepError::Threads { workers, source })?;
        }
        Ok(())
    })?;
    if let Some(source) = write_error.into_inner().expect("not poisoned") {
        return Err(SweepError::Io {
            path: manifest.path().to_owned(),
            source,
        });
    }
    Ok(counts.into_inner().expect("not poisoned"))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENE: &str = "\
[simulation]
dt = 0.001
duration = 0.05
frame_rate = 100.0

[[body]]
name = \"cube\"
kind = \"cuboid\"
size = [0.2, 0.2, 0.2]
resolution = [3, 3, 3]
center = [0.0, 0.3, 0.0]
mass = 1.0
structural = { stiffness = 500.0, damping = 1.0 }

[[terrain]]
kind = \"plane\"
normal = [0.0, 1.0, 0.0]
friction = 0.3
";

    fn sweep(body: &str) -> Result<Sweep, SweepError> {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("s.toml"), SCENE).unwrap();
        let text = format!("scene = \"s.toml\"\n{body}");
        Sweep::from_toml(&text, &dir.path().join("sweep.toml"))
    }

    #[test]
    fn a_grid_is_every_combination_the_last_key_fastest() {
        let s = sweep(
            "[grid]\n\"body[0].mass\" = [1.0, 2.0]\n\"terrain[0].friction\" = [0.1, 0.2, 0.3]\n",
        )
        .unwrap();
        assert_eq!(s.len(), 6);
        let mass_friction = |i: usize| {
            let p = s.parameters(i);
            (p[0].1.as_float().unwrap(), p[1].1.as_float().unwrap())
        };
        assert_eq!(mass_friction(0), (1.0, 0.1));
        assert_eq!(mass_friction(2), (1.0, 0.3));
        assert_eq!(mass_friction(3), (2.0, 0.1));
        assert_eq!(mass_friction(5), (2.0, 0.3));
        assert_eq!(s.run_file(5).as_deref(), Some("runs/run-000005.npz"));
    }

    #[test]
    fn random_draws_depend_on_the_seed_alone_and_stay_in_range() {
        let text = "[random]\nruns = 50\nseed = 7\n[random.parameters]\n\
                    \"body[0].mass\" = { uniform = [1.0, 3.0] }\n\
                    \"terrain[0].friction\" = { log_uniform = [0.01, 1.0] }\n\
                    \"simulation.integrator\" = { choice = [\"rk4\", \"midpoint\"] }\n";
        let a = sweep(text).unwrap();
        let b = sweep(text).unwrap();
        assert_eq!(a.len(), 50);
        let mut integrators = std::collections::BTreeSet::new();
        for i in 0..50 {
            assert_eq!(a.parameters(i), b.parameters(i), "same seed, same plan");
            let p: BTreeMap<_, _> = a.parameters(i).iter().cloned().collect();
            let mass = p["body[0].mass"].as_float().unwrap();
            let mu = p["terrain[0].friction"].as_float().unwrap();
            assert!((1.0..=3.0).contains(&mass) && (0.01..=1.0).contains(&mu));
            integrators.insert(p["simulation.integrator"].as_str().unwrap().to_owned());
        }
        assert_eq!(integrators.len(), 2, "both choices drawn in 50 runs");
        let c = sweep(&text.replace("seed = 7", "seed = 8")).unwrap();
        assert_ne!(a.parameters(0), c.parameters(0));
    }

    #[test]
    fn bad_sweep_files_are_located() {
        let cases = [
            (
                "[grid]\n\"body[0].mass\" = 2.0\n",
                "grid.body[0].mass",
                "non-empty list",
            ),
            (
                "[grid]\n\"body[0]mass\" = [1.0]\n",
                "grid.body[0]mass",
                "is not a key path",
            ),
            ("", "(document)", "exactly one of"),
            (
                "format = \"xls\"\n[grid]\n\"body[0].mass\" = [1.0]\n",
                "format",
                "unknown format",
            ),
            (
                "metrics = [\"speed\"]\n[grid]\n\"body[0].mass\" = [1.0]\n",
                "metrics[0]",
                "unknown metric `speed`",
            ),
            (
                "[random]\nruns = 2\nseed = 1\n[random.parameters]\n\"body[0].mass\" = { uniform = [2.0, 1.0] }\n",
                "random.parameters.body[0].mass",
                "uniform = [lo, hi]",
            ),
            (
                "colour = 1\n[grid]\n\"body[0].mass\" = [1.0]\n",
                "colour",
                "unknown field",
            ),
        ];
        for (body, key, says) in cases {
            let e = sweep(body).unwrap_err();
            let SweepError::File(SceneError::Invalid(d)) = &e else {
                panic!("{body}: {e}");
            };
            assert_eq!(d.key.to_string(), key, "{body}");
            assert!(d.message.contains(says), "{body}: {e}");
            assert!(e.is_bad_input());
        }
        // The base scene with the common settings must load.
        let e =
            sweep("set = { \"body[0].mass\" = -1.0 }\n[grid]\n\"terrain[0].friction\" = [0.1]\n")
                .unwrap_err();
        assert!(
            e.to_string().contains("(from --set body[0].mass=-1.0)"),
            "{e}"
        );
    }

    #[test]
    fn jobs_record_ok_unstable_and_invalid_runs_with_metrics() {
        let dir = tempfile::tempdir().unwrap();
        let s = sweep(
            "metrics = [\"frames\", \"min_height\", \"final_center\"]\n[[runs]]\n\"body[0].mass\" = 2.0\n\
             [[runs]]\n\"body[0].mass\" = -2.0\n\
             [[runs]]\n\"simulation.integrator\" = \"explicit-euler\"\n\"simulation.dt\" = 0.01\n\
             \"simulation.frame_rate\" = 50.0\n\"simulation.duration\" = 3.0\n\
             \"body[0].structural\" = { stiffness = 1e6 }\n",
        )
        .unwrap();
        let ok = s.job(0, dir.path()).run();
        assert_eq!(
            (ok.status, ok.exit_status, ok.error.as_deref()),
            (Status::Ok, 0, None)
        );
        assert_eq!(ok.metrics["frames"], Json::from(6));
        assert_eq!(ok.parameters["body[0].mass"], Json::from(2.0));
        assert_eq!(ok.file.as_deref(), Some("runs/run-000000.npz"));
        assert!(dir.path().join("runs/run-000000.npz").is_file());
        let center = ok.metrics["final_center"].as_array().unwrap();
        assert_eq!(center.len(), 3);
        assert!(ok.metrics["min_height"].as_f64().unwrap() > 0.0);

        let invalid = s.job(1, dir.path()).run();
        assert_eq!((invalid.status, invalid.exit_status), (Status::Invalid, 2));
        assert!(
            invalid
                .error
                .as_deref()
                .unwrap()
                .contains("must be greater than zero"),
            "{invalid:?}"
        );
        assert_eq!(invalid.file, None);
        assert_eq!(invalid.metrics["frames"], Json::from(0));
        assert_eq!(invalid.metrics["min_height"], Json::Null);
        assert!(!dir.path().join("runs/run-000001.npz").exists());

        let unstable = s.job(2, dir.path()).run();
        assert_eq!(
            (unstable.status, unstable.exit_status),
            (Status::Unstable, 3)
        );
        assert!(
            unstable
                .error
                .as_deref()
                .unwrap()
                .contains("became unstable")
        );
        assert_eq!(
            unstable.file.as_deref(),
            Some("runs/run-000002.npz"),
            "frames kept"
        );

        // A job travels as JSON and runs the same there: the same metrics, bit for bit.
        let json = serde_json::to_string(&s.job(0, &dir.path().join("elsewhere"))).unwrap();
        let shipped: Job = serde_json::from_str(&json).unwrap();
        let again = shipped.run();
        assert_eq!(again.metrics, ok.metrics);
    }

    #[test]
    fn a_local_sweep_writes_the_manifest_and_resumes() {
        let dir = tempfile::tempdir().unwrap();
        let s = sweep("format = \"jsonl\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, -1.0, 3.0]\n")
            .unwrap();
        let out = dir.path().join("out");
        let options = Options {
            workers: Some(2),
            task: None,
        };
        let first = run_local(&s, &out, &options, &|_, _| {}).unwrap();
        assert_eq!(
            first,
            Outcome {
                planned: 4,
                ok: 3,
                invalid: 1,
                ..Outcome::default()
            }
        );
        let text = std::fs::read_to_string(out.join(MANIFEST)).unwrap();
        assert_eq!(text.lines().count(), 1 + 4, "a header and a line per run");
        let header: Json = serde_json::from_str(text.lines().next().unwrap()).unwrap();
        assert_eq!(header["softbody_sweep"], Json::from(1));
        assert_eq!(header["runs"], Json::from(4));
        let records = read_records(&out.join(MANIFEST)).unwrap();
        let mut runs: Vec<usize> = records.iter().map(|r| r.run).collect();
        runs.sort();
        assert_eq!(runs, [0, 1, 2, 3]);

        // Everything finished: a second sweep runs nothing and keeps the records.
        let second = run_local(&s, &out, &options, &|_, _| {}).unwrap();
        assert_eq!((second.skipped, second.ok + second.invalid), (4, 0));
        assert_eq!(read_records(&out.join(MANIFEST)).unwrap().len(), 4);

        // A failed record and a half-written line are run again.
        let mut failed = records.iter().find(|r| r.run == 3).unwrap().clone();
        failed.status = Status::Failed;
        failed.exit_status = 1;
        let kept: Vec<String> = records
            .iter()
            .filter(|r| r.run != 3 && r.run != 0)
            .map(|r| serde_json::to_string(r).unwrap())
            .collect();
        std::fs::write(
            out.join(MANIFEST),
            format!(
                "{}\n{}\n{}\n{{\"run\": 0, \"param",
                header_line(&s),
                kept.join("\n"),
                serde_json::to_string(&failed).unwrap()
            ),
        )
        .unwrap();
        let third = run_local(&s, &out, &options, &|_, _| {}).unwrap();
        assert_eq!((third.skipped, third.ok), (2, 2));
        let records = read_records(&out.join(MANIFEST)).unwrap();
        assert_eq!(records.len(), 4, "one record per run after the rewrite");
        assert!(records.iter().all(|r| r.status.finished()));

        // Another sweep's manifest is refused.
        let other = sweep("[grid]\n\"body[0].mass\" = [5.0]\n").unwrap();
        let e = run_local(&other, &out, &options, &|_, _| {}).unwrap_err();
        assert!(e.to_string().contains("is another sweep's"), "{e}");
    }

    #[test]
    fn slurm_tasks_write_their_own_manifests_and_a_sweep_merges_them() {
        let dir = tempfile::tempdir().unwrap();
        let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0]\n").unwrap();
        let out = dir.path().join("out");
        assert_eq!(task_runs(3, Some((1, 1))), [1]);
        assert_eq!(task_runs(3, Some((5, 1))), Vec::<usize>::new());
        assert_eq!(task_runs(5, Some((1, 2))), [1, 3]);
        for i in 0..3 {
            let options = Options {
                workers: Some(1),
                task: Some((i, 1)),
            };
            let o = run_local(&s, &out, &options, &|_, _| {}).unwrap();
            assert_eq!((o.planned, o.ok), (1, 1));
            let own = read_records(&out.join(format!("manifest-task-{i}.jsonl"))).unwrap();
            assert_eq!(own.len(), 1);
            assert_eq!(own[0].run, i);
            assert_eq!(own[0].file, None, "metrics only");
        }
        let merged = run_local(&s, &out, &Options::default(), &|_, _| {}).unwrap();
        assert_eq!((merged.skipped, merged.ok), (3, 0));
        assert_eq!(read_records(&out.join(MANIFEST)).unwrap().len(), 3);
    }

    /// 1,000 runs on two workers: each run's solver steps in a pool of its own, which nested
    /// the runs on one stack (and overflowed it) when the workers were a rayon pool.
    #[test]
    fn a_thousand_runs_finish_on_two_workers() {
        let dir = tempfile::tempdir().unwrap();
        let scene = "[simulation]\ndt = 0.001\nduration = 0.005\nframe_rate = 200.0\n\
                     [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0]]\nmasses = [1.0]\n";
        std::fs::write(dir.path().join("p.toml"), scene).unwrap();
        let text = "scene = \"p.toml\"\nformat = \"none\"\nmetrics = [\"final_time\"]\n\
                    [random]\nruns = 1000\nseed = 5\n[random.parameters]\n\
                    \"body[0].masses\" = { choice = [[1.0], [2.0]] }\n";
        let s = Sweep::from_toml(text, &dir.path().join("sweep.toml")).unwrap();
        let options = Options {
            workers: Some(2),
            task: None,
        };
        let out = dir.path().join("out");
        let o = run_local(&s, &out, &options, &|_, _| {}).unwrap();
        assert_eq!((o.planned, o.ok), (1000, 1000));
        let records = read_manifest(&s, &out).unwrap();
        assert_eq!(records.len(), 1000);
        assert!(records.iter().all(|r| r.metrics["final_time"] == 0.005));
    }

    #[test]
    fn runs_are_reproducible_whatever_the_workers() {
        let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0]\n").unwrap();
        let metrics = |workers: usize| {
            let dir = tempfile::tempdir().unwrap();
            let options = Options {
                workers: Some(workers),
                task: None,
            };
            run_local(&s, dir.path(), &options, &|_, _| {}).unwrap();
            let mut r = read_records(&dir.path().join(MANIFEST)).unwrap();
            r.sort_by_key(|r| r.run);
            r.into_iter().map(|r| r.metrics).collect::<Vec<_>>()
        };
        assert_eq!(metrics(1), metrics(3));
    }
}
