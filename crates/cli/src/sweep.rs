//! `softbody sweep`: a base scene run many times with values changed, in parallel on the local
//! cores (or, through the Python package, on a Ray cluster), one output per run and a manifest.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::Ordering;
use std::time::Instant;

use clap::Args;
use softbody::service::ExitClass;
use softbody::sweep::{Options, Sweep, SweepError, run_local};

use crate::run::Signals;
use crate::{Failure, bad_input, file_stem, progress, status};

#[derive(Args)]
pub struct SweepArgs {
    /// The sweep file (TOML): the base scene, the parameters to vary, the metrics.
    sweep: PathBuf,
    /// Output directory: runs/run-NNNNNN.<format> and manifest.jsonl. Default: out/{sweep
    /// file stem}. A sweep run again into the same directory skips the runs finished there.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Runs at once (default: all cores divided by the sweep's threads per run).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    workers: Option<u16>,
    /// Run only this Slurm array task's share: with --task-count N the runs i with
    /// i % N == INDEX, else the run INDEX alone ($SLURM_ARRAY_TASK_ID). Its records go to
    /// manifest-task-INDEX.jsonl; a later sweep without --task-index merges them.
    #[arg(long, value_name = "INDEX")]
    task_index: Option<usize>,
    /// The number of array tasks sharing the runs (with --task-index).
    #[arg(long, value_name = "N", requires = "task_index", value_parser = clap::value_parser!(u32).range(1..))]
    task_count: Option<u32>,
    /// Run each run as a task on the Ray cluster at ADDRESS (`auto`, `HOST:6379`,
    /// `ray://HOST:10001`, or `local` for a cluster of this machine) through the Python package
    /// (`pip install ./crates/python ray`); `python3` or $SOFTBODY_PYTHON runs it.
    #[arg(long, value_name = "ADDRESS", conflicts_with_all = ["task_index", "workers"])]
    ray: Option<String>,
    /// With --ray: K runs per Ray task, one after the other (default 1), so that Ray schedules
    /// a task per K runs (for many short runs on a cluster); the same records and files.
    #[arg(long, value_name = "K", requires = "ray", value_parser = clap::value_parser!(u32).range(1..))]
    batch: Option<u32>,
    /// No progress bar and no summary.
    #[arg(long, short)]
    quiet: bool,
}

pub fn sweep(args: SweepArgs) -> Result<(), Failure> {
    let sweep = Sweep::from_file(&args.sweep).map_err(sweep_failure)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("out").join(file_stem(&args.sweep).as_ref()));
    if let Some(address) = &args.ray {
        return ray(&args, address, &out);
    }
    let signals = Signals::register()?;
    let options = Options {
        workers: args.workers.map(usize::from),
        task: args
            .task_index
            .map(|i| (i, args.task_count.map_or(1, |n| n as usize))),
        stop: Some(&signals.stop),
    };
    let bar = progress::bar(0, "runs", args.quiet);
    let started = Instant::now();
    let outcome = run_local(&sweep, &out, &options, &|done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .map_err(sweep_failure)?;
    bar.finish_and_clear();
    let seconds = started.elapsed().as_secs_f64();
    let ran = outcome.ok + outcome.unstable + outcome.invalid + outcome.failed;
    if !args.quiet {
        let manifest = match options.task {
            Some((i, _)) => out.join(format!("manifest-task-{i}.jsonl")),
            None => out.join(softbody::sweep::MANIFEST),
        };
        say!(
            "{} runs ({} finished before): {} ok, {} unstable, {} invalid, {} failed in \
             {seconds:.2} s ({:.2} runs/s): {}",
            outcome.planned,
            outcome.skipped,
            outcome.ok,
            outcome.unstable,
            outcome.invalid,
            outcome.failed,
            ran as f64 / seconds.max(1e-9),
            manifest.display()
        );
    }
    if signals.stop.load(Ordering::Relaxed) {
        let terminated = signals.terminated.load(Ordering::Relaxed);
        return Err(Failure {
            status: if terminated {
                status::TERMINATED
            } else {
                ExitClass::Stopped.status()
            },
            error: anyhow::anyhow!(
                "stopped: {} runs under way were not recorded; run the sweep again to go on",
                outcome.stopped
            ),
        });
    }
    if outcome.failed > 0 {
        return Err(Failure {
            status: status::OUTPUT,
            error: anyhow::anyhow!(
                "{} runs failed (their errors are in the manifest); run the sweep again to \
                 retry them",
                outcome.failed
            ),
        });
    }
    Ok(())
}

fn sweep_failure(e: SweepError) -> Failure {
    if e.is_bad_input() {
        bad_input(e)
    } else {
        e.into()
    }
}

/// The sweep on Ray, by the Python package's executor (Ray's client is Python).
fn ray(args: &SweepArgs, address: &str, out: &std::path::Path) -> Result<(), Failure> {
    let python = std::env::var_os("SOFTBODY_PYTHON").unwrap_or_else(|| "python3".into());
    // Said up front, in words, rather than as the interpreter's ModuleNotFoundError.
    let usable = Command::new(&python)
        .args(["-c", "import softbody, ray"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !usable {
        return Err(bad_input(anyhow::anyhow!(
            "--ray runs the sweep through the Python package, which {} cannot import with Ray: \
             pip install ./crates/python ray (or name another interpreter with SOFTBODY_PYTHON)",
            python.to_string_lossy()
        )));
    }
    let mut command = Command::new(&python);
    command
        .args(["-m", "softbody", "sweep"])
        .arg(&args.sweep)
        .arg("--ray")
        .arg(address)
        .arg("--out")
        .arg(out);
    if let Some(batch) = args.batch {
        command.arg("--batch").arg(batch.to_string());
    }
    if args.quiet {
        command.arg("--quiet");
    }
    let status = command.status().map_err(|e| {
        bad_input(anyhow::anyhow!(
            "--ray runs the sweep through the Python package, but {} cannot start: {e}",
            python.to_string_lossy()
        ))
    })?;
    match status.code() {
        Some(0) => Ok(()),
        // The Python side has said what went wrong; its status is the sweep's.
        Some(code) => std::process::exit(code),
        None => Err(Failure {
            status: status::OUTPUT,
            error: anyhow::anyhow!("the Ray sweep was ended by a signal"),
        }),
    }
}
