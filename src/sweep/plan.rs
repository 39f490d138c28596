//! A sweep's plan: each run's parameter set, from a [grid] (every combination), a list of
//! [[runs]], or [random] draws from a seeded PCG-64 — a function of the file alone, so every
//! worker that reads it agrees on which run gets which values.

use rand::{RngExt, SeedableRng};
use serde::Deserialize;
use softbody_scene::KeyPath;

use super::Parameters;
use crate::Setting;

/// The `[random]` table as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RandomFile {
    runs: usize,
    seed: u64,
    parameters: toml::Table,
}

pub(super) fn key(name: &str) -> KeyPath {
    KeyPath::root().key(name)
}

/// A table of `key path = value` pairs as parameters, each key checked.
pub(super) fn parameters(
    table: &toml::Table,
    at: &KeyPath,
) -> Result<Parameters, (KeyPath, String)> {
    table
        .iter()
        .map(|(k, v)| match Setting::new(k, v.clone()) {
            Ok(_) => Ok((k.clone(), v.clone())),
            Err(e) => Err((at.key(k), e)),
        })
        .collect()
}

/// Every combination of the grid's values, the last key varying fastest.
pub(super) fn grid_runs(grid: &toml::Table) -> Result<Vec<Parameters>, (KeyPath, String)> {
    let mut axes = Vec::new();
    for (k, v) in grid {
        let at = key("grid").key(k);
        Setting::new(k, v.clone()).map_err(|e| (at.clone(), e))?;
        match v {
            toml::Value::Array(values) if !values.is_empty() => axes.push((k, values)),
            _ => {
                return Err((
                    at,
                    "a grid parameter takes a non-empty list of values".into(),
                ));
            }
        }
    }
    let mut runs: Vec<Parameters> = vec![Vec::new()];
    for (k, values) in axes {
        runs = runs
            .into_iter()
            .flat_map(|run| {
                values.iter().map(move |v| {
                    let mut run = run.clone();
                    run.push((k.clone(), v.clone()));
                    run
                })
            })
            .collect();
    }
    Ok(runs)
}

/// `runs` parameter sets drawn from the seeded generator, run by run, key by key (sorted).
pub(super) fn random_runs(random: &RandomFile) -> Result<Vec<Parameters>, (KeyPath, String)> {
    enum Draw<'a> {
        Uniform(f64, f64),
        LogUniform(f64, f64),
        Choice(&'a [toml::Value]),
    }
    let mut draws = Vec::new();
    for (k, v) in &random.parameters {
        let at = key("random").key("parameters").key(k);
        Setting::new(k, toml::Value::Integer(0)).map_err(|e| (at.clone(), e))?;
        let bad = || {
            (
                at.clone(),
                "a random parameter is { uniform = [lo, hi] }, { log_uniform = [lo, hi] } (0 < \
                 lo) or { choice = [a, b, …] }"
                    .to_owned(),
            )
        };
        let range = |v: &toml::Value| -> Option<(f64, f64)> {
            let a = v.as_array()?;
            let num = |x: &toml::Value| x.as_float().or_else(|| x.as_integer().map(|i| i as f64));
            match a.as_slice() {
                [lo, hi] => {
                    let (lo, hi) = (num(lo)?, num(hi)?);
                    (lo.is_finite() && hi.is_finite() && lo <= hi).then_some((lo, hi))
                }
                _ => None,
            }
        };
        let table = v.as_table().filter(|t| t.len() == 1).ok_or_else(bad)?;
        let (kind, arg) = table.iter().next().expect("one entry");
        let draw = match kind.as_str() {
            "uniform" => range(arg).map(|(lo, hi)| Draw::Uniform(lo, hi)),
            "log_uniform" => range(arg)
                .filter(|(lo, _)| *lo > 0.0)
                .map(|(lo, hi)| Draw::LogUniform(lo, hi)),
            "choice" => arg
                .as_array()
                .filter(|a| !a.is_empty())
                .map(|a| Draw::Choice(a)),
            _ => None,
        };
        draws.push((k, draw.ok_or_else(bad)?));
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(random.seed);
    let runs = (0..random.runs)
        .map(|_| {
            draws
                .iter()
                .map(|(k, draw)| {
                    let value = match draw {
                        Draw::Uniform(lo, hi) => {
                            toml::Value::Float(lo + (hi - lo) * rng.random::<f64>())
                        }
                        Draw::LogUniform(lo, hi) => {
                            let (a, b) = (lo.ln(), hi.ln());
                            toml::Value::Float((a + (b - a) * rng.random::<f64>()).exp())
                        }
                        Draw::Choice(values) => values[rng.random_range(0..values.len())].clone(),
                    };
                    ((*k).clone(), value)
                })
                .collect()
        })
        .collect();
    Ok(runs)
}
