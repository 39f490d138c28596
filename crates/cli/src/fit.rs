//! `softbody fit`: fit scene values to a recorded run by L-BFGS on the run's gradient.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, anyhow};
use clap::Args;
use softbody::Backend;
use softbody::fit::{FitRequest, Iteration};
use softbody::output::Staged;

use crate::args::StepOverrides;
use crate::{Failure, bad_input, emit};

#[derive(Args)]
pub struct FitArgs {
    /// The scene file (TOML): the values to fit start from its own.
    scene: PathBuf,
    /// The recorded run to fit to (.jsonl or .npz written by `softbody run` for the same
    /// particles): the loss is grad's --target-frames.
    #[arg(long, value_name = "FILE")]
    to: PathBuf,
    /// A key to fit, as --set names it (repeatable): body[0].structural.stiffness, …
    #[arg(long, value_name = "KEY", required = true)]
    param: Vec<String>,
    /// Keep a key within (LO, HI) (repeatable; by a change of variables).
    #[arg(long, value_name = "KEY=LO,HI", value_parser = bounds)]
    bounds: Vec<(String, (f64, f64))>,
    /// The most L-BFGS iterations.
    #[arg(long, default_value_t = 30)]
    max_iterations: u64,
    /// Where the fitted scene goes: the input with the fitted values written in.
    #[arg(long)]
    out: PathBuf,
    /// Solver threads of each run (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Solver backend: cpu (gradients have no GPU adjoint yet).
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    // Last: the heading applies to every option after it.
    #[command(flatten, next_help_heading = "Overrides of the scene (as for run)")]
    overrides: StepOverrides,
}

fn bounds(s: &str) -> Result<(String, (f64, f64)), String> {
    let (key, range) = s
        .split_once('=')
        .ok_or_else(|| format!("expected KEY=LO,HI, not {s:?}"))?;
    let (lo, hi) = range
        .split_once(',')
        .ok_or_else(|| format!("expected KEY=LO,HI, not {s:?}"))?;
    let parse = |x: &str| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}"));
    Ok((key.trim().to_owned(), (parse(lo)?, parse(hi)?)))
}

pub fn fit(args: FitArgs) -> Result<(), Failure> {
    if args.backend != Backend::Cpu {
        return Err(bad_input(anyhow!(
            "--backend {}: fits run on the CPU backend only (the GPU has no adjoint yet); use \
             --backend cpu",
            args.backend
        )));
    }
    if args.threads == Some(0) {
        return Err(bad_input(anyhow!("--threads: at least 1")));
    }
    for (key, _) in &args.bounds {
        if !args.param.contains(key) {
            return Err(bad_input(anyhow!(
                "--bounds {key}: not one of the --param keys"
            )));
        }
    }
    let request = FitRequest {
        scene: args.scene.clone(),
        settings: args.overrides.settings(),
        to: args.to.clone(),
        params: args
            .param
            .iter()
            .map(|k| {
                let b = args
                    .bounds
                    .iter()
                    .find(|(key, _)| key == k)
                    .map(|(_, b)| *b);
                (k.clone(), b)
            })
            .collect(),
        max_iterations: args.max_iterations,
        threads: args.threads,
    };
    let report = softbody::fit::fit(&request).map_err(|e| Failure {
        status: e.status(),
        error: e.into(),
    })?;
    let mut out = String::new();
    for it in &report.iterations {
        out += &line(it);
    }
    out += &format!(
        "{} after {} iterations and {} runs: loss {:e}\n",
        report.stopped, report.best.iteration, report.evaluations, report.best.loss
    );
    write_scene(&args.out, &report.scene_text)?;
    out += &format!("the fitted scene is in {}\n", args.out.display());
    emit(&out)
}

fn line(it: &Iteration) -> String {
    let values: Vec<String> = it
        .values
        .iter()
        .map(|(k, v)| match v.as_slice() {
            [x] => format!("{k} = {x}"),
            v => format!("{k} = {v:?}"),
        })
        .collect();
    format!(
        "iteration {:>3}: loss {:e}  {}\n",
        it.iteration,
        it.loss,
        values.join("  ")
    )
}

/// Writes `text` to `path` by a file beside it moved into place (as `run`'s outputs).
fn write_scene(path: &std::path::Path, text: &str) -> Result<(), Failure> {
    let (staged, mut file) = Staged::file(path).map_err(crate::output_failure)?;
    file.write_all(text.as_bytes())
        .and_then(|()| file.flush())
        .with_context(|| format!("cannot write {}", path.display()))?;
    staged.commit().map_err(crate::output_failure)
}
