//! What every backend offers: the stepping API the CLI and embedders drive.

use std::fmt;

use crate::controls::Controls;
use crate::model::{Model, State};

/// Energies of a state, joules.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Energies {
    /// ½ Σ m_i |v_i|².
    pub kinetic: f64,
    /// −Σ m_i g·x_i.
    pub gravitational: f64,
    /// ½ Σ k_s (|x_a − x_b| − r)².
    pub elastic: f64,
}

impl Energies {
    /// Kinetic + gravitational + elastic.
    pub fn total(&self) -> f64 {
        self.kinetic + self.gravitational + self.elastic
    }
}

/// The run stopped because the state stopped making physical sense.
#[derive(Debug, Clone, PartialEq)]
pub struct Instability {
    /// The step that produced it (1 is the first step).
    pub step: u64,
    /// Its time, seconds.
    pub time: f64,
    /// The particle it was first seen on.
    pub particle: u32,
    /// What was seen.
    pub what: String,
}

impl fmt::Display for Instability {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the simulation became unstable at step {} (t = {} s): particle {} {}",
            self.step,
            four_digits(self.time),
            self.particle,
            self.what
        )
    }
}

/// `x` to four significant digits, for people (the step says it exactly): 0.1667, 12.35, 2500,
/// 1.235e-5.
fn four_digits(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return x.to_string();
    }
    let magnitude = x.abs().log10().floor() as i32;
    match 3 - magnitude {
        decimals @ 0..=8 => format!("{x:.*}", decimals as usize),
        ..0 => format!("{x:.0}"),
        _ => format!("{x:.3e}"),
    }
}

impl Instability {
    /// What to try next, for a run of `integrator`.
    pub fn advice(integrator: crate::Integrator) -> &'static str {
        match integrator {
            crate::Integrator::ImplicitEuler => "try a smaller dt",
            _ => {
                "try a smaller dt (`softbody check` estimates the largest stable one) or the implicit-euler integrator"
            }
        }
    }
}

/// Why a step (or a read-back) failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StepError {
    /// A non-finite value or runaway energy.
    #[error("{0}")]
    Unstable(Instability),
    /// The device failed (GPU lost, out of memory, ...).
    #[error("device failure: {0}")]
    Device(String),
    /// The request does not fit the solver (a state of the wrong size).
    #[error("{0}")]
    Invalid(String),
}

/// What a solver carries from one step into the next besides the state and the step count:
/// implicit Euler's warm start and contact modes, and on the CPU the positions and
/// constraints its multigrid's kept values were computed from (explicit integrators carry
/// nothing). Given back with the state to [`Solver::restore`], it makes the steps that follow
/// bit-identical to those of the run it was taken from, which is what `softbody run --resume`
/// relies on.
///
/// Its parts are the backend's own named byte arrays: a history is for a solver of the same
/// backend and model only, and [`History::part`] refuses a part that is missing or of the
/// wrong size.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct History {
    /// (name, bytes) in the order the backend listed them.
    pub parts: Vec<(String, Vec<u8>)>,
}

impl History {
    /// Adds a part.
    pub fn push(&mut self, name: &str, bytes: Vec<u8>) {
        self.parts.push((name.to_owned(), bytes));
    }

    /// The bytes of part `name`, which must be `len` long.
    pub fn part(&self, name: &str, len: usize) -> Result<&[u8], StepError> {
        let bytes = self
            .parts
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, b)| b.as_slice())
            .ok_or_else(|| {
                StepError::Invalid(format!("restore: the history has no part `{name}`"))
            })?;
        if bytes.len() != len {
            return Err(StepError::Invalid(format!(
                "restore: the history's `{name}` has {} bytes, this solver needs {len}",
                bytes.len()
            )));
        }
        Ok(bytes)
    }
}

/// Wall-clock time spent in one stage, over a run: what rapier's stage counters report.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Timer {
    /// Seconds in all.
    pub seconds: f64,
    /// Times the stage ran.
    pub calls: u64,
}

