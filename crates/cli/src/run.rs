//! `softbody run`: run a scene and write its frames.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use clap::Args;
use softbody::Backend;
use softbody::checkpoint::Checkpoints;
use softbody::output::{Format, FrameSink, Output, WithSceneText};
use softbody::run::RunError;

use crate::args::StepOverrides;
use crate::{
    Failure, bad_input, load_with, open_failure, output_failure, output_stem, progress,
    run_failure, scene_text, status,
};

#[derive(Args)]
pub struct RunArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Output file (the .pvd for vtk, a directory for ply and obj: NAME.ply and NAME.obj name
    /// the directory NAME); `-` writes to standard output (single-file formats). An existing
    /// file is replaced (a link is followed, a device or FIFO written in place). Default:
    /// out/{name}.{extension}, or the directory out/{name} for ply and obj, where {name} is the
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
    /// signal stopped it.
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
    let overrides = (&args.overrides).into();
    let scene = load_with(&args.scene, args.overrides.settings(), &overrides)?;

    let format = Format::for_output(args.format, args.out.as_deref()).map_err(bad_input)?;
    let to_stdout = args.out.as_deref() == Some(Path::new("-"));
    let checkpointing = args.checkpoint_every.is_some() || args.resume;
    if to_stdout && checkpointing {
        return Err(bad_input(anyhow::anyhow!(
            "--checkpoint-every and --resume need an output file (--out), not standard output"
        )));
    }
    let out_path = match &args.out {
        Some(p) => p.clone(),
        None => format.default_path(&output_stem(
            &args.scene,
            args.overrides.settings(),
            &overrides,
            args.backend,
        )),
    };

    // Before the solver (a GPU takes seconds to open) and the run: a destination that cannot
    // be written is refused first. The library stages the frames beside the destination and
    // puts them in place at commit (see `softbody::output::destination`).
    let mut output = Output::create(format, (!to_stdout).then_some(out_path.as_path()))
        .map_err(output_failure)?;

    let mut solver = softbody::open(&scene, args.backend, args.threads.map(usize::from))
        .map_err(open_failure)?;
    // Said even with --quiet: they are about the results, not the progress. The step's
    // estimate is left to `check`: a run that becomes unstable says so itself, with the step.
    let x = solver
        .state()
        .map_err(|e| {
            run_failure(
                e.into(),
                scene.simulation.integrator,
                "no frame was written",
            )
        })?
        .x
        .clone();
    for w in softbody::warnings::inside_terrain(solver.model(), &x) {
        eprintln!("warning: {w}");
    }

    // The frames' header holds the scene that ran: with --set or overrides, not the file's.
    let text = scene_text(&args.scene, args.overrides.settings(), &overrides)?;
    let mut with_text;
    let sink = match text {
        Some(text) => {
            with_text = WithSceneText::new(output.sink(), text);
            &mut with_text as &mut dyn FrameSink
        }
        None => output.sink(),
    };

    let dir = Checkpoints::dir_for(&out_path);
    let mut checkpoints = match (args.resume, args.checkpoint_every) {
        (true, every) => {
            let resumed = Checkpoints::resume(&dir, every, solver.as_mut())
                .map_err(|e| checkpoint_failure(e, &scene))?;
            match (resumed, every) {
                (Some(c), _) => Some(c),
                (None, Some(every)) => Some(
                    Checkpoints::create(&dir, every, solver.as_mut())
                        .map_err(|e| checkpoint_failure(e, &scene))?,
                ),
                (None, None) => None,
            }
        }
        (false, Some(every)) => Some(
            Checkpoints::create(&dir, every, solver.as_mut())
                .map_err(|e| checkpoint_failure(e, &scene))?,
        ),
        (false, None) => None,
    };
    if args.resume && !args.quiet {
        match &checkpoints {
            Some(c) if c.resumed_frames() > 0 => eprintln!(
                "resuming after frame {} from {}",
                c.resumed_frames() - 1,
                dir.display()
            ),
            _ => eprintln!(
                "no checkpoint in {}: starting from the beginning",
                dir.display()
            ),
        }
    }

    let bar = progress::bar(scene.simulation.steps(), "steps", args.quiet);
    let started = Instant::now();
    let result = softbody::run::run_until(
        solver.as_mut(),
        Some(&args.scene),
        sink,
        &mut |done, _| bar.set_position(done),
        &signals.stop,
        checkpoints.as_mut(),
    );
    bar.finish_and_clear();
    // Frames that failed to write, a scene refused before its first frame, and a run stopped
    // before it leave nothing (the output is dropped, its staging removed, an existing file
    // untouched); a run stopped by an instability, a device failure or a signal keeps the
    // frames before it.
    let keep = match &result {
        Err(RunError::Io(_)) => false,
        Err(e) if e.is_bad_input() => false,
        Err(RunError::Stopped { frames, .. }) => *frames > 0,
        _ => true,
    };
    if keep {
        output.commit().map_err(output_failure)?;
    }
    // A run that ended (completed, diverged) has no use for its checkpoint; one stopped by a
    // signal, a device or a file system can go on from it.
    let mut resumable = String::new();
    if let Some(c) = checkpoints.take() {
        if matches!(result, Ok(_) | Err(RunError::Unstable(_)))
            || result.as_ref().is_err_and(RunError::is_bad_input)
        {
            c.remove().map_err(Failure::from)?;
        } else {
            resumable = format!(
                "; the checkpoint is in {}: go on with --resume",
                c.dir().display()
            );
        }
    }
    let where_ = if to_stdout {
        "standard output".to_owned()
    } else {
        out_path.display().to_string()
    };
    let seconds = started.elapsed().as_secs_f64();
    match result {
        Ok(summary) => {
            if !args.quiet {
                eprintln!(
                    "{} frames, {} steps of {} on {} in {seconds:.2} s ({} steps/s): {where_}",
                    summary.frames,
                    summary.steps,
                    scene.simulation.integrator,
                    solver.device(),
                    progress::whole(summary.steps as f64 / seconds.max(1e-9)),
                );
            }
            Ok(())
        }
        Err(e) => {
            let kept = if keep {
                format!("the frames before it are in {where_}{resumable}")
            } else {
                format!("nothing was written to {where_}{resumable}")
            };
            let mut failure = run_failure(e, scene.simulation.integrator, &kept);
            if signals.terminated.load(Ordering::Relaxed) {
                failure.status = status::TERMINATED;
            }
            Err(failure)
        }
    }
}

/// A checkpoint that cannot be resumed or written, as the run's failures are reported.
fn checkpoint_failure(
    e: softbody::checkpoint::CheckpointError,
    scene: &softbody::Scene,
) -> Failure {
    run_failure(
        e.into(),
        scene.simulation.integrator,
        "no frame was written",
    )
}

/// SIGINT (Ctrl-C) and SIGTERM (`kill`) stop a run after its complete frames instead of
/// killing it mid-write: the first sets `stop`, which the run looks at every few hundred steps;
/// a second ends the process at once (status 128 + the signal), leaving its staged files to the
/// next run to the same destination to remove.
struct Signals {
    stop: Arc<AtomicBool>,
    /// SIGTERM was the signal (status 143 rather than 130).
    terminated: Arc<AtomicBool>,
}

impl Signals {
    fn register() -> Result<Signals, Failure> {
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
