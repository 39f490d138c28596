//! A sweep's plan: each run's parameter set, from a [grid] (every combination), a list of
//! [[runs]], or [random] draws from a seeded PCG-64 — a function of the file alone, so every
//! worker that reads it agrees on which run gets which values.

use rand::{RngExt, SeedableRng};
use serde::Deserialize;
use softbody_scene::KeyPath;

use super::Parameters;
use crate::Setting;

/// The most runs a sweep plans. Its plan is held in memory: a million runs of four random
/// parameters take 422 MB (peak resident, the plan built in 0.5 s), ~100 bytes a value. Larger
/// studies are several sweeps.
pub(super) const MAX_RUNS: usize = 1_000_000;

fn too_many(at: KeyPath, runs: String) -> (KeyPath, String) {
    (
        at,
        format!(
            "the plan has {runs} runs; a sweep has at most {MAX_RUNS}: split it into several \
             sweeps"
        ),
    )
}

/// The key paths given so far in a sweep, by canonical form (`body[00].mass` is `body[0].mass`),
/// to refuse a value given twice.
#[derive(Default, Clone)]
pub(super) struct Keys(Vec<(String, String, &'static str)>);

impl Keys {
    /// Checks `k` (as written in `table`) against the keys given before, and keeps it.
    pub(super) fn add(
        &mut self,
        k: &str,
        setting: &Setting,
        table: &'static str,
        at: &KeyPath,
    ) -> Result<(), (KeyPath, String)> {
        let canonical = setting.key().to_string();
        if let Some((_, written, other)) = self.0.iter().find(|(c, ..)| *c == canonical) {
            let message = if *other == table {
                format!("`{k}` names the same value as `{written}`, given before")
            } else {
                format!("`{k}` is fixed in {other} and varied here: give it in one place")
            };
            return Err((at.clone(), message));
        }
        self.0.push((canonical, k.to_owned(), table));
        Ok(())
    }
}

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

/// A table of `key path = value` pairs as parameters, each key checked against `keys` (those
/// given before) and added to them as given in `name`.
pub(super) fn parameters(
    table: &toml::Table,
    at: &KeyPath,
    name: &'static str,
    keys: &mut Keys,
) -> Result<Parameters, (KeyPath, String)> {
    table
        .iter()
        .map(|(k, v)| {
            let setting = Setting::new(k, v.clone()).map_err(|e| (at.key(k), e))?;
            keys.add(k, &setting, name, &at.key(k))?;
            Ok((k.clone(), v.clone()))
        })
        .collect()
}

/// Every combination of the grid's values, the last key varying fastest; `keys` are those of
/// `set`.
pub(super) fn grid_runs(
    grid: &toml::Table,
    mut keys: Keys,
) -> Result<Vec<Parameters>, (KeyPath, String)> {
    let mut axes = Vec::new();
    for (k, v) in grid {
        let at = key("grid").key(k);
        let setting = Setting::new(k, v.clone()).map_err(|e| (at.clone(), e))?;
        keys.add(k, &setting, "[grid]", &at)?;
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
    let count = axes
        .iter()
        .try_fold(1usize, |n, (_, values)| n.checked_mul(values.len()));
    if count.is_none_or(|n| n > MAX_RUNS) {
        let sizes: Vec<String> = axes.iter().map(|(_, v)| v.len().to_string()).collect();
        return Err(too_many(key("grid"), sizes.join(" × ")));
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

/// `runs` parameter sets drawn from the seeded generator, run by run, key by key (sorted);
/// `keys` are those of `set`.
pub(super) fn random_runs(
    random: &RandomFile,
    mut keys: Keys,
) -> Result<Vec<Parameters>, (KeyPath, String)> {
    if random.runs > MAX_RUNS {
        return Err(too_many(key("random").key("runs"), random.runs.to_string()));
    }
    enum Draw<'a> {
        Uniform(f64, f64),
        LogUniform(f64, f64),
        Choice(&'a [toml::Value]),
    }
    let mut draws = Vec::new();
    for (k, v) in &random.parameters {
        let at = key("random").key("parameters").key(k);
        let setting = Setting::new(k, toml::Value::Integer(0)).map_err(|e| (at.clone(), e))?;
        keys.add(k, &setting, "[random.parameters]", &at)?;
        let bad = || {
            (
                at.clone(),
                "a random parameter is { uniform = [lo, hi] }, { log_uniform = [lo, hi] } (0 < \
                 lo) or { choice = [a, b, …] }"
                    .to_owned(),
            )
        };
        // Draws are lo + (hi − lo)·u: hi − lo must be finite too, or every draw is ±inf.
        let range = |v: &toml::Value| -> Result<(f64, f64), (KeyPath, String)> {
            let num = |x: &toml::Value| x.as_float().or_else(|| x.as_integer().map(|i| i as f64));
            match v.as_array().map(Vec::as_slice) {
                Some([lo, hi]) => match (num(lo), num(hi)) {
                    (Some(lo), Some(hi)) if lo <= hi && (hi - lo).is_finite() => Ok((lo, hi)),
                    (Some(_), Some(_)) => Err((
                        at.clone(),
                        "a range [lo, hi] takes lo ≤ hi, both finite and hi − lo finite".into(),
                    )),
                    _ => Err(bad()),
                },
                _ => Err(bad()),
            }
        };
        let table = v.as_table().filter(|t| t.len() == 1).ok_or_else(bad)?;
        let (kind, arg) = table.iter().next().expect("one entry");
        let draw = match kind.as_str() {
            "uniform" => Some(range(arg).map(|(lo, hi)| Draw::Uniform(lo, hi))?),
            "log_uniform" => Some(range(arg)?)
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
