//! The run service: one run of a scene, from its file (or text) to the frames kept. What
//! `softbody run` and `softbody render`, a sweep's jobs and Python's `run` do, written once.
//!
//! A [`RunRequest`] says what runs: the scene, the [`Setting`]s that change it (the CLI's
//! `--set`s and overrides, a sweep's parameters, Python's keywords: one path), the backend,
//! where the frames go and whether the run checkpoints or resumes. [`execute`] reads the scene
//! file once, applies the settings to its text once (that text is what the frames' header
//! records), refuses a destination that cannot be written before it opens the solver (a GPU
//! takes seconds to open), runs, and applies one keep rule. The [`Outcome`] says how the run
//! ended, what was kept, and its [`ExitClass`], whose [`status`](ExitClass::status) is the one
//! table of exit statuses.
//!
//! **The keep rule.** The frames are put in place (the staged output committed over the
//! destination) when the run completed, or when it stopped early — an instability, a device
//! failure, a stop request — after writing at least one frame. They are dropped, and the
//! destination left as it was, when writing them failed or the run was refused before its first
//! frame (a scene, an output or a checkpoint that cannot be used). A checkpoint is removed when
//! the run ended by itself (completed, or diverged: going on would diverge again) or was
//! refused before its first frame (its energy overflows, its output does not fit), and is kept,
//! and named in the outcome, when a stop request, the device or a file ended it: `--resume`
//! goes on from there. A checkpoint that cannot be resumed (of another run or version, or
//! damaged, also when that is found in a frame read back) is left as it was, not named, and the
//! destination is left as it was too.
//!
//! **Checkpointing runs.** One that checkpoints or resumes holds an [`OutputLock`] on its
//! destination from before its checkpoint is touched to its end, so that a second one to the
//! same destination is refused at once ([`RunFailure::Lock`], exit status 1) rather than
//! replacing the first's checkpoint; and its destination must be a regular file or a series'
//! directory (or not exist yet): a device or a FIFO is refused before anything is opened
//! ([`RunFailure::Request`], exit status 2).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use glam::DVec3;
use softbody_scene::{Controls, Integrator, SceneError};

use crate::checkpoint::{CheckpointError, Checkpoints};
use crate::lock::{LockError, OutputLock};
use crate::output::{Format, Frame, FrameSink, Header, Output, OutputError};
use crate::run::{RunError, SceneFile, Summary};
use crate::{Backend, OpenError, Scene, Setting};

/// Where the scene comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum SceneSource {
    /// A scene file, read once.
    File(PathBuf),
    /// Scene text, with the path it stands for (messages name it; mesh paths are relative to
    /// its directory).
    Text {
        /// The TOML text.
        text: String,
        /// The file it stands for.
        origin: PathBuf,
    },
}

impl SceneSource {
    /// The path messages name.
    pub fn path(&self) -> &Path {
        match self {
            SceneSource::File(path) => path,
            SceneSource::Text { origin, .. } => origin,
        }
    }
}

/// Where the frames go.
#[derive(Debug, Clone, PartialEq)]
pub enum Destination {
    /// Nowhere but the request's observer ([`Hooks::observer`]).
    None,
    /// A file (or a directory of files, for the series formats), staged beside it and put in
    /// place as the keep rule says.
    File {
        /// The format.
        format: Format,
        /// The destination.
        path: PathBuf,
    },
    /// Standard output (the single-file formats).
    Stdout(Format),
}

/// Checkpointing: every `every` frames into `<destination>.checkpoint`, and/or going on from
/// the checkpoint there.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CheckpointPlan {
    /// Checkpoint every this many frames.
    pub every: Option<u64>,
    /// Go on from the destination's checkpoint, if it has one.
    pub resume: bool,
}

