//! What every backend offers: the stepping API the CLI and embedders drive.

use std::fmt;

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
            self.step, self.time, self.particle, self.what
        )
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
}

/// Counters a backend keeps over a run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Statistics {
    /// Steps taken.
    pub steps: u64,
    /// Conjugate-gradient iterations over all implicit steps.
    pub cg_iterations: u64,
    /// Conjugate-gradient solves (more than one per step when contacts change state).
    pub cg_solves: u64,
    /// Largest relative residual a CG solve ended with.
    pub cg_max_residual: f64,
}

/// A backend that advances a [`Model`] through time. The CPU and GPU solvers implement it; the
/// CLI drives it without knowing which runs.
pub trait Solver {
    /// `"cpu"` or `"gpu"`.
    fn backend(&self) -> &'static str;
    /// What runs it, for headers and logs (thread count, adapter name).
    fn device(&self) -> String;
    /// The model being stepped.
    fn model(&self) -> &Model;
    /// Advances `steps` steps; stops at the first unstable one.
    fn advance(&mut self, steps: u64) -> Result<(), StepError>;
    /// Steps taken since the start.
    fn steps_taken(&self) -> u64;
    /// The current state (a GPU backend reads it back).
    fn state(&mut self) -> Result<&State, StepError>;
    /// Energies of the current state.
    fn energies(&mut self) -> Result<Energies, StepError>;
    /// Counters over the run so far.
    fn statistics(&self) -> Statistics;
}
