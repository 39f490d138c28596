//! `softbody`: the command-line tool. Argument parsing, progress and output; the simulation
//! itself lives in the `softbody` library.
//!
//! Exit status (`softbody::service::ExitClass`): 0 done; 1 the output could not be written
//! (also: another process checkpoints to it, or `<out>.checkpoint` is not a checkpoint);
//! 2 bad input (scene file or arguments, or a scene beyond what `--backend gpu` runs: the
//! adapter's limits); 3 the simulation became unstable (the frames before it are written);
//! 4 `--backend gpu` found no usable GPU adapter, or the device failed during the run (the
//! frames before it are written); 130 / 143 `run` stopped by SIGINT (Ctrl-C) / SIGTERM (the
//! frames before it are written; a second signal ends the process at once).

/// `eprintln!` that does not panic when standard error is gone (a closed pipe, a closed
/// descriptor): the message is lost, the exit status is kept.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

mod args;
mod bench;
mod check;
mod compare;
mod estimate;
mod fit;
mod grad;
mod progress;
mod render;
mod run;
mod sweep;

use std::borrow::Cow;
use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use softbody::output::OutputError;
use softbody::run::RunError;
use softbody::service::RunFailure;
use softbody::{Integrator, Overrides, Scene, Setting};

/// Exit statuses (documented in docs/guide/cli.md): the library's table of outcome classes
/// ([`ExitClass::status`]), and the signal that stopped a run.
mod status {
    use softbody::service::ExitClass;
    pub const OUTPUT: u8 = ExitClass::Output.status();
    pub const BAD_INPUT: u8 = ExitClass::BadInput.status();
    pub const UNSTABLE: u8 = ExitClass::Unstable.status();
    pub const NO_ADAPTER: u8 = ExitClass::Device.status();
    /// 128 + SIGTERM's number, as a shell reports a process the signal ended (a SIGINT's is
    /// `ExitClass::Stopped`'s 130).
    pub const TERMINATED: u8 = 143;
    /// `compare`: the reference is not converged, so no run's error is a measure (the report is
    /// printed all the same).
    pub const UNCONVERGED: u8 = 5;
}

#[derive(Parser)]
#[command(
    name = "softbody",
    version,
    about = "Mass-spring soft bodies: run scenes, write frames"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// GPU adapter to run on (`--backend gpu`), by part of its name, e.g. "H100" or
    /// "llvmpipe"; default: a discrete GPU before an integrated or software one. The same as
    /// setting SOFTBODY_ADAPTER; WGPU_BACKEND chooses the backends.
    #[arg(long, global = true, value_name = "NAME")]
    adapter: Option<String>,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write its frames.
    Run(run::RunArgs),
    /// Validate a scene and describe it.
    Check(check::CheckArgs),
    /// Time the standard benchmark cube (the peers' jelly cube) at several sizes.
    Bench(bench::BenchArgs),
    /// Draw a scene's frames (simulated, or read from a run's .jsonl) as PNG files or a GIF.
    Render(render::RenderArgs),
    /// Run a scene with several integrators and time steps against a converged rk4 reference.
    Compare(compare::CompareArgs),
    /// Run a scene many times with values changed (a grid, a list or random draws), in
    /// parallel, one output per run and a manifest; resumable.
    Sweep(sweep::SweepArgs),
    /// The gradient of a loss over a whole run (CPU, f64) with respect to scene keys.
    Grad(grad::GradArgs),
    /// Fit scene values to a recorded run (L-BFGS on the run's gradient) and write the scene.
    Fit(fit::FitArgs),
}

/// A failure with its exit status.
struct Failure {
    status: u8,
    error: anyhow::Error,
}

impl<E: Into<anyhow::Error>> From<E> for Failure {
    fn from(e: E) -> Self {
        Failure {
            status: status::OUTPUT,
            error: e.into(),
        }
    }
}

