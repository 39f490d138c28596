//! Fitting scene values to a recorded run: the service behind `softbody fit`.
//!
//! The `--target-frames` loss of [`crate::grad`] is minimised over the chosen keys with
//! argmin's L-BFGS (More–Thuente line search), its gradient from the run's adjoint. The
//! optimiser works on variables u of one scale, so that a stiffness of 2000 N/m and a damping
//! of 25 N·s/m move alike, and that keep each key where the scene accepts it:
//!
//! - a key given bounds (lo, hi): θ = lo + (hi − lo)·σ(u), σ the logistic function, so
//!   dθ/du = (hi − lo)·σ(u)(1 − σ(u)); restitution, whose values are [0, 1], takes (0, 1)
//!   unless given others;
//! - a positive key that cannot change sign (a mass, a stiffness, a damping, drag, a friction
//!   coefficient): θ = θ₀·e^u, dθ/du = θ, so it moves by factors and stays positive;
//! - any other (a centre, a velocity, gravity, or one of the above at 0): θ = s·u with
//!   s = |θ₀| (1 where θ₀ = 0).

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use argmin::core::observers::{Observe, ObserverMode};
use argmin::core::{CostFunction, Error as ArgminError, Executor, Gradient, KV, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;

use crate::grad::{Derivative, GradError, GradRequest, Target, gradient};
use crate::{Setting, scene_text};

/// A fit to make.
#[derive(Debug, Clone)]
pub struct FitRequest {
    /// The scene file.
    pub scene: PathBuf,
    /// Settings applied to it first (`--set` and the overrides), in order.
    pub settings: Vec<Setting>,
    /// The recorded run (`.jsonl` or `.npz` written by `softbody run`).
    pub to: PathBuf,
    /// The keys to fit, with their bounds where given.
    pub params: Vec<(String, Option<(f64, f64)>)>,
    /// The most L-BFGS iterations.
    pub max_iterations: u64,
    /// Threads of each run (all cores if `None`).
    pub threads: Option<usize>,
}

/// One iteration of a fit: the loss and the values there.
#[derive(Debug, Clone, PartialEq)]
pub struct Iteration {
    /// The iteration, from 0 (the start).
    pub iteration: u64,
    /// The loss.
    pub loss: f64,
    /// Each key's value (three numbers for a vector key).
    pub values: Vec<(String, Vec<f64>)>,
}

/// What [`fit`] found.
#[derive(Debug, Clone)]
pub struct FitReport {
    /// The best values and their loss.
    pub best: Iteration,
    /// Every iteration's best so far, in order.
    pub iterations: Vec<Iteration>,
    /// Runs made (forward and backward each), line searches included.
    pub evaluations: u64,
    /// Why L-BFGS stopped.
    pub stopped: String,
    /// The scene text with the best values written in (and the request's settings).
    pub scene_text: String,
}

/// One fitted number: a key's component, its start and its bounds.
#[derive(Debug, Clone)]
struct Variable {
    key: usize,
    component: Option<usize>,
    start: f64,
    bounds: Option<(f64, f64)>,
    /// Fitted in log scale (a positive start of a key that cannot change sign).
    positive: bool,
}

impl Variable {
    fn scale(&self) -> f64 {
        if self.start == 0.0 {
            1.0
        } else {
            self.start.abs()
        }
    }

    /// θ(u) and dθ/du.
    fn value(&self, u: f64) -> (f64, f64) {
        match (self.bounds, self.positive) {
            (Some((lo, hi)), _) => {
                let s = 1.0 / (1.0 + (-u).exp());
                (lo + (hi - lo) * s, (hi - lo) * s * (1.0 - s))
            }
            (None, true) => {
                let theta = self.start * u.exp();
                (theta, theta)
            }
            (None, false) => (self.scale() * u, self.scale()),
        }
    }

    /// u(θ₀).
    fn initial(&self) -> f64 {
        match (self.bounds, self.positive) {
            (Some((lo, hi)), _) => {
                let p = (self.start - lo) / (hi - lo);
                (p / (1.0 - p)).ln()
            }
            (None, true) => 0.0,
            (None, false) => self.start / self.scale(),
        }
    }
}

/// One evaluation: u's bits, the loss, dL/du.
type Evaluation = (Vec<u64>, f64, Vec<f64>);

/// The fitted keys' values for u, as settings after the request's own.
struct Problem<'a> {
    request: &'a FitRequest,
    keys: Vec<(String, bool)>,
    variables: Vec<Variable>,
    /// The last evaluation: argmin asks for the cost and the gradient at one point separately.
    last: Mutex<Option<Evaluation>>,
    evaluations: Mutex<u64>,
}

