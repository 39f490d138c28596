//! `softbody`: the command-line tool. Argument parsing, progress and output; the simulation
//! itself lives in the `softbody` library.
//!
//! Exit status: 0 done; 1 the output could not be written; 2 bad input (scene file or
//! arguments, or a scene beyond what `--backend gpu` runs: the adapter's limits);
//! 3 the simulation became unstable (the frames before it are written); 4 `--backend gpu`
//! found no usable GPU adapter, or the device failed during the run (the frames before it are
//! written); 130 / 143 `run` stopped by SIGINT (Ctrl-C) / SIGTERM (the frames before it are
//! written; a second signal ends the process at once).

mod args;
mod bench;
mod check;
mod compare;
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
use softbody::{Integrator, Overrides, Scene, Setting};

/// Exit statuses (documented in the README).
mod status {
    pub const OUTPUT: u8 = 1;
    pub const BAD_INPUT: u8 = 2;
    pub const UNSTABLE: u8 = 3;
    pub const NO_ADAPTER: u8 = 4;
    /// 128 + the signal's number, as a shell reports a process the signal ended.
    pub const INTERRUPTED: u8 = 130;
    pub const TERMINATED: u8 = 143;
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
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // A reader that stops early (`--out - | head`) ends the run quietly, as for any Unix
        // filter.
        Err(f) if is_broken_pipe(&f.error) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("error: {:#}", f.error);
            ExitCode::from(f.status)
        }
    }
}

fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain()
        .filter_map(|c| c.downcast_ref::<std::io::Error>())
        .any(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
}

/// Loads a scene file with the command line's `--set`s and overrides applied: every command
/// that takes them goes through here.
fn load_with(path: &Path, settings: &[Setting], overrides: &Overrides) -> Result<Scene, Failure> {
    let scene = softbody::load_scene(path, settings).map_err(bad_input)?;
    overrides.apply_to(scene, path).map_err(bad_input)
}

/// The text of the scene that runs when `settings` and `overrides` change the file at `path`
/// (for the frames' header); `None` when they change nothing, and the file's text is it.
fn scene_text(
    path: &Path,
    settings: &[Setting],
    overrides: &Overrides,
) -> Result<Option<String>, Failure> {
    let all: Vec<Setting> = settings
        .iter()
        .cloned()
        .chain(overrides.to_settings())
        .collect();
    if all.is_empty() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(path)?;
    let edited = softbody::scene_text(&text, path, &all).map_err(bad_input)?;
    Ok(Some(edited))
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

/// A solver that cannot be opened: no usable GPU (4), a scene the GPU does not run (2), or CPU
/// threads that cannot start (1, as before).
fn open_failure(e: softbody::OpenError) -> Failure {
    let status = match &e {
        softbody::OpenError::Gpu(g) if g.no_usable_gpu() => status::NO_ADAPTER,
        softbody::OpenError::Gpu(_) => status::BAD_INPUT,
        _ => status::OUTPUT,
    };
    Failure {
        status,
        error: e.into(),
    }
}

/// An output that cannot be made: a request that cannot be met (2), else the file system (1).
fn output_failure(e: OutputError) -> Failure {
    if e.is_bad_input() {
        bad_input(e)
    } else {
        e.into()
    }
}

/// A run of `integrator` that stopped early: unstable (3) or a failed device (4), the frames
/// before it kept as `kept` says; or frames that could not be written (1).
fn run_failure(e: RunError, integrator: Integrator, kept: &str) -> Failure {
    match e {
        RunError::Unstable(i) => Failure {
            status: status::UNSTABLE,
            error: anyhow::anyhow!("{i}; {}\n{kept}", softbody::Instability::advice(integrator)),
        },
        RunError::Overflow(_) | RunError::TooLarge(_) => bad_input(e),
        RunError::Stopped { .. } => Failure {
            status: status::INTERRUPTED,
            error: anyhow::anyhow!("{e}\n{kept}"),
        },
        RunError::Device(d) => Failure {
            status: status::NO_ADAPTER,
            error: anyhow::anyhow!("device failure: {d}\n{kept}"),
        },
        RunError::Checkpoint(c) if c.is_bad_input() => bad_input(c),
        RunError::Io(_) | RunError::Checkpoint(_) => e.into(),
    }
}

/// Writes `text` to standard output; a reader that went away early is not an error.
fn emit(text: &str) -> Result<(), Failure> {
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}
