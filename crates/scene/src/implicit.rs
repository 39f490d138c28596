//! What the implicit-Euler solvers of every backend share: the velocity constraint of a
//! particle in the filtered CG solve, and the limits of a step's solve.
//!
//! Each backend keeps its own CG tolerance, which depends on its precision (the CPU's f64 solve
//! goes to 1e-8, the GPU's f32 solve to 1e-5).

use glam::DVec3;

/// CG stops after this many iterations whatever the residual (counted in the statistics).
pub const CG_MAX_ITERATIONS: u32 = 2000;
/// Solves per step at most while the contact active set changes.
pub const ACTIVE_SET_ROUNDS: u32 = 8;

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
