//! What the implicit-Euler solvers of every backend share: the velocity constraint of a
//! particle in the filtered CG solve, and the limits of a step's solve.
//!
//! The CG tolerance is the scene's `simulation.cg_tolerance` ([`CG_TOLERANCE`] by default);
//! the GPU's f32 solve stops at no less than its own floor (1e-5), below which f32 resolves
//! nothing.

use glam::DVec3;

/// The default of `simulation.cg_tolerance`: CG stops when the preconditioned residual is this
/// fraction of the right-hand side's.
pub const CG_TOLERANCE: f64 = 1e-8;

/// CG stops after this many iterations whatever the residual (counted in the statistics).
pub const CG_MAX_ITERATIONS: u32 = 2000;
/// Solves per step at most while the contact active set changes.
pub const ACTIVE_SET_ROUNDS: u32 = 8;

/// How far, in units of the precision's rounding (ε_mach·(|x|∞ + h|v|)), a particle touching a
/// surface at the end of the last step may be predicted above ε and still be activated
/// ([`resting_slack`]).
pub const RESTING_ULPS: f64 = 64.0;

/// The activation slack of a particle that touched a surface at the end of the last step, at
/// x with velocity v, for a step h and the precision's machine epsilon `epsilon`.
///
/// A contact lands its particle exactly on the surface (v_n' = −φ/h), so a particle at rest on
/// it starts the next step with φ + h v·N = 0 up to the rounding of x and h v. Tested against
/// ε = 0 without slack, that rounding decides whether the contact is made before the first
/// solve or only after it, step by step at random: a body at rest would be solved twice a step,
/// the first time falling freely. Past the rounding the test is the same.
#[inline]
pub fn resting_slack(x: DVec3, v: DVec3, h: f64, epsilon: f64) -> f64 {
    RESTING_ULPS * epsilon * (x.abs().max_element() + h * v.length())
}

/// The velocity constraint of one particle during a solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Constraint {
    /// Δv is free.
    Free,
    /// The component along this unit normal is prescribed; the tangential part is free.
    Normal(DVec3),
    /// All of Δv is prescribed (pinned particles and sticking contacts).
    Fixed,
}

impl Constraint {
    /// S_i p: the free part of p.
    #[inline(always)]
    pub fn filter(self, p: DVec3) -> DVec3 {
        match self {
            Constraint::Free => p,
            Constraint::Normal(n) => p - p.dot(n) * n,
            Constraint::Fixed => DVec3::ZERO,
        }
    }
}

/// The preconditioner of implicit Euler's conjugate gradients (scene key
/// `simulation.preconditioner`). The CPU runs the one asked for, except that multigrid needs
/// lattice coordinates for every particle (cuboid and mesh bodies): a model with a `particles`
/// body runs block Jacobi. The GPU always runs block Jacobi.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Deserialize, serde::Serialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum Preconditioner {
    /// Aggregation multigrid on the lattice (W-cycle, block-Jacobi smoothing).
    #[default]
    Multigrid,
    /// The inverse of each particle's 3×3 diagonal block.
    BlockJacobi,
}

impl Preconditioner {
    /// Both, in the order tables list them.
    pub const ALL: [Preconditioner; 2] = [Preconditioner::Multigrid, Preconditioner::BlockJacobi];

    /// The name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Preconditioner::Multigrid => "multigrid",
            Preconditioner::BlockJacobi => "block-jacobi",
        }
    }
}

impl std::fmt::Display for Preconditioner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Preconditioner {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Preconditioner::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Preconditioner::ALL.iter().map(|p| p.name()).collect();
                format!(
                    "unknown preconditioner `{s}`; expected one of {}",
                    names.join(", ")
                )
            })
    }
}