/// One run to do.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRequest {
    /// The scene.
    pub scene: SceneSource,
    /// Values that replace the scene's, in order (a later one wins).
    pub settings: Vec<Setting>,
    /// The solver.
    pub backend: Backend,
    /// CPU threads (all cores when `None`).
    pub threads: Option<usize>,
    /// Where the frames go.
    pub destination: Destination,
    /// Checkpointing, if any (needs a file destination).
    pub checkpoint: Option<CheckpointPlan>,
    /// Control forces, F × N (frame-major) for the run's F frames and N particles
    /// ([`softbody_scene::controls`]; the CPU backend; a checkpoint's fingerprint holds them).
    pub controls: Option<Arc<[DVec3]>>,
}

impl RunRequest {
    /// A run of the scene file at `path` on the CPU, on all cores, writing nowhere but to an
    /// observer.
    pub fn file(path: impl Into<PathBuf>) -> RunRequest {
        RunRequest {
            scene: SceneSource::File(path.into()),
            settings: Vec::new(),
            backend: Backend::Cpu,
            threads: None,
            destination: Destination::None,
            checkpoint: None,
            controls: None,
        }
    }
}

/// What the service says while it works, for a front end to show.
#[derive(Debug, Clone, PartialEq)]
pub enum Notice {
    /// Something about the results, e.g. a body starting inside the terrain.
    Warning(String),
    /// Going on from a checkpoint after this frame.
    Resuming {
        /// The last frame the checkpoint holds.
        after_frame: u64,
        /// The checkpoint.
        dir: PathBuf,
    },
    /// `resume` found no checkpoint: the run starts from the beginning.
    NoCheckpoint(PathBuf),
}

/// What the caller hears and adds while a run goes; each part is optional
/// (`Hooks::default()` has none).
#[derive(Default)]
pub struct Hooks<'a> {
    /// A sink that sees the header and every frame beside the destination's (a sweep's
    /// metrics, Python's arrays, `render`'s pictures). The caller finishes it.
    pub observer: Option<&'a mut dyn FrameSink>,
    /// Hears (steps done, steps in all) every few hundred steps.
    pub progress: Option<&'a mut dyn FnMut(u64, u64)>,
    /// Set (by a signal handler, another thread) to stop the run after its complete frames.
    pub stop: Option<&'a AtomicBool>,
    /// Hears the warnings and the checkpoint's news.
    pub notice: Option<&'a mut dyn FnMut(Notice)>,
}

/// Why a run did not complete.
#[derive(Debug, thiserror::Error)]
pub enum RunFailure {
    /// The scene file cannot be read or is invalid, with its settings.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The destination cannot be made or the frames cannot be put in place.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The solver cannot be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// The run stopped early, or its checkpoint cannot be used.
    #[error(transparent)]
    Run(#[from] RunError),
    /// Another process is checkpointing to the same destination (or its lock cannot be
    /// taken): an output's failure, exit status 1.
    #[error(transparent)]
    Lock(#[from] LockError),
    /// The request itself cannot be met (checkpoints on standard output).
    #[error("{0}")]
    Request(String),
}

impl From<CheckpointError> for RunFailure {
    fn from(e: CheckpointError) -> Self {
        RunFailure::Run(RunError::Checkpoint(e))
    }
}

/// How a run ended, as a class of outcomes; [`ExitClass::status`] is the command line's exit
/// status for each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExitClass {
    /// The run completed.
    Done,
    /// The output (or a checkpoint) could not be written, another process is checkpointing to
    /// it, its checkpoint's directory is not one, or the CPU threads could not start.
    Output,
    /// Bad input: the scene, the arguments, a checkpoint of another run or version or a damaged
    /// one, a checkpointed destination that is a device or a FIFO, a scene beyond what the GPU
    /// adapter runs.
    BadInput,
    /// The simulation became unstable.
    Unstable,
    /// No usable GPU adapter, or the device failed during the run.
    Device,
    /// Stopped on request (a signal).
    Stopped,
}

impl ExitClass {
    /// The exit status: 0, 1, 2, 3, 4, and 130 for a stop (128 + SIGINT, as a shell reports a
    /// process Ctrl-C ended; the CLI reports a SIGTERM's as 143).
    pub const fn status(self) -> u8 {
        match self {
            ExitClass::Done => 0,
            ExitClass::Output => 1,
            ExitClass::BadInput => 2,
            ExitClass::Unstable => 3,
            ExitClass::Device => 4,
            ExitClass::Stopped => 130,
        }
    }
}

impl RunFailure {
    /// The failure and its causes, each said once: "cannot write frames: No space left on
    /// device (os error 28)".
    pub fn message(&self) -> String {
        let mut message = self.to_string();
        let mut source = std::error::Error::source(self);
        while let Some(cause) = source {
            let text = cause.to_string();
            if !message.contains(&text) {
                message = format!("{message}: {text}");
            }
            source = cause.source();
        }
        message
    }

