//! `softbody run`: run a scene and write its frames.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use softbody::output::{Format, Output, OutputError};
use softbody::run::RunError;
use softbody::{Backend, Integrator};

use crate::{Failure, bad_input, load, non_negative, open_failure, positive, progress, status};

#[derive(Args)]
pub struct RunArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Integrator: explicit-euler, symplectic-euler, midpoint, rk4 or implicit-euler.
    #[arg(long)]
    integrator: Option<Integrator>,
    /// Time step, seconds.
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    dt: Option<f64>,
    /// Simulated time, seconds.
    #[arg(long, value_parser = non_negative, allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Frames per simulated second.
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    fps: Option<f64>,
    /// Output file (the .pvd for vtk, a directory for ply and obj); `-` writes to standard
    /// output (single-file formats). Default: out/{scene file stem}.{extension}, or the
    /// directory out/{scene file stem} for ply and obj.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Output format: jsonl, csv, npz, vtk, ply or obj; default from the --out extension
    /// (.csv, .npz, .pvd), else jsonl.
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
}

pub fn run(args: RunArgs) -> Result<(), Failure> {
    let mut scene = load(&args.scene)?;
    let sim = &mut scene.simulation;
    if let Some(i) = args.integrator {
        sim.integrator = i;
    }
    if let Some(dt) = args.dt {
        sim.dt = dt;
    }
    if let Some(d) = args.duration {
        sim.duration = d;
    }
    if let Some(fps) = args.fps {
        sim.frame_rate = fps;
    }
    scene.validate().map_err(|e| {
        bad_input(anyhow::anyhow!(
            "{}: {}: {} (with the command-line overrides)",
            args.scene.display(),
            e.key,
            e.message
        ))
    })?;

    let format = args
        .format
        .or_else(|| args.out.as_deref().and_then(Format::from_path))
        .unwrap_or_default();
    let to_stdout = args.out.as_deref() == Some(Path::new("-"));
    let out_path = match &args.out {
        Some(p) => p.clone(),
        None => {
            let stem = args
                .scene
                .file_stem()
                .map_or("frames".into(), |s| s.to_string_lossy());
            format.default_path(&stem)
        }
    };
    // Refused before the run rather than after it.
    if to_stdout && format.is_series() {
        return Err(bad_input(OutputError::Stdout(format)));
    }

    let mut solver = softbody::open(&scene, args.backend, args.threads.map(usize::from))
        .map_err(open_failure)?;

    // The library stages the frames beside the destination and puts them in place at commit
    // (see `softbody::output::destination`).
    let mut output = Output::create(format, (!to_stdout).then_some(out_path.as_path()))
        .map_err(output_failure)?;

    let bar = progress::bar(scene.simulation.steps(), args.quiet);
    let started = Instant::now();
    let result = softbody::run::run(
        solver.as_mut(),
        Some(&args.scene),
        output.sink(),
        &mut |done, _| bar.set_position(done),
    );
    bar.finish_and_clear();
    // Frames that failed to write are discarded (the output is dropped, its staging removed);
    // a run stopped by an instability or a device failure keeps the frames before it.
    if !matches!(result, Err(RunError::Io(_))) {
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
                    "{} frames, {} steps of {} on {} in {seconds:.2} s ({:.0} steps/s): {where_}",
                    summary.frames,
                    summary.steps,
                    scene.simulation.integrator,
                    solver.device(),
                    summary.steps as f64 / seconds.max(1e-9),
                );
            }
            Ok(())
        }
        Err(RunError::Unstable(i)) => Err(Failure {
            status: status::UNSTABLE,
            error: anyhow::anyhow!(
                "{i}; {}\nthe frames before it are in {where_}",
                softbody::Instability::advice(scene.simulation.integrator)
            ),
        }),
        Err(RunError::Device(d)) => Err(Failure {
            status: status::NO_ADAPTER,
            error: anyhow::anyhow!("device failure: {d}\nthe frames before it are in {where_}"),
        }),
        Err(e) => Err(e.into()),
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