/// Per-stage wall-clock timings of a solver, in the order the stages first ran. Each backend
/// names its own stages (the CPU's explicit integrators run spring forces, forces, update and
/// collision response as one fused pass, so that is one stage there); see each solver's
/// documentation for what its stages measure.
///
/// ```
/// use softbody_scene::Timings;
/// let mut t = Timings::default();
/// let x = t.time("assemble", || 6 * 7);
/// t.add("cg", 0.25);
/// t.add("cg", 0.5);
/// assert_eq!(x, 42);
/// assert_eq!(t.get("cg").unwrap().calls, 2);
/// assert_eq!(t.get("cg").unwrap().seconds, 0.75);
/// assert_eq!(t.iter().map(|(stage, _)| stage).collect::<Vec<_>>(), ["assemble", "cg"]);
/// ```
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Timings {
    stages: Vec<(&'static str, Timer)>,
}

impl Timings {
    /// Counts one run of `stage` that took `seconds`.
    pub fn add(&mut self, stage: &'static str, seconds: f64) {
        let timer = match self.stages.iter_mut().find(|(s, _)| *s == stage) {
            Some((_, t)) => t,
            None => {
                self.stages.push((stage, Timer::default()));
                &mut self.stages.last_mut().expect("just pushed").1
            }
        };
        timer.seconds += seconds;
        timer.calls += 1;
    }

    /// Runs `f` as one run of `stage`.
    pub fn time<R>(&mut self, stage: &'static str, f: impl FnOnce() -> R) -> R {
        let started = std::time::Instant::now();
        let result = f();
        self.add(stage, started.elapsed().as_secs_f64());
        result
    }

    /// The timer of `stage`, if it ran.
    pub fn get(&self, stage: &str) -> Option<Timer> {
        self.stages
            .iter()
            .find(|(s, _)| *s == stage)
            .map(|&(_, t)| t)
    }

    /// Every stage that ran, in the order it first ran.
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, Timer)> + '_ {
        self.stages.iter().copied()
    }

    /// Seconds over all stages.
    pub fn total(&self) -> f64 {
        self.stages.iter().map(|(_, t)| t.seconds).sum()
    }
}

impl fmt::Display for Timings {
    /// One line per stage: name, seconds, calls, share of the total.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let total = self.total();
        for (stage, t) in self.iter() {
            let share = if total > 0.0 {
                100.0 * t.seconds / total
            } else {
                0.0
            };
            writeln!(
                f,
                "{stage:<24} {:>10.4} s {:>10} calls {share:>5.1} %",
                t.seconds, t.calls
            )?;
        }
        Ok(())
    }
}

/// Counters a backend keeps over a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Statistics {
    /// Steps taken.
    pub steps: u64,
    /// Conjugate-gradient iterations over all implicit steps.
    pub cg_iterations: u64,
    /// Conjugate-gradient solves (more than one per step when contacts change state).
    pub cg_solves: u64,
    /// Largest relative residual a CG solve ended with.
    pub cg_max_residual: f64,
    /// The preconditioner of the CG solves (implicit Euler on a backend that reports it; the
    /// GPU runs block Jacobi and reports none).
    pub preconditioner: Option<crate::Preconditioner>,
    /// Compute dispatches encoded (a GPU backend; 0 on the CPU).
    pub dispatches: u64,
    /// Bytes of device memory those dispatches move by the design's count: every bound storage
    /// buffer read once, every read-write one also written once (a GPU backend; 0 on the CPU).
    pub device_bytes: u64,
    /// Wall-clock time per stage.
    pub timings: Timings,
    /// How the spring forces are computed: the CPU's route (`stencil-avx512`, `stencil-avx2` or
    /// `stencil`: lattice bodies by their stencil; `sweep-avx2` or `sweep`: springs sorted by their first end, in
    /// one fused sweep; `gather`: every spring into a buffer, then a gather per particle;
    /// `matrix-free-lattice` or `matrix-free` for implicit Euler's system on lattices or by its
    /// spring list), the GPU's kernels.
    pub kernel: &'static str,
}