/// Each key's value (three numbers for a vector key) at u.
fn values(keys: &[(String, bool)], variables: &[Variable], u: &[f64]) -> Vec<(String, Vec<f64>)> {
    keys.iter()
        .enumerate()
        .map(|(k, (name, vector))| {
            let mut v = vec![0.0; if *vector { 3 } else { 1 }];
            for (var, &u) in variables.iter().zip(u).filter(|(var, _)| var.key == k) {
                v[var.component.unwrap_or(0)] = var.value(u).0;
            }
            (name.clone(), v)
        })
        .collect()
}

impl Problem<'_> {
    fn values(&self, u: &[f64]) -> Vec<(String, Vec<f64>)> {
        values(&self.keys, &self.variables, u)
    }

    fn settings(&self, u: &[f64]) -> Result<Vec<Setting>, GradError> {
        let mut settings = self.request.settings.clone();
        for (name, v) in self.values(u) {
            let value = if v.len() == 1 {
                toml::Value::Float(v[0])
            } else {
                toml::Value::Array(v.into_iter().map(toml::Value::Float).collect())
            };
            settings.push(
                Setting::new(&name, value).map_err(|m| GradError::Input(format!("{name}: {m}")))?,
            );
        }
        Ok(settings)
    }

    fn evaluate(&self, u: &[f64]) -> Result<(f64, Vec<f64>), ArgminError> {
        let bits: Vec<u64> = u.iter().map(|x| x.to_bits()).collect();
        if let Some((_, loss, g)) = self
            .last
            .lock()
            .expect("not poisoned")
            .as_ref()
            .filter(|(b, _, _)| *b == bits)
        {
            return Ok((*loss, g.clone()));
        }
        let request = GradRequest {
            scene: self.request.scene.clone(),
            settings: self.settings(u)?,
            wrt: self.keys.iter().map(|(k, _)| k.clone()).collect(),
            target: Target::Frames(self.request.to.clone()),
            threads: self.request.threads,
            ..GradRequest::default()
        };
        let report = gradient(&request)?;
        *self.evaluations.lock().expect("not poisoned") += 1;
        let g = self
            .variables
            .iter()
            .zip(u)
            .map(|(var, &u)| {
                let d = match report.gradient[var.key].1 {
                    Derivative::Scalar(x) => x,
                    Derivative::Vector(v) => v[var.component.unwrap_or(0)],
                };
                d * var.value(u).1
            })
            .collect::<Vec<_>>();
        *self.last.lock().expect("not poisoned") = Some((bits, report.loss, g.clone()));
        Ok((report.loss, g))
    }
}

impl CostFunction for &Problem<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, u: &Vec<f64>) -> Result<f64, ArgminError> {
        self.evaluate(u).map(|(loss, _)| loss)
    }
}

impl Gradient for &Problem<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, u: &Vec<f64>) -> Result<Vec<f64>, ArgminError> {
        self.evaluate(u).map(|(_, g)| g)
    }
}

/// Keeps every iteration's best point.
struct Record {
    keys: Vec<(String, bool)>,
    variables: Vec<Variable>,
    iterations: std::sync::Arc<Mutex<Vec<Iteration>>>,
}

impl<I: State<Param = Vec<f64>, Float = f64>> Observe<I> for Record {
    fn observe_iter(&mut self, state: &I, _kv: &KV) -> Result<(), ArgminError> {
        if let Some(u) = state.get_best_param() {
            self.iterations
                .lock()
                .expect("not poisoned")
                .push(Iteration {
                    // Called once an iteration is done, before the count moves on.
                    iteration: state.get_iter() + 1,
                    loss: state.get_best_cost(),
                    values: values(&self.keys, &self.variables, u),
                });
        }
        Ok(())
    }
}

/// The value of `key` in the scene file with `settings` applied, from its TOML document.
fn current(
    text: &str,
    origin: &Path,
    settings: &[Setting],
    key: &str,
) -> Result<toml::Value, GradError> {
    let edited = scene_text(text, origin, settings)?;
    let doc: toml::Table = edited
        .parse()
        .map_err(|e| GradError::Input(format!("{}: {e}", origin.display())))?;
    let mut node = toml::Value::Table(doc);
    for part in key.split('.') {
        let (name, index) = match part.split_once('[') {
            Some((name, rest)) => (name, rest.trim_end_matches(']').parse::<usize>().ok()),
            None => (part, None),
        };
        let next = node.get(name).cloned();
        node = match (next, index) {
            (Some(toml::Value::Array(items)), Some(i)) => items.get(i).cloned(),
            (Some(v), None) => Some(v),
            _ => None,
        }
        .ok_or_else(|| {
            GradError::Input(format!(
                "--param {key}: the scene file gives it no value to start from; give one with --set {key}=…"
            ))
        })?;
    }
    Ok(node)
}