    /// The class of the failure.
    pub fn class(&self) -> ExitClass {
        match self {
            RunFailure::Scene(_) | RunFailure::Request(_) => ExitClass::BadInput,
            RunFailure::Output(e) if e.is_bad_input() => ExitClass::BadInput,
            RunFailure::Output(_) => ExitClass::Output,
            RunFailure::Open(OpenError::Gpu(g)) if g.no_usable_gpu() => ExitClass::Device,
            RunFailure::Open(OpenError::Gpu(_)) => ExitClass::BadInput,
            RunFailure::Open(OpenError::Threads { .. }) => ExitClass::Output,
            RunFailure::Lock(_) => ExitClass::Output,
            RunFailure::Run(e) => match e {
                RunError::Unstable(_) => ExitClass::Unstable,
                RunError::Device(_) => ExitClass::Device,
                RunError::Stopped { .. } => ExitClass::Stopped,
                RunError::Checkpoint(c) if c.is_bad_input() => ExitClass::BadInput,
                e if e.is_bad_input() => ExitClass::BadInput,
                RunError::Io(_) | RunError::Checkpoint(_) => ExitClass::Output,
                _ => ExitClass::Output,
            },
        }
    }
}

/// How a run went.
#[derive(Debug)]
pub struct Outcome {
    /// The summary of a completed run, or why it did not complete.
    pub result: Result<Summary, RunFailure>,
    /// The scene that ran (with its settings), once it loaded.
    pub scene: Option<Scene>,
    /// Frames written to the destination and the observer.
    pub frames: u64,
    /// Whether the frames were put in place at the destination (see the keep rule).
    pub kept: bool,
    /// The checkpoint left to go on from (`--resume`), if one was.
    pub checkpoint: Option<PathBuf>,
    /// The solver's device, e.g. "CPU, 2 threads" (empty when none opened).
    pub device: String,
    /// Wall-clock seconds of the run itself (the solver opened).
    pub seconds: f64,
}

impl Outcome {
    /// The class of the outcome.
    pub fn class(&self) -> ExitClass {
        match &self.result {
            Ok(_) => ExitClass::Done,
            Err(e) => e.class(),
        }
    }

    /// The integrator of the scene that ran (for the advice on an instability).
    pub fn integrator(&self) -> Option<Integrator> {
        self.scene.as_ref().map(|s| s.simulation.integrator)
    }