/// A backend that advances a [`Model`] through time. The CPU and GPU solvers implement it; the
/// CLI, the tests and the benchmarks drive it without knowing which runs.
///
/// A solver may run ahead of its caller (a GPU queues work): [`Solver::advance`] may return
/// before the steps are computed, and [`Solver::sync`] waits for them. Reading the state or the
/// energies waits too.
pub trait Solver: Send {
    /// `"cpu"` or `"gpu"`.
    fn backend(&self) -> &'static str;
    /// What runs it, for headers and logs (thread count, adapter name).
    fn device(&self) -> String;
    /// The model being stepped.
    fn model(&self) -> &Model;
    /// Advances `steps` steps; stops at the first unstable one. A solver that runs ahead
    /// reports an instability here or by the next call that waits for its steps
    /// ([`Solver::sync`], the state, the energies, the history).
    fn advance(&mut self, steps: u64) -> Result<(), StepError>;
    /// Waits until every step asked for has been computed (a no-op where stepping is
    /// synchronous): what a benchmark calls before stopping its clock.
    fn sync(&mut self) -> Result<(), StepError>;
    /// Steps taken since the start.
    fn steps_taken(&self) -> u64;
    /// The current state (a GPU backend reads it back).
    fn state(&mut self) -> Result<&State, StepError>;
    /// Replaces the current state; the step count stays. The state must have one position and
    /// one velocity per particle ([`StepError::Invalid`] otherwise).
    fn set_state(&mut self, state: &State) -> Result<(), StepError>;
    /// Applies `controls` (external forces frame by frame, [`crate::controls`]) in every step
    /// from now on, matched to frames by the step count; `None` ends them.
    /// [`StepError::Invalid`] where the backend takes none (the GPU, for now).
    fn set_controls(&mut self, controls: Option<Controls>) -> Result<(), StepError>;
    /// The controls being applied, if any.
    fn controls(&self) -> Option<&Controls>;
    /// What the solver carries into its next step besides the state (a GPU backend reads it
    /// back).
    fn history(&mut self) -> Result<History, StepError>;
    /// Puts the solver where another of the same backend and model was after `steps` steps, in
    /// `state` with `history`: the steps that follow are bit-identical to that solver's.
    /// [`StepError::Invalid`] for a state or a history that does not fit.
    fn restore(&mut self, steps: u64, state: &State, history: &History) -> Result<(), StepError>;
    /// Energies of the current state.
    fn energies(&mut self) -> Result<Energies, StepError>;
    /// Counters and per-stage timings over the run so far.
    fn statistics(&self) -> Statistics;
    /// Bytes the solver holds for the model, the state and its scratch (host memory on the
    /// CPU, device buffers on a GPU).
    fn memory_bytes(&self) -> u64;
}

/// Whether `state` fits `model`: the check of [`Solver::set_state`].
pub fn check_state_len(model: &Model, state: &State) -> Result<(), StepError> {
    let n = model.len();
    if state.x.len() != n || state.v.len() != n {
        return Err(StepError::Invalid(format!(
            "set_state: the state has {} positions and {} velocities, the model {n} particles",
            state.x.len(),
            state.v.len()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod four_digits_tests {
    use super::four_digits;

    #[test]
    fn times_are_rounded_to_four_significant_digits() {
        for (x, text) in [
            (0.0, "0"),
            (1.0 / 6.0, "0.1667"),
            (0.16, "0.1600"),
            (12.345678, "12.35"),
            (2500.4, "2500"),
            (123456.7, "123457"),
            (1.2346e-5, "0.00001235"),
            (1.2346e-9, "1.235e-9"),
        ] {
            assert_eq!(four_digits(x), text, "{x}");
        }
    }
}