fn bad_input(error: impl Into<anyhow::Error>) -> Failure {
    Failure {
        status: status::BAD_INPUT,
        error: error.into(),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(adapter) = &cli.adapter {
        // SAFETY: no other thread runs yet (the solvers' pools, signal handlers and GPU
        // devices are made later), so nothing reads the environment concurrently.
        unsafe { std::env::set_var(softbody::gpu::ADAPTER_VARIABLE, adapter) };
    }
    let result = match cli.command {
        Command::Run(args) => run::run(args),
        Command::Check(args) => check::check(args),
        Command::Bench(args) => bench::bench(args),
        Command::Render(args) => render::render(args),
        Command::Compare(args) => compare::compare(args),
        Command::Sweep(args) => sweep::sweep(args),
        Command::Grad(args) => grad::grad(args),
        Command::Fit(args) => fit::fit(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // A reader that stops early (`--out - | head`) ends the run quietly, as for any Unix
        // filter.
        Err(f) if is_broken_pipe(&f.error) => ExitCode::SUCCESS,
        Err(f) => {
            say!("error: {}", said_once(&f.error));
            ExitCode::from(f.status)
        }
    }
}

/// `e` and its causes, joined by ": ", leaving out a cause whose text is said already: an
/// error that names its cause in its own message and also gives it as its source would say it
/// twice.
fn said_once(e: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if message.is_empty() {
            message = text;
        } else if !message.contains(&text) {
            message = format!("{message}: {text}");
        }
    }
    message
}

fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain()
        .filter_map(|c| c.downcast_ref::<std::io::Error>())
        .any(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
}

/// Loads a scene file with the command line's `--set`s and overrides applied: every command
/// that takes them goes through here.
fn load_with(path: &Path, settings: &[Setting]) -> Result<Scene, Failure> {
    softbody::load_scene(path, settings).map_err(bad_input)
}

/// The stem of an input file, for the default output names.
fn file_stem(path: &Path) -> Cow<'_, str> {
    path.file_stem()
        .map_or("frames".into(), |s| s.to_string_lossy())
}

/// The default output name of a run of the scene file `path` with `overrides` on `backend`:
/// the file's stem, then what differs from the scene's own run (the `--set`s, the overrides, a
/// GPU backend: `jelly-body0.mass2-rk4-dt0.0001-gpu`), so
/// that runs with other settings do not replace each other's frames.
fn output_stem(
    path: &Path,
    settings: &[Setting],
    overrides: &Overrides,
    backend: softbody::Backend,
) -> String {
    let mut parts = vec![file_stem(path).into_owned()];
    parts.extend(settings.iter().map(Setting::label));
    parts.push(overrides.label());
    if backend != softbody::Backend::Cpu {
        parts.push(backend.to_string());
    }
    parts.retain(|p| !p.is_empty());
    parts.join("-")
}

/// A failure of the run service's kinds, with the status of its class.
fn failure(e: impl Into<RunFailure>) -> Failure {
    let e = e.into();
    Failure {
        status: e.class().status(),
        error: e.into(),
    }
}

/// A solver that cannot be opened: no usable GPU (4), a scene the GPU does not run (2), or CPU
/// threads that cannot start (1).
fn open_failure(e: softbody::OpenError) -> Failure {
    failure(e)
}

/// An output that cannot be made: a request that cannot be met (2), else the file system (1).
fn output_failure(e: OutputError) -> Failure {
    failure(e)
}

/// A run of `integrator` that did not complete, with what became of its frames and its
/// checkpoint (`kept`, said after an instability, a device failure, a stop, a failure to write
/// frames, and any failure once the run `began` writing frames or a checkpoint): the advice for
/// an instability, the device for a device failure.
fn run_failure(
    e: impl Into<RunFailure>,
    integrator: Option<Integrator>,
    kept: &str,
    began: bool,
) -> Failure {
    let e = e.into();
    let status = e.class().status();
    let error = match e {
        RunFailure::Run(RunError::Unstable(i)) => {
            let advice = integrator
                .map(softbody::Instability::advice)
                .unwrap_or_default();
            anyhow::anyhow!("{i}; {advice}\n{kept}")
        }
        RunFailure::Run(RunError::Device(d)) => anyhow::anyhow!("device failure: {d}\n{kept}"),
        e @ RunFailure::Run(RunError::Stopped { .. } | RunError::Io(_)) => {
            anyhow::anyhow!("{}\n{kept}", e.message())
        }
        // The output that could not be put in place, the checkpoint that could not be written:
        // the checkpoint kept is what to go on from.
        e if began => anyhow::anyhow!("{}\n{kept}", e.message()),
        e => e.into(),
    };
    Failure { status, error }
}

/// Writes `text` to standard output; a reader that went away early is not an error.
fn emit(text: &str) -> Result<(), Failure> {
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}