    fn failed(e: impl Into<RunFailure>, scene: Option<Scene>) -> Outcome {
        Outcome {
            result: Err(e.into()),
            scene,
            frames: 0,
            kept: false,
            checkpoint: None,
            device: String::new(),
            seconds: 0.0,
        }
    }
}

/// A scene read and changed by its settings: the scene, and the text that describes it (the
/// file's own when no setting changed it).
#[derive(Debug, Clone, PartialEq)]
pub struct Loaded {
    /// The scene.
    pub scene: Scene,
    /// Its text.
    pub text: String,
    /// The path messages and the header name.
    pub path: PathBuf,
}

/// Reads `source` once and applies `settings` to it.
pub fn load(source: &SceneSource, settings: &[Setting]) -> Result<Loaded, SceneError> {
    let (text, path) = match source {
        SceneSource::File(path) => {
            let text = std::fs::read_to_string(path).map_err(|cause| SceneError::Io {
                path: path.clone(),
                cause,
            })?;
            (text, path.clone())
        }
        SceneSource::Text { text, origin } => (text.clone(), origin.clone()),
    };
    let (scene, text) = crate::overrides::parse_with(&text, &path, settings)?;
    Ok(Loaded { scene, text, path })
}

/// Runs `request`: see the module's documentation for what it does and the keep rule.
pub fn execute(request: &RunRequest, hooks: Hooks<'_>) -> Outcome {
    let Hooks {
        observer,
        mut progress,
        stop,
        mut notice,
    } = hooks;
    let listening = notice.is_some();
    let mut notice = |n: Notice| {
        if let Some(hear) = notice.as_deref_mut() {
            hear(n);
        }
    };
    let loaded = match load(&request.scene, &request.settings) {
        Ok(loaded) => loaded,
        Err(e) => return Outcome::failed(e, None),
    };
    let scene = Some(loaded.scene.clone());
    let (format, path) = match &request.destination {
        Destination::None => (None, None),
        Destination::File { format, path } => (Some(*format), Some(path.as_path())),
        Destination::Stdout(format) => (Some(*format), None),
    };
    if request.checkpoint.is_some() && path.is_none() {
        return Outcome::failed(
            RunFailure::Request(
                "--checkpoint-every and --resume need an output file (--out), not standard \
                 output"
                    .into(),
            ),
            scene,
        );
    }
    // Before the device opens: a machine without an adapter says the same.
    if request.controls.is_some() && request.backend == Backend::Gpu {
        return Outcome::failed(RunFailure::Request(softbody_gpu::NO_CONTROLS.into()), scene);
    }
    if request.checkpoint.is_some()
        && let Some(path) = path
        && let Err(why) = checkpointable(path)
    {
        return Outcome::failed(RunFailure::Request(why), scene);
    }
    // Before the solver: a destination that cannot be written is refused first.
    let mut output = match format.map(|f| Output::create(f, path)).transpose() {
        Ok(output) => output,
        Err(e) => return Outcome::failed(e, scene),
    };
    // Held to the end: a second process checkpointing to this destination would replace this
    // one's checkpoint. Taken once `Output::create` has made the directory the lock goes in,
    // and before the solver opens, so that the second is refused at once.
    let _lock = match (request.checkpoint, path) {
        (Some(_), Some(path)) => match OutputLock::file(path) {
            Ok(lock) => Some(lock),
            Err(e) => return Outcome::failed(e, scene),
        },
        _ => None,
    };
    let mut solver = match crate::open(&loaded.scene, request.backend, request.threads) {
        Ok(solver) => solver,
        Err(e) => return Outcome::failed(e, scene),
    };
    let device = solver.device();
    let failed = |e: RunFailure, scene: Option<Scene>| Outcome {
        device: device.clone(),
        ..Outcome::failed(e, scene)
    };
    if let Some(forces) = &request.controls {
        let controls = Controls::new(solver.model(), forces.clone());
        if let Err(e) = controls.and_then(|c| solver.set_controls(Some(c))) {
            return failed(RunFailure::Request(e.to_string()), scene);
        }
    }
    // Said before the first step, so that a run about to diverge is warned of before it is
    // waited for. The step's estimate only to a listener: it takes seconds on large bodies.
    match solver.state() {
        Ok(state) => {
            let x = state.x.clone();
            let model = solver.model();
            let step = listening
                .then(|| {
                    crate::warnings::step_above_stable(model, || {
                        softbody_cpu::stable_step::stable_dt_estimate(model, &x)
                    })
                })
                .flatten();
            for w in crate::warnings::inside_terrain(model, &x)
                .into_iter()
                .chain(step)
            {
                notice(Notice::Warning(w.to_string()));
            }
        }
        Err(e) => return failed(RunError::from(e).into(), scene),
    }

    let dir = path.map(Checkpoints::dir_for);
    let mut checkpoints = None;
    if let (Some(plan), Some(dir)) = (request.checkpoint, &dir) {
        let opened = if plan.resume {
            match Checkpoints::resume(dir, plan.every, solver.as_mut()) {
                Ok(Some(c)) => {
                    notice(Notice::Resuming {
                        after_frame: c.resumed_frames().saturating_sub(1),
                        dir: dir.clone(),
                    });
                    Ok(Some(c))
                }
                Ok(None) => {
                    notice(Notice::NoCheckpoint(dir.clone()));
                    plan.every
                        .map(|every| Checkpoints::create(dir, every, solver.as_mut()))
                        .transpose()
                }
                Err(e) => Err(e),
            }
        } else {
            plan.every
                .map(|every| Checkpoints::create(dir, every, solver.as_mut()))
                .transpose()
        };
        match opened {
            Ok(c) => checkpoints = c,
            Err(e) => return failed(e.into(), scene),
        }
    }

    let mut tee = Tee {
        output: output.as_mut().map(Output::sink),
        observer,
        frames: 0,
    };
    let started = Instant::now();
    let never = AtomicBool::new(false);
    let result = crate::run::run_until(
        solver.as_mut(),
        Some(SceneFile {
            path: &loaded.path,
            text: &loaded.text,
        }),
        &mut tee,
        &mut |done, all| {
            if let Some(hear) = progress.as_deref_mut() {
                hear(done, all);
            }
        },
        stop.unwrap_or(&never),
        checkpoints.as_mut(),
    );
    let seconds = started.elapsed().as_secs_f64();
    // The tee's borrows of the output end here, before the output is committed.
    let frames = tee.frames;

    // A checkpoint refused while its frames were read (damaged, or of another version) gave
    // the output frames that are not to be kept, and is left as it was.
    let refused = matches!(&result, Err(RunError::Checkpoint(c)) if c.is_bad_input());
    let keep = match &result {
        Ok(_) => true,
        Err(RunError::Io(_)) => false,
        Err(e) => !refused && !e.is_bad_input() && frames > 0,
    };
    let mut result = result.map_err(RunFailure::from);
    let mut kept = false;
    if let Some(output) = output
        && keep
    {
        match output.commit() {
            Ok(()) => kept = true,
            Err(e) => result = Err(e.into()),
        }
    }
    let ended = matches!(&result, Ok(_) | Err(RunFailure::Run(RunError::Unstable(_))))
        || matches!(&result, Err(RunFailure::Run(e)) if e.is_bad_input());
    let mut checkpoint = None;
    if let Some(c) = checkpoints {
        if refused {
            // Left alone, and not named: it is not one to go on from.
        } else if ended {
            if let Err(e) = c.remove()
                && result.is_ok()
            {
                result = Err(e.into());
            }
        } else {
            checkpoint = Some(c.dir().to_owned());
        }
    }
    Outcome {
        result,
        scene,
        frames,
        kept,
        checkpoint,
        device,
        seconds,
    }
}

/// Refuses checkpointing a run to `path` unless it is absent, a regular file or a directory (a
/// series' destination): a device or a FIFO has no directory of its own to keep a checkpoint
/// beside (`/dev/null.checkpoint` would go into `/dev`).
fn checkpointable(path: &Path) -> Result<(), String> {
    // What cannot be looked at, `Output::create` refuses with its own reason.
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(());
    };
    if meta.is_file() || meta.is_dir() {
        return Ok(());
    }
    #[cfg(unix)]
    let what = {
        use std::os::unix::fs::FileTypeExt;
        let kind = meta.file_type();
        if kind.is_char_device() {
            "a character device"
        } else if kind.is_block_device() {
            "a block device"
        } else if kind.is_fifo() {
            "a FIFO"
        } else if kind.is_socket() {
            "a socket"
        } else {
            "a special file"
        }
    };
    #[cfg(not(unix))]
    let what = "a special file";
    let path = path.display();
    Err(format!(
        "cannot checkpoint a run to {path}: it is {what}, not a regular file (the checkpoint \
         goes beside the output, in {path}.checkpoint)"
    ))
}

