//! `softbody bench`: time the standard benchmark cube at several sizes.

use std::io::Write;

use clap::Args;
use softbody::benchmark::GpuRoute;
use softbody::{Backend, Integrator, Preconditioner};

use crate::args::{positive, time_step};
use crate::{Failure, bad_input, open_failure, progress, status};

#[derive(Args)]
pub struct BenchArgs {
    /// Solver backend: cpu (f64) or gpu (wgpu compute shaders, f32).
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    /// Integrator: explicit-euler, symplectic-euler, midpoint, rk4 or implicit-euler.
    #[arg(long, default_value = "symplectic-euler")]
    integrator: Integrator,
    /// Implicit Euler's CG preconditioner on the CPU: multigrid or block-jacobi (the GPU always
    /// runs block Jacobi).
    #[arg(long, default_value = "multigrid")]
    preconditioner: Preconditioner,
    /// How the GPU finds each particle's springs: auto (the fused stencil on the cube), gather
    /// (the fused step through the spring list), per-spring (forces per spring, then a
    /// gather). Only with --backend gpu.
    #[arg(long, default_value = "auto")]
    gpu_route: GpuRoute,
    /// Cube sizes: n for n³ particles, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "10,22,46,100",
          value_parser = clap::value_parser!(u32).range(2..=1000))]
    sizes: Vec<u32>,
    /// Timed steps per size (default: about 1e7 particle-steps and at least 1 s, at most about
    /// 20 s per size).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// Steps before timing (default: about a quarter of a second, until the rate settles).
    /// With --steps, every run times the same stretch of the cube's motion, as comparisons of
    /// implicit Euler need: its cost per step depends on whether the cube falls or rests.
    #[arg(long)]
    warmup_steps: Option<u64>,
    /// CPU threads (default: all cores).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..), allow_negative_numbers = true)]
    threads: Option<u16>,
    /// Spring stiffness k_s, N/m (default: the standard cube's 2000).
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    stiffness: Option<f64>,
    /// Time step, seconds, e.g. 0.001 or 1/60 (default: half the largest stable
    /// symplectic-Euler step for the size and stiffness).
    #[arg(long, value_parser = time_step, allow_negative_numbers = true)]
    dt: Option<f64>,
    /// Time each size twice, without and with self-contact (every particle checked against
    /// the others; nothing touches), and report the cost of the contact checks.
    #[arg(long)]
    contact: bool,
    /// One JSON object per line and size instead of a table.
    #[arg(long)]
    json: bool,
    /// No progress bar and no summary.
    #[arg(long, short)]
    quiet: bool,
}

pub fn bench(args: BenchArgs) -> Result<(), Failure> {
    use softbody::benchmark::{self, BenchError, Options};
    if args.gpu_route != GpuRoute::Auto && args.backend != Backend::Gpu {
        return Err(bad_input(anyhow::anyhow!(
            "--gpu-route {} needs --backend gpu",
            args.gpu_route.name()
        )));
    }
    let plain = Options {
        backend: args.backend,
        integrator: args.integrator,
        threads: args.threads.map(usize::from),
        steps: args.steps,
        warmup_steps: args.warmup_steps,
        stiffness: args.stiffness.unwrap_or(benchmark::STIFFNESS),
        dt: args.dt,
        self_contact: false,
        preconditioner: args.preconditioner,
        gpu_route: args.gpu_route,
    };
    let with_contact = Options {
        self_contact: true,
        ..plain
    };
    let variants: &[&Options] = if args.contact {
        &[&plain, &with_contact]
    } else {
        &[&plain]
    };
    let started = std::time::Instant::now();
    let mut out = std::io::stdout().lock();
    let mut header = false;
    // The rate of the size's run without contact, for the overhead of the run with it.
    let mut plain_rate = None;
    for (&n, options) in args
        .sizes
        .iter()
        .flat_map(|n| variants.iter().map(move |&o| (n, o)))
    {
        let bar = progress::bar(0, "steps", args.quiet);
        bar.set_message(format!(
            "{n}³ cube{}",
            if options.self_contact {
                ", self-contact"
            } else {
                ""
            }
        ));
        let m = benchmark::measure(n, options, &mut |done, total| {
            bar.set_length(total);
            bar.set_position(done);
        });
        bar.finish_and_clear();
        let m = m.map_err(|e| match e {
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
            format!("{}\n", m.to_json(options))
        } else {
            let mut text = String::new();
            if !header {
                header = true;
                text.push_str(&format!(
                    "{}{} on {} ({}), k_s = {} N/m, kernel {}
",
                    options.integrator,
                    m.preconditioner
                        .map_or(String::new(), |p| format!(" ({p} preconditioner)")),
                    options.backend,
                    m.device,
                    options.stiffness,
                    m.kernel
                ));
                text.push_str(&format!(
                    "{}{:>5} {:>10} {:>11} {:>7} {:>10} {:>8} {:>14} {:>13} {:>9}{}{}\n",
                    if args.contact { "contact " } else { "" },
                    "n",
                    "particles",
                    "springs",
                    "steps",
                    "dt [s]",
                    "seconds",
                    "Mparticle-st/s",
                    "Mspring-st/s",
                    "B/particle",
                    if m.design.is_some() {
                        "  dispatches/step  B/particle-step"
                    } else {
                        ""
                    },
                    if m.cg_iterations_per_step.is_some() {
                        "  CG it/step"
                    } else {
                        ""
                    }
                ));
            }
            let contact = match (args.contact, options.self_contact) {
                (false, _) => String::new(),
                (true, false) => format!("{:<8}", "off"),
                (true, true) => format!("{:<8}", "on"),
            };
            let overhead = match (options.self_contact, plain_rate) {
                (true, Some(rate)) => {
                    format!(
                        "  {:+.1}% time",
                        100.0 * (rate / m.particle_steps_per_s() - 1.0)
                    )
                }
                _ => String::new(),
            };
            text.push_str(&format!(
                "{contact}{:>5} {:>10} {:>11} {:>7} {:>10.3e} {:>8.3} {:>14.3} {:>13.2} {:>9}{}{}{}\n",
                m.n,
                m.particles,
                m.springs,
                m.steps,
                m.dt,
                m.seconds,
                m.particle_steps_per_s() / 1e6,
                m.spring_steps_per_s() / 1e6,
                format!("{:.0}", m.bytes_per_particle),
                m.design.map_or(String::new(), |d| format!(
                    " {:>16.1} {:>16.0}",
                    d.dispatches_per_step, d.bytes_per_particle_step
                )),
                m.cg_iterations_per_step
                    .map_or(String::new(), |c| format!(" {c:>11.1}")),
                overhead
            ));
            text
        };
        plain_rate = (!options.self_contact).then(|| m.particle_steps_per_s());
        match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
            r => r?,
        }
    }
    if !args.quiet {
        let sizes = args.sizes.len();
        say!(
            "{sizes} size{} timed in {:.1} s (setup and warm-up included)",
            if sizes == 1 { "" } else { "s" },
            started.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
