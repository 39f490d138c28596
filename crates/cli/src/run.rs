//! `softbody run`: run a scene and write its frames.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use softbody::output::{self, Format};
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
    /// Output file; `-` writes to standard output. Default: out/{scene file stem}.{format}.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Output format; default from the --out extension, else jsonl.
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

    let format =
        args.format
            .unwrap_or_else(|| match args.out.as_ref().and_then(|p| p.extension()) {
                Some(e) if e == "csv" => Format::Csv,
                Some(e) if e == "npz" => Format::Npz,
                _ => Format::Jsonl,
            });
    let to_stdout = args.out.as_deref() == Some(Path::new("-"));
    let out_path = match &args.out {
        Some(p) => p.clone(),
        None => {
            let stem = args
                .scene
                .file_stem()
                .map_or("frames".into(), |s| s.to_string_lossy());
            PathBuf::from("out").join(format!("{stem}.{}", format.extension()))
        }
    };

    let mut solver = softbody::open(&scene, args.backend, args.threads.map(usize::from))
        .map_err(open_failure)?;

    // Frames go to a temporary file beside the destination, renamed into place when the run
    // ends (completed or stopped by an instability): a failed run leaves nothing half-written.
    let (mut temp, writer): (Option<tempfile::NamedTempFile>, Box<dyn Write>) = if to_stdout {
        (None, Box::new(std::io::stdout().lock()))
    } else {
        let dir = out_path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        // An ordinary file once renamed into place: 0666 less the umask, not a temporary
        // file's 0600.
        let mut builder = tempfile::Builder::new();
        builder.prefix(".softbody-").suffix(".part");
        #[cfg(unix)]
        builder.permissions(
            <std::fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o666),
        );
        let file = builder
            .tempfile_in(dir)
            .with_context(|| format!("cannot write in {}", dir.display()))?;
        let handle = file.reopen()?;
        (Some(file), Box::new(std::io::BufWriter::new(handle)))
    };
    let mut sink = output::sink(format, writer)?;

    let bar = progress::bar(scene.simulation.steps(), args.quiet);
    let started = Instant::now();
    let result = softbody::run::run(
        solver.as_mut(),
        Some(&args.scene),
        sink.as_mut(),
        &mut |done, _| bar.set_position(done),
    );
    bar.finish_and_clear();
    sink.finish().context("cannot write frames")?;
    drop(sink);
    if let Some(file) = temp.take() {
        file.persist(&out_path)
            .with_context(|| format!("cannot write {}", out_path.display()))?;
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