/// The destination's sink and the observer, each given every frame; counts the frames.
struct Tee<'a, 'b> {
    output: Option<&'a mut (dyn FrameSink + 'a)>,
    observer: Option<&'a mut (dyn FrameSink + 'b)>,
    frames: u64,
}

impl FrameSink for Tee<'_, '_> {
    fn header(&mut self, header: &Header) -> std::io::Result<()> {
        self.take_header(header.clone())
    }

    fn take_header(&mut self, header: Header) -> std::io::Result<()> {
        match (&mut self.output, &mut self.observer) {
            (Some(output), Some(observer)) => {
                observer.header(&header)?;
                output.take_header(header)
            }
            (Some(output), None) => output.take_header(header),
            (None, Some(observer)) => observer.take_header(header),
            (None, None) => Ok(()),
        }
    }

    fn frame(&mut self, frame: &Frame<'_>) -> std::io::Result<()> {
        if let Some(observer) = &mut self.observer {
            observer.frame(frame)?;
        }
        if let Some(output) = &mut self.output {
            output.frame(frame)?;
        }
        self.frames += 1;
        Ok(())
    }

    /// The destination's sink is finished as it is committed, the observer by its owner.
    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }

    fn wants_springs(&self) -> bool {
        self.output.as_ref().is_some_and(|s| s.wants_springs())
            || self.observer.as_ref().is_some_and(|s| s.wants_springs())
    }
}

