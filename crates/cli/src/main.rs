//! `softbody`: the command-line tool. Argument parsing, progress and output; the simulation
//! itself lives in the `softbody` library.
//!
//! Exit status: 0 done; 1 the output could not be written; 2 bad input (scene file or
//! arguments, or a scene beyond what `--backend gpu` runs: the adapter's limits);
//! 3 the simulation became unstable (the frames before it are written); 4 `--backend gpu`
//! found no usable GPU adapter, or the device failed during the run (the frames before it are
//! written).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use softbody::output::{self, Format};
use softbody::run::RunError;
use softbody::{Backend, Integrator, Model, Scene};

/// Exit statuses (documented in the README).
mod status {
    pub const OUTPUT: u8 = 1;
    pub const BAD_INPUT: u8 = 2;
    pub const UNSTABLE: u8 = 3;
    pub const NO_ADAPTER: u8 = 4;
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
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write its frames.
    Run(RunArgs),
    /// Validate a scene and describe it.
    Check(CheckArgs),
    /// Time the standard benchmark cube (the peers' jelly cube) at several sizes.
    Bench(BenchArgs),
}

#[derive(Args)]
struct RunArgs {
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

#[derive(Args)]
struct CheckArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct BenchArgs {
    /// Solver backend: cpu (f64) or gpu (wgpu compute shaders, f32).
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    /// Integrator: explicit-euler, symplectic-euler, midpoint, rk4 or implicit-euler.
    #[arg(long, default_value = "symplectic-euler")]
    integrator: Integrator,
    /// Cube sizes: n for n³ particles, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "10,22,46,100",
          value_parser = clap::value_parser!(u32).range(2..=1000))]
    sizes: Vec<u32>,
    /// Timed steps per size (default: about 1e7 particle-steps, at most about 20 s per size).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// CPU threads (default: all cores).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..), allow_negative_numbers = true)]
    threads: Option<u16>,
    /// Spring stiffness k_s, N/m (default: the standard cube's 2000).
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    stiffness: Option<f64>,
    /// Time step, seconds, e.g. 0.001 or 1/60 (default: half the largest stable
    /// symplectic-Euler step for the size and stiffness).
    #[arg(long, value_parser = positive_or_fraction, allow_negative_numbers = true)]
    dt: Option<f64>,
    /// One JSON object per line and size instead of a table.
    #[arg(long)]
    json: bool,
}

fn positive_or_fraction(s: &str) -> Result<f64, String> {
    match s.split_once('/') {
        Some((a, b)) => {
            let (a, b) = (positive(a.trim())?, positive(b.trim())?);
            positive(&(a / b).to_string()).map_err(|_| format!("`{s}` is not a usable fraction"))
        }
        None => positive(s),
    }
}

fn positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("`{s}` is not a finite number greater than zero")),
    }
}

fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("`{s}` is not a finite number of at least zero")),
    }
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
    let result = match cli.command {
        Command::Run(args) => run(args),
        Command::Check(args) => check(args),
        Command::Bench(args) => bench(args),
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

fn load(path: &Path) -> Result<Scene, Failure> {
    Scene::from_file(path).map_err(bad_input)
}

fn run(args: RunArgs) -> Result<(), Failure> {
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

    let show = !args.quiet && std::io::stderr().is_terminal();
    let total = scene.simulation.steps();
    let bar = if show {
        let bar = indicatif::ProgressBar::new(total);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} steps, {per_sec}, ETA {eta}",
            )
            .expect("static template"),
        );
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let started = Instant::now();
    let result = softbody::run::run(solver.as_mut(), sink.as_mut(), &mut |done, _| {
        bar.set_position(done)
    });
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

