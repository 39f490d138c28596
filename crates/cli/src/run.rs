//! `softbody run`: run a scene and write its frames.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use clap::Args;
use softbody::Backend;
use softbody::output::{Format, FrameSink, Output, WithSceneText};
use softbody::run::RunError;
use softbody::warnings::Warning;

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
    let warnings = softbody::warnings::warnings(solver.model(), &x);
    for w in warnings
        .iter()
        .filter(|w| matches!(w, Warning::InsideTerrain { .. }))
    {
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

    let bar = progress::bar(scene.simulation.steps(), "steps", args.quiet);
    let started = Instant::now();
    let result = softbody::run::run_until(
        solver.as_mut(),
        Some(&args.scene),
        sink,
        &mut |done, _| bar.set_position(done),
        &signals.stop,
    );
    bar.finish_and_clear();
    // Frames that failed to write, a scene refused before its first frame, and a run stopped
    // before it leave nothing (the output is dropped, its staging removed, an existing file
    // untouched); a run stopped by an instability, a device failure or a signal keeps the
    // frames before it.
    let keep = match &result {
        Err(RunError::Io(_) | RunError::Overflow(_)) => false,
        Err(RunError::Stopped { frames, .. }) => *frames > 0,
        _ => true,
    };
    if keep {
        output.commit().map_err(output_failure)?;
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
                format!("the frames before it are in {where_}")
            } else {
                format!("nothing was written to {where_}")
            };
            let mut failure = run_failure(e, scene.simulation.integrator, &kept);
            if signals.terminated.load(Ordering::Relaxed) {
                failure.status = status::TERMINATED;
            }
            Err(failure)
        }
    }
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
