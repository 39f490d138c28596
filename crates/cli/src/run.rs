//! `softbody run`: run a scene and write its frames.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Args;
use softbody::output::Format;
use softbody::service::{
    self, CheckpointPlan, Destination, ExitClass, Hooks, Notice, RunRequest, SceneSource,
};
use softbody::{Backend, Overrides};

use crate::args::StepOverrides;
use crate::{Failure, bad_input, output_stem, progress, run_failure, status};

#[derive(Args)]
pub struct RunArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Output file (the .pvd for vtk, a directory for ply and obj: NAME.ply and NAME.obj name
    /// the directory NAME); `-` writes to standard output (single-file formats). An existing
    /// file is replaced (a link is followed, a device or FIFO written in place). Default:
    /// out/{name}.{extension}, or the directory out/{name}-ply or -obj, where {name} is the
    /// scene file's stem followed by the overrides and a GPU backend (jelly-rk4-dt0.0001-gpu).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Output format: jsonl, csv, npz, vtk, ply or obj; default from the --out extension
    /// (.jsonl, .csv, .npz, .pvd, .ply, .obj; another extension needs --format), else jsonl.
    #[arg(long)]
    format: Option<Format>,
    /// CPU threads (default: all cores).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..), allow_negative_numbers = true)]
    threads: Option<u16>,
    /// Solver backend: cpu (f64) or gpu (wgpu compute shaders, f32).
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    /// Checkpoint the run every N frames (a directory beside the output, `<out>.checkpoint`,
    /// journaling the frames): a run killed in any way (SIGKILL, a power cut) goes on from its
    /// last checkpoint with --resume. The checkpoint is removed when the run ends, unless a
    /// signal or a failure stopped it. The output must be a regular file (or a series'
    /// directory), and one checkpointing process at a time writes it (<out>.lock).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    checkpoint_every: Option<u64>,
    /// Go on from the output's checkpoint (see --checkpoint-every), which must be of the same
    /// scene, overrides and backend; the frames are those of an uninterrupted run, byte for
    /// byte. Without a checkpoint the run starts from the beginning.
    #[arg(long)]
    resume: bool,
    /// No progress bar and no summary.
    #[arg(long, short)]
    quiet: bool,
    // Last: the heading applies to every option after it.
    #[command(flatten, next_help_heading = "Overrides of the scene")]
    overrides: StepOverrides,
}

pub fn run(args: RunArgs) -> Result<(), Failure> {
    let signals = Signals::register()?;
    let overrides: Overrides = (&args.overrides).into();
    let format = Format::for_output(args.format, args.out.as_deref()).map_err(bad_input)?;
    let to_stdout = args.out.as_deref() == Some(Path::new("-"));
    let out_path = match &args.out {
        Some(p) => p.clone(),
        None => format.default_path(&output_stem(
            &args.scene,
            args.overrides.sets(),
            &overrides,
            args.backend,
        )),
    };
    let request = RunRequest {
        scene: SceneSource::File(args.scene.clone()),
        settings: args.overrides.settings(),
        backend: args.backend,
        threads: args.threads.map(usize::from),
        destination: if to_stdout {
            Destination::Stdout(format)
        } else {
            Destination::File {
                format,
                path: out_path.clone(),
            }
        },
        checkpoint: (args.checkpoint_every.is_some() || args.resume).then_some(CheckpointPlan {
            every: args.checkpoint_every,
            resume: args.resume,
        }),
        controls: None,
    };

    let mut bar = None;
    let quiet = args.quiet;
    let outcome = service::execute(
        &request,
        Hooks {
            observer: None,
            progress: Some(&mut |done, all| {
                bar.get_or_insert_with(|| progress::bar(all, "steps", quiet))
                    .set_position(done)
            }),
            stop: Some(&signals.stop),
            // Warnings are said even with --quiet: they are about the results, not the
            // progress.
            notice: Some(&mut |notice| match notice {
                Notice::Warning(w) => say!("warning: {w}"),
                Notice::Resuming { after_frame, dir } if !quiet => {
                    say!("resuming after frame {after_frame} from {}", dir.display())
                }
                Notice::NoCheckpoint(dir) if !quiet => say!(
                    "no checkpoint in {}: starting from the beginning",
                    dir.display()
                ),
                _ => {}
            }),
        },
    );
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let where_ = if to_stdout {
        "standard output".to_owned()
    } else {
        out_path.display().to_string()
    };
    let integrator = outcome.integrator();
    match outcome.result {
        Ok(summary) => {
            if !args.quiet {
                let seconds = outcome.seconds;
                say!(
                    "{} frames, {} steps of {} on {} in {seconds:.2} s ({} steps/s): {where_}",
                    summary.frames,
                    summary.steps,
                    integrator.map_or("?", |i| i.name()),
                    outcome.device,
                    progress::whole(summary.steps as f64 / seconds.max(1e-9)),
                );
            }
            Ok(())
        }
        Err(e) => {
            let resumable = outcome.checkpoint.as_ref().map_or(String::new(), |dir| {
                format!(
                    "; the checkpoint is in {}: go on with --resume",
                    dir.display()
                )
            });
            let kept = if outcome.kept {
                format!("the frames before it are in {where_}{resumable}")
            } else {
                format!("nothing was written to {where_}{resumable}")
            };
            let began = outcome.frames > 0 || outcome.checkpoint.is_some();
            let mut failure = run_failure(e, integrator, &kept, began);
            if failure.status == ExitClass::Stopped.status()
                && signals.terminated.load(Ordering::Relaxed)
            {
                failure.status = status::TERMINATED;
            }
            Err(failure)
        }
    }
}

/// SIGINT (Ctrl-C) and SIGTERM (`kill`) stop a run (or a sweep's runs) after its complete
/// frames instead of killing it mid-write: the first sets `stop`, which the run looks at every
/// few hundred steps;
/// a second ends the process at once (status 128 + the signal), leaving its staged files to the
/// next run to the same destination to remove.
pub(crate) struct Signals {
    pub(crate) stop: Arc<AtomicBool>,
    /// SIGTERM was the signal (status 143 rather than 130).
    pub(crate) terminated: Arc<AtomicBool>,
}

impl Signals {
    pub(crate) fn register() -> Result<Signals, Failure> {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let signals = Signals {
            stop: Arc::new(AtomicBool::new(false)),
            terminated: Arc::new(AtomicBool::new(false)),
        };
        for signal in [SIGINT, SIGTERM] {
            // In this order: the shutdown looks at the flag the first signal set.
            signal_hook::flag::register_conditional_shutdown(
                signal,
                128 + signal,
                Arc::clone(&signals.stop),
            )?;
            signal_hook::flag::register(signal, Arc::clone(&signals.stop))?;
        }
        signal_hook::flag::register(SIGTERM, Arc::clone(&signals.terminated))?;
        Ok(signals)
    }
}