fn bench(args: BenchArgs) -> Result<(), Failure> {
    use softbody::benchmark::{self, BenchError, Options};
    let options = Options {
        backend: args.backend,
        integrator: args.integrator,
        threads: args.threads.map(usize::from),
        steps: args.steps,
        stiffness: args.stiffness.unwrap_or(benchmark::STIFFNESS),
        dt: args.dt,
    };
    let mut out = std::io::stdout().lock();
    let mut header = false;
    for &n in &args.sizes {
        let m = benchmark::measure(n, &options).map_err(|e| match e {
            BenchError::Invalid { .. } => bad_input(e),
            BenchError::Open(o) => open_failure(o),
            BenchError::Step {
                source: softbody::StepError::Device(_),
                ..
            } => Failure {
                status: status::NO_ADAPTER,
                error: e.into(),
            },
            BenchError::Step { .. } | BenchError::NotFinite { .. } => Failure {
                status: status::UNSTABLE,
                error: e.into(),
            },
        })?;
        // One write per size, as it completes, so that a long run shows its progress.
        let text = if args.json {
            format!("{}\n", m.to_json(&options))
        } else {
            let mut text = String::new();
            if !header {
                header = true;
                text.push_str(&format!(
                    "{} on {} ({}), k_s = {} N/m\n",
                    options.integrator, options.backend, m.device, options.stiffness
                ));
                text.push_str(&format!(
                    "{:>5} {:>10} {:>11} {:>7} {:>10} {:>8} {:>14} {:>13} {:>9}{}\n",
                    "n",
                    "particles",
                    "springs",
                    "steps",
                    "dt [s]",
                    "seconds",
                    "Mparticle-st/s",
                    "Mspring-st/s",
                    "B/particle",
                    if m.cg_iterations_per_step.is_some() {
                        "  CG it/step"
                    } else {
                        ""
                    }
                ));
            }
            text.push_str(&format!(
                "{:>5} {:>10} {:>11} {:>7} {:>10.3e} {:>8.3} {:>14.3} {:>13.2} {:>9}{}\n",
                m.n,
                m.particles,
                m.springs,
                m.steps,
                m.dt,
                m.seconds,
                m.particle_steps_per_s() / 1e6,
                m.spring_steps_per_s() / 1e6,
                m.bytes_per_particle
                    .map_or("-".to_owned(), |b| format!("{b:.0}")),
                m.cg_iterations_per_step
                    .map_or(String::new(), |c| format!(" {c:>11.1}"))
            ));
            text
        };
        match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
            r => r?,
        }
    }
    Ok(())
}

fn check(args: CheckArgs) -> Result<(), Failure> {
    let scene = load(&args.scene)?;
    // Printed in one write at the end, so that a closed pipe (`| head -1`) is one error to
    // handle instead of a panic in `println!`.
    let mut out = String::new();
    macro_rules! line {
        ($($arg:tt)*) => {{
            out.push_str(&format!($($arg)*));
            out.push('\n');
        }};
    }
    let (model, _) = Model::build(&scene);
    let counts = model.spring_counts;
    let sim = &scene.simulation;
    let stable_dt = model.stable_dt();
    let terrain: Vec<&str> = scene
        .terrain
        .iter()
        .map(|t| terrain_kind(&t.shape))
        .collect();
    if args.json {
        let value = serde_json::json!({
            "particles": model.len(),
            "springs": {
                "structural": counts.structural,
                "shear": counts.shear,
                "bending": counts.bending,
                "total": counts.total(),
            },
            "total_mass": scene.total_mass(),
            "stable_dt": stable_dt,
            "bodies": model.bodies.iter().map(|b| serde_json::json!({"name": b.name, "first": b.first, "count": b.count})).collect::<Vec<_>>(),
            "terrain": terrain,
            "integrator": sim.integrator.name(),
            "dt": sim.dt,
            "steps": sim.steps(),
            "frames": sim.frame_count(),
        });
        line!("{value}");
        return emit(&out);
    }
    line!("{}: valid", args.scene.display());
    line!("  particles   {}", model.len());
    for b in &model.bodies {
        line!("    {:<10} {} particles from {}", b.name, b.count, b.first);
    }
    line!(
        "  springs     {} ({} structural, {} shear, {} bending)",
        counts.total(),
        counts.structural,
        counts.shear,
        counts.bending
    );
    line!("  total mass  {} kg", scene.total_mass());
    line!(
        "  terrain     {}",
        if terrain.is_empty() {
            "none".to_owned()
        } else {
            terrain.join(", ")
        }
    );
    line!(
        "  integrator  {}, dt = {} s, {} steps, {} frames",
        sim.integrator,
        sim.dt,
        sim.steps(),
        sim.frame_count()
    );
    match stable_dt {
        Some(h) => {
            line!(
                "  stable dt   about {h:.3e} s for the explicit integrators (implicit-euler: any)"
            );
            if sim.integrator != Integrator::ImplicitEuler && sim.dt > h {
                line!(
                    "  warning     dt = {} s is above it: expect this run to become unstable",
                    sim.dt
                );
            }
        }
        None => line!("  stable dt   unlimited (no springs)"),
    }
    emit(&out)
}

/// Writes `text` to standard output; a reader that went away early is not an error.
fn emit(text: &str) -> Result<(), Failure> {
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}

fn terrain_kind(shape: &softbody::scene::TerrainShape) -> &'static str {
    use softbody::scene::TerrainShape::*;
    match shape {
        Plane { .. } => "plane",
        Box { .. } => "box",
        Sphere { .. } => "sphere",
        Bowl { .. } => "bowl",
        Heightfield(_) => "heightfield",
        Mesh(_) => "mesh",
    }
}
