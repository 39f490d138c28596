//! The integrators on the GPU (twins of `softbody_cpu::integrators`), each path a type owning
//! its buffers and kernel calls; [`Stepper`] holds the one a run uses.
//!
//! The explicit family is encoded on the device step after step (many steps per submission),
//! fused where it can be ([`fused`]: one dispatch per stage, the collision response and the
//! finiteness check included), otherwise on the per-spring path ([`per_spring`]: the forces of
//! each stage's state, then its update; the solver adds the collision response and the
//! instability check). Both paths run the kernels of one file, `shaders/explicit.wgsl`, whose
//! entry points are each method's stages ([`entries`]). Implicit Euler is driven from the host,
//! which reads the CG's progress back ([`implicit_euler`]).
//!
//! Where the fused step finds its springs on the lattices (every body a lattice), the run needs
//! no spring list at all: the run's [`Route`], decided before anything is allocated
//! ([`crate::plan`]), says so, and both the buffers ([`crate::buffers`]) and the [`Stepper`]
//! follow it.

pub mod fused;
pub mod implicit_euler;
pub mod per_spring;

use softbody_scene::Integrator;

use crate::GpuError;
use crate::body_contact::BodyContact;
use crate::buffers::{Route, Setup};

/// The integrator of a run.
pub(crate) enum Stepper {
    /// Explicit Euler, symplectic Euler, midpoint or RK4, fused: the collision response and the
    /// check are its own.
    Fused(fused::Fused),
    /// Explicit Euler, symplectic Euler, midpoint or RK4 on the per-spring path.
    PerSpring(per_spring::PerSpring),
    /// Implicit Euler.
    Implicit(Box<implicit_euler::ImplicitEuler>),
}

/// What an integrator's kernels work with besides the model's buffers: the stages the solver
/// built before it, and whether there is terrain.
#[derive(Clone, Copy)]
pub(crate) struct Around<'a> {
    /// The contact between bodies, for models whose bodies touch: every force evaluation adds
    /// its pairs' penalty forces, implicit Euler's system their terms.
    pub contact: Option<&'a BodyContact>,
    /// The collision response's record of each step's start (explicit integrators with
    /// terrain), which the fused step's last stage reads and renews.
    pub start: Option<&'a wgpu::Buffer>,
    /// Whether the scene has terrain (implicit Euler's contacts).
    pub terrain: bool,
    /// The scene's `cg_tolerance` (implicit Euler's, at no less than [`CG_TOLERANCE_F32`]).
    ///
    /// [`CG_TOLERANCE_F32`]: implicit_euler::CG_TOLERANCE_F32
    pub cg_tolerance: f64,
}

impl Stepper {
    /// `integrator`'s buffers and calls on `route` (where the plan chose a fused route, it
    /// found that the fused kernels fit); `per_spring` keeps implicit Euler's product in its two
    /// passes.
    pub fn new(
        s: Setup<'_>,
        around: Around<'_>,
        integrator: Integrator,
        route: Route,
        per_spring: bool,
    ) -> Result<Stepper, GpuError> {
        if route != Route::PerSpring {
            return Ok(Stepper::Fused(fused::Fused::new(
                s,
                integrator,
                around.start,
            )?));
        }
        Ok(match integrator {
            Integrator::ImplicitEuler => Stepper::Implicit(Box::new(
                implicit_euler::ImplicitEuler::new(s, around, per_spring)?,
            )),
            _ => Stepper::PerSpring(per_spring::PerSpring::new(s, around.contact, integrator)?),
        })
    }
}

/// Names of `integrator`'s kernels in `shaders/explicit.wgsl`, in the order of a step, on
/// either path (none for implicit Euler).
pub(crate) fn entries(integrator: Integrator) -> &'static [&'static str] {
    match integrator {
        Integrator::ExplicitEuler => &["explicit_euler"],
        Integrator::SymplecticEuler => &["symplectic_euler"],
        Integrator::Midpoint => &["midpoint_stage", "midpoint_update"],
        Integrator::Rk4 => &["rk4_first", "rk4_second", "rk4_third", "rk4_last"],
        Integrator::ImplicitEuler => &[],
    }
}