/// Fits the request's keys to its recorded run.
pub fn fit(request: &FitRequest) -> Result<FitReport, GradError> {
    let text = std::fs::read_to_string(&request.scene).map_err(|cause| {
        GradError::Scene(softbody_scene::SceneError::Io {
            path: request.scene.clone(),
            cause,
        })
    })?;
    let mut keys = Vec::new();
    let mut variables = Vec::new();
    for (k, (key, bounds)) in request.params.iter().enumerate() {
        let value = current(&text, &request.scene, &request.settings, key)?;
        let number = |v: &toml::Value| {
            v.as_float()
                .or_else(|| v.as_integer().map(|i| i as f64))
                .ok_or_else(|| GradError::Input(format!("--param {key}: not a number: {v}")))
        };
        let starts: Vec<f64> = match &value {
            toml::Value::Array(items) => items.iter().map(number).collect::<Result<_, _>>()?,
            v => vec![number(v)?],
        };
        let vector = starts.len() == 3 && matches!(value, toml::Value::Array(_));
        if let Some((lo, hi)) = bounds
            && (lo >= hi || lo.is_nan() || starts.iter().any(|s| *s <= *lo || *s >= *hi))
        {
            return Err(GradError::Input(format!(
                "--bounds {key}={lo},{hi}: the start {starts:?} must lie strictly inside (lo < hi)"
            )));
        }
        let last = key.rsplit('.').next().unwrap_or_default();
        let signed = matches!(last, "center" | "velocity" | "gravity");
        let bounds = match (bounds, last) {
            (None, "restitution" | "body_restitution") => Some((0.0, 1.0)),
            (b, _) => *b,
        };
        for (c, &start) in starts.iter().enumerate() {
            variables.push(Variable {
                key: k,
                component: vector.then_some(c),
                start,
                bounds,
                positive: !signed && start > 0.0,
            });
        }
        keys.push((key.clone(), vector));
    }
    let problem = Problem {
        request,
        keys,
        variables,
        last: Mutex::new(None),
        evaluations: Mutex::new(0),
    };
    let start: Vec<f64> = problem.variables.iter().map(Variable::initial).collect();
    // The start's evaluation first: a bad key or scene is reported as itself, not through
    // the optimiser.
    let (loss0, _) = problem.evaluate(&start).map_err(unwrap_error)?;
    let iterations = std::sync::Arc::new(Mutex::new(vec![Iteration {
        iteration: 0,
        loss: loss0,
        values: problem.values(&start),
    }]));
    // Stop when an iteration gains less than ε² of the starting loss: positions matched to
    // rounding (ε relative) leave squared differences of ε² of their scale, and nothing
    // below that is a fit. No gradient tolerance: its scale is the loss's, which is the user's.
    let solver = LBFGS::new(MoreThuenteLineSearch::new(), 7)
        .with_tolerance_grad(0.0)
        .and_then(|s| s.with_tolerance_cost(loss0 * f64::EPSILON * f64::EPSILON))
        .map_err(|e| GradError::Other(e.to_string()))?;
    let result = Executor::new(&problem, solver)
        .configure(|state| state.param(start.clone()).max_iters(request.max_iterations))
        .add_observer(
            Record {
                keys: problem.keys.clone(),
                variables: problem.variables.clone(),
                iterations: iterations.clone(),
            },
            ObserverMode::Always,
        )
        .run()
        .map_err(unwrap_error)?;
    let state = result.state();
    let best_u = state.get_best_param().cloned().unwrap_or(start);
    let best = Iteration {
        iteration: state.get_iter(),
        loss: state.get_best_cost(),
        values: problem.values(&best_u),
    };
    let settings = problem.settings(&best_u)?;
    let scene_text = scene_text(&text, &request.scene, &settings)?;
    let evaluations = *problem.evaluations.lock().expect("not poisoned");
    Ok(FitReport {
        best,
        iterations: iterations.lock().expect("not poisoned").clone(),
        evaluations,
        stopped: state
            .get_termination_reason()
            .map_or_else(|| "unknown".to_owned(), |r| r.text().to_owned()),
        scene_text,
    })
}

/// The [`GradError`] an evaluation failed with, back from argmin's error.
fn unwrap_error(e: ArgminError) -> GradError {
    match e.downcast::<GradError>() {
        Ok(e) => e,
        Err(e) => GradError::Other(format!("the optimiser stopped: {e}")),
    }
}
