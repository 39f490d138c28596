//! `softbody grad`: the gradient of a loss over a whole run with respect to scene keys.

use std::path::PathBuf;

use anyhow::anyhow;
use clap::Args;
use glam::DVec3;
use softbody::Backend;
use softbody::grad::{Derivative, GradError, GradReport, GradRequest, Target};

use crate::args::StepOverrides;
use crate::{Failure, bad_input, emit};

#[derive(Args)]
pub struct GradArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// A key to differentiate by, as --set names it (repeatable): body[0].structural.stiffness,
    /// body[0].center, simulation.gravity, terrain[0].friction, …
    #[arg(long, value_name = "KEY", required = true)]
    wrt: Vec<String>,
    /// L = |c − target|², c the mass-weighted centre of all particles at the last frame.
    #[arg(long, value_name = "X,Y,Z", value_parser = point, allow_negative_numbers = true,
          conflicts_with = "target_frames", required_unless_present = "target_frames")]
    target_com: Option<DVec3>,
    /// L = (1/(F·N)) Σ |x − x̂|² over the frames of a run of the same particles (.jsonl or
    /// .npz written by `softbody run`) that this run has too.
    #[arg(long, value_name = "FILE")]
    target_frames: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
    /// Solver threads (default: all cores); the gradient's bits do not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Solver backend: cpu (gradients have no GPU adjoint yet).
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    // Last: the heading applies to every option after it.
    #[command(flatten, next_help_heading = "Overrides of the scene (as for run)")]
    overrides: StepOverrides,
}

fn point(s: &str) -> Result<DVec3, String> {
    let parts: Vec<&str> = s.split(',').collect();
    let values: Result<Vec<f64>, _> = parts.iter().map(|p| p.trim().parse::<f64>()).collect();
    match values {
        Ok(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => {
            Ok(DVec3::new(v[0], v[1], v[2]))
        }
        _ => Err(format!("expected three finite numbers X,Y,Z, not {s:?}")),
    }
}

pub fn grad(args: GradArgs) -> Result<(), Failure> {
    if args.backend != Backend::Cpu {
        return Err(bad_input(anyhow!(
            "--backend {}: gradients are computed on the CPU backend only (the GPU has no \
             adjoint yet); use --backend cpu",
            args.backend
        )));
    }
    if args.threads == Some(0) {
        return Err(bad_input(anyhow!("--threads: at least 1")));
    }
    let target = match (&args.target_com, &args.target_frames) {
        (Some(c), _) => Target::Com(*c),
        (None, Some(f)) => Target::Frames(f.clone()),
        (None, None) => unreachable!("clap requires one"),
    };
    let request = GradRequest {
        scene: args.scene.clone(),
        settings: args.overrides.settings(),
        wrt: args.wrt.clone(),
        target,
        threads: args.threads,
        ..GradRequest::default()
    };
    let report = softbody::grad::gradient(&request).map_err(grad_failure)?;
    emit(&if args.json {
        json(&report)
    } else {
        text(&report)
    })
}

fn grad_failure(e: GradError) -> Failure {
    Failure {
        status: e.status(),
        error: e.into(),
    }
}

fn json(report: &GradReport) -> String {
    let gradient: serde_json::Map<String, serde_json::Value> = report
        .gradient
        .iter()
        .map(|(k, d)| {
            let v = match d {
                Derivative::Scalar(x) => serde_json::json!(x),
                Derivative::Vector(v) => serde_json::json!([v.x, v.y, v.z]),
            };
            (k.clone(), v)
        })
        .collect();
    let b = &report.backward;
    let value = serde_json::json!({
        "loss": report.loss,
        "gradient": gradient,
        "steps": b.steps,
        "peak_memory_bytes": b.peak_memory_bytes,
        "forward_seconds": b.forward_seconds,
        "backward_seconds": b.backward_seconds,
        "turned_steps": b.turned_steps,
    });
    format!("{value}\n")
}

fn text(report: &GradReport) -> String {
    let b = &report.backward;
    let mut out = format!("loss {:e}\n", report.loss);
    for (k, d) in &report.gradient {
        match d {
            Derivative::Scalar(x) => out += &format!("d loss / d {k} = {x:e}\n"),
            Derivative::Vector(v) => {
                out += &format!("d loss / d {k} = [{:e}, {:e}, {:e}]\n", v.x, v.y, v.z)
            }
        }
    }
    out += &format!(
        "{} steps, checkpoints every {}; forward {:.3} s, backward {:.3} s (recomputation \
         included); peak memory {:.1} MB\n",
        b.steps,
        b.interval,
        b.forward_seconds,
        b.backward_seconds,
        b.peak_memory_bytes as f64 / 1e6
    );
    if b.turned_steps > 0 {
        out += &format!(
            "{} steps had a contact turn from sticking to slipping: the gradient holds its \
             friction direction there (docs/physics.md, \"Kinks\")\n",
            b.turned_steps
        );
    }
    out
}