#[cfg(test)]
mod tests {
    //! The keep rule, one outcome a test: what is at the destination and the checkpoint after.
    use std::sync::atomic::Ordering;

    use super::*;

    const JELLY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/jelly-on-ground.toml");

    fn request(scene: SceneSource, out: &Path, checkpoint: bool) -> RunRequest {
        RunRequest {
            scene,
            settings: vec!["simulation.duration=0.2".parse().unwrap()],
            backend: Backend::Cpu,
            threads: Some(1),
            destination: Destination::File {
                format: Format::Jsonl,
                path: out.to_owned(),
            },
            checkpoint: checkpoint.then_some(CheckpointPlan {
                every: Some(1),
                resume: false,
            }),
            controls: None,
        }
    }

    fn lines(path: &Path) -> usize {
        std::fs::read_to_string(path).map_or(0, |t| t.lines().count())
    }

    #[test]
    fn a_completed_run_is_kept_and_its_checkpoint_removed() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("jelly.jsonl");
        let outcome = execute(
            &request(SceneSource::File(JELLY.into()), &out, true),
            Hooks::default(),
        );
        let summary = outcome.result.as_ref().unwrap();
        assert_eq!(outcome.class(), ExitClass::Done);
        assert!(outcome.kept);
        assert_eq!(outcome.frames, summary.frames);
        assert_eq!(lines(&out) as u64, 1 + summary.frames);
        assert_eq!(outcome.checkpoint, None);
        assert!(!Checkpoints::dir_for(&out).exists());
    }

    #[test]
    fn an_unstable_run_keeps_the_frames_before_it_and_removes_its_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("unstable.jsonl");
        let scene = SceneSource::Text {
            text: crate::run::tests::UNSTABLE_CUBE.into(),
            origin: dir.path().join("unstable.toml"),
        };
        let mut request = request(scene, &out, true);
        request.settings.clear();
        let outcome = execute(&request, Hooks::default());
        assert_eq!(outcome.class(), ExitClass::Unstable, "{:?}", outcome.result);
        assert!(outcome.kept && outcome.frames > 0);
        assert_eq!(lines(&out) as u64, 1 + outcome.frames);
        assert!(!Checkpoints::dir_for(&out).exists());
    }

    #[test]
    fn a_stopped_run_keeps_its_frames_and_its_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("stopped.jsonl");
        let stop = AtomicBool::new(false);
        let outcome = execute(
            &request(SceneSource::File(JELLY.into()), &out, true),
            Hooks {
                progress: Some(&mut |done, _| {
                    if done > 1000 {
                        stop.store(true, Ordering::Relaxed);
                    }
                }),
                stop: Some(&stop),
                ..Hooks::default()
            },
        );
        assert_eq!(outcome.class(), ExitClass::Stopped, "{:?}", outcome.result);
        assert!(outcome.kept && outcome.frames > 0);
        assert_eq!(lines(&out) as u64, 1 + outcome.frames);
        let kept = Checkpoints::dir_for(&out);
        assert_eq!(outcome.checkpoint.as_deref(), Some(kept.as_path()));
        assert!(kept.join("frames").exists());
    }

    /// A sink that fails at its third frame, as a full disk would.
    struct FailsAtThirdFrame(u64);

    impl FrameSink for FailsAtThirdFrame {
        fn header(&mut self, _: &Header) -> std::io::Result<()> {
            Ok(())
        }
        fn frame(&mut self, _: &Frame<'_>) -> std::io::Result<()> {
            self.0 += 1;
            if self.0 == 3 {
                return Err(std::io::Error::other("the disk is full"));
            }
            Ok(())
        }
        fn finish(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_run_whose_frames_cannot_be_written_leaves_the_destination_and_keeps_its_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("full.jsonl");
        std::fs::write(&out, "the previous run\n").unwrap();
        let mut failing = FailsAtThirdFrame(0);
        let outcome = execute(
            &request(SceneSource::File(JELLY.into()), &out, true),
            Hooks {
                observer: Some(&mut failing),
                ..Hooks::default()
            },
        );
        assert_eq!(outcome.class(), ExitClass::Output, "{:?}", outcome.result);
        assert!(!outcome.kept);
        let message = outcome.result.as_ref().unwrap_err().message();
        assert!(
            message.ends_with("cannot write frames: the disk is full"),
            "{message}"
        );
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "the previous run\n");
        assert!(outcome.checkpoint.is_some_and(|c| c.exists()));
    }

    #[test]
    fn a_refused_scene_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("refused.jsonl");
        // Refused by its settings before anything opens, and by its energy before a frame.
        for setting in ["body[0].mass=-1", "body[0].velocity=[1e200, 0.0, 0.0]"] {
            let mut request = request(SceneSource::File(JELLY.into()), &out, true);
            request.settings.push(setting.parse().unwrap());
            let outcome = execute(&request, Hooks::default());
            assert_eq!(
                outcome.class(),
                ExitClass::BadInput,
                "{setting}: {:?}",
                outcome.result
            );
            assert!(!outcome.kept && outcome.frames == 0 && outcome.checkpoint.is_none());
            assert!(!out.exists(), "{setting}");
            assert!(!Checkpoints::dir_for(&out).exists(), "{setting}");
        }
    }

    #[test]
    fn checkpoints_need_a_file() {
        let mut request = request(SceneSource::File(JELLY.into()), Path::new("x"), true);
        request.destination = Destination::Stdout(Format::Jsonl);
        let outcome = execute(&request, Hooks::default());
        assert_eq!(outcome.class(), ExitClass::BadInput);
    }

    /// The header records the scene that ran: the file's text with the settings written in.
    #[test]
    fn the_header_holds_the_text_of_the_scene_that_ran() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("jelly.jsonl");
        let request = request(SceneSource::File(JELLY.into()), &out, false);
        assert!(execute(&request, Hooks::default()).result.is_ok());
        let header: serde_json::Value = serde_json::from_str(
            std::fs::read_to_string(&out)
                .unwrap()
                .lines()
                .next()
                .unwrap(),
        )
        .unwrap();
        let text = header["scene_text"].as_str().unwrap();
        let loaded = load(&request.scene, &request.settings).unwrap();
        assert_eq!(text, loaded.text);
        assert_eq!(loaded.scene.simulation.duration, 0.2);
        let again = Scene::from_toml(text, Path::new(JELLY)).unwrap();
        assert_eq!(again, loaded.scene);
    }
}
