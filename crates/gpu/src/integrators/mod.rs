//! The integrators on the GPU, each a type owning its buffers and kernel calls, one module each
//! (twins of `softbody_cpu::integrators`); [`Stepper`] holds the one a run uses.
//!
//! The explicit family is encoded on the device step after step (many steps per submission),
//! fused where it can be ([`fused`]: one dispatch per stage, the collision response and the
//! finiteness check included), otherwise on the per-spring path:
//!
//! | integrator | dispatches of a step (per-spring path) |
//! |---|---|
//! | explicit / symplectic Euler | forces(x, v) → update |
//! | midpoint | forces(x, v) → `midpoint_stage` → forces(stage) → `midpoint_update` |
//! | RK4 | forces(x, v) → `rk4_first` → forces(stage) → `rk4_second` → forces(stage) → `rk4_third` → forces(stage) → `rk4_last` |
//!
//! where forces(·) is [`Accelerations`] (spring forces, then the gather). The solver adds the
//! collision response (with terrain) and the instability check. The per-spring path serves
//! models whose bodies touch (their pair forces need the broad phase's grid of each stage's
//! state) and adapters that cannot bind the fused kernels' buffers. Implicit Euler is driven
//! from the host, which reads the CG's progress back ([`implicit_euler`]).

pub mod explicit_euler;
pub mod fused;
pub mod implicit_euler;
pub mod midpoint;
pub mod rk4;
pub mod symplectic_euler;

use softbody_scene::{Integrator, Lattice};

use crate::GpuError;
use crate::builder::Setup;
use crate::forces::Accelerations;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// An integrator whose steps are encoded on the device alone.
pub(crate) trait ExplicitStep: Send {
    /// Encodes one step's force evaluations and updates.
    fn encode(&self, pass: &mut wgpu::ComputePass<'_>);
}

/// The integrator of a run.
pub(crate) enum Stepper {
    /// Explicit Euler, symplectic Euler, midpoint or RK4, fused: the collision response and the
    /// check are its own.
    Fused(fused::Fused),
    /// Explicit Euler, symplectic Euler, midpoint or RK4 on the per-spring path.
    Explicit(Box<dyn ExplicitStep>),
    /// Implicit Euler.
    Implicit(Box<implicit_euler::ImplicitEuler>),
}

impl Stepper {
    /// `integrator`'s buffers and calls; `terrain` says whether the scene has terrain, `start`
    /// is the collision response's record of each step's start (explicit integrators with
    /// terrain). The explicit integrators are fused unless `per_spring` asks for the per-spring
    /// path, bodies touch, or the adapter cannot bind the fused kernels; fused, they find their
    /// springs on `lattices` where given (every body's).
    pub fn new(
        s: Setup<'_>,
        integrator: Integrator,
        terrain: bool,
        start: Option<&wgpu::Buffer>,
        per_spring: bool,
        lattices: Option<&[Lattice]>,
    ) -> Result<Stepper, GpuError> {
        if integrator != Integrator::ImplicitEuler && s.body_contact.is_none() && !per_spring {
            match fused::Fused::new(s, integrator, start, lattices) {
                Ok(fused) => return Ok(Stepper::Fused(fused)),
                Err(GpuError::Limit { .. }) => {}
                Err(e) => return Err(e),
            }
        }
        Ok(match integrator {
            Integrator::ExplicitEuler => Stepper::Explicit(Box::new(explicit_euler::new(s)?)),
            Integrator::SymplecticEuler => Stepper::Explicit(Box::new(symplectic_euler::new(s)?)),
            Integrator::Midpoint => Stepper::Explicit(Box::new(midpoint::Midpoint::new(s)?)),
            Integrator::Rk4 => Stepper::Explicit(Box::new(rk4::Rk4::new(s)?)),
            Integrator::ImplicitEuler => {
                Stepper::Implicit(Box::new(implicit_euler::ImplicitEuler::new(s, terrain)?))
            }
        })
    }
}

/// A single-stage explicit method: forces at (x, v), then one update kernel.
pub(crate) struct SingleStage {
    forces: Accelerations,
    update: Call,
    grid: Grid,
}

impl SingleStage {
    /// The method whose update is `entry` of `stage`.
    fn new(s: Setup<'_>, stage: Stage, entry: &'static str) -> Result<SingleStage, GpuError> {
        let b = s.buffers;
        Ok(SingleStage {
            forces: Accelerations::new(s, &b.x, &b.v)?,
            update: s.builder.call(stage, entry, &b.resources())?,
            grid: s.particles,
        })
    }
}

impl ExplicitStep for SingleStage {
    fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.forces.encode(pass);
        self.update.run(pass, self.grid);
    }
}
