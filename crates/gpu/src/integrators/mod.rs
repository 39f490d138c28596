//! The integrators on the GPU, each a type owning its buffers and kernel calls, one module each
//! (twins of `softbody_cpu::integrators`); [`Stepper`] holds the one a run uses.
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
//! no spring list at all: [`Route`] decides that before anything is allocated, and both the
//! buffers ([`crate::buffers`]) and the [`Stepper`] follow its decision.

pub mod fused;
pub mod implicit_euler;
pub mod per_spring;

use softbody_scene::{Integrator, Model};

use crate::builder::{Setup, answer, fits};
use crate::chunks::Chunking;
use crate::layout::{SpringBlockGpu, SpringGpu};
use crate::limits::check_chunks;
use crate::shaders::Stage;
use crate::{GpuError, GpuOptions};

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

/// How a run finds each particle's springs, and so what the device holds of them: decided
/// once, before anything is allocated, by [`Route::of`]; the buffers uploaded and the
/// [`Stepper`] built follow it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Route {
    /// The explicit integrators fused, finding the springs on the lattices (`stencil.wgsl`):
    /// neither the host nor the device holds a spring list.
    Stencil,
    /// The explicit integrators fused, gathering through the spring records and the CSR
    /// adjacency (`fused_gather.wgsl`): nothing per spring is written.
    Gather,
    /// The spring list and what the per-spring kernels write into (the per-spring vectors, the
    /// accelerations): the per-spring path and implicit Euler.
    PerSpring,
}

impl Route {
    /// The route of `model` on an adapter with `limits`, and the chunking of its spring list
    /// (one empty chunk on the stencil route). The explicit integrators run fused
    /// ([`fused_applies`]) where the adapter can bind the fused kernels (reflected from their
    /// WGSL): on the stencil where every body is a lattice and `options` do not ask for the
    /// gather, else on the gather. Everything else takes the per-spring route.
    pub fn of(
        model: &Model,
        options: &GpuOptions,
        limits: &wgpu::Limits,
        adapter: &str,
    ) -> Result<(Route, Chunking), GpuError> {
        let integrator = model.simulation.integrator;
        let implicit = integrator == Integrator::ImplicitEuler;
        let stride = if implicit {
            std::mem::size_of::<SpringBlockGpu>()
        } else {
            std::mem::size_of::<SpringGpu>()
        } as u64;
        let fused = fused_applies(integrator, model.contact.enabled(), options.per_spring);
        let entries = entries(integrator);
        // Whether `stage`'s fused kernels fit; a limit is an answer, anything else an error.
        let fit = |stage, chunking| answer(fits(limits, adapter, stage, entries, chunking));
        let lattices = model.lattices().len() == model.bodies.len();
        if fused && lattices && !options.gather && fit(Stage::FusedStencil, Chunking::ONE)? {
            return Ok((
                Route::Stencil,
                check_chunks(limits, adapter, 0, stride, implicit)?,
            ));
        }
        let springs = model.spring_count() as u64;
        let chunking = check_chunks(limits, adapter, springs, stride, implicit)?;
        let route = if fused && fit(Stage::FusedStep, chunking)? {
            Route::Gather
        } else {
            Route::PerSpring
        };
        Ok((route, chunking))
    }
}

/// Whether `integrator` runs fused unless the adapter cannot bind the fused kernels: an
/// explicit integrator, bodies that do not touch (`contact`: their pair forces need the broad
/// phase of each stage's state), and `per_spring` not asking for the per-spring path.
fn fused_applies(integrator: Integrator, contact: bool, per_spring: bool) -> bool {
    integrator != Integrator::ImplicitEuler && !contact && !per_spring
}

impl Stepper {
    /// `integrator`'s buffers and calls on `route` ([`Route::of`], which found that the fused
    /// kernels fit where it chose them); `terrain` says whether the scene has terrain, `start`
    /// is the collision response's record of each step's start (explicit integrators with
    /// terrain); `per_spring` keeps implicit Euler's product in its two passes.
    pub fn new(
        s: Setup<'_>,
        integrator: Integrator,
        terrain: bool,
        start: Option<&wgpu::Buffer>,
        route: Route,
        per_spring: bool,
    ) -> Result<Stepper, GpuError> {
        if route != Route::PerSpring {
            return Ok(Stepper::Fused(fused::Fused::new(s, integrator, start)?));
        }
        Ok(match integrator {
            Integrator::ImplicitEuler => Stepper::Implicit(Box::new(
                implicit_euler::ImplicitEuler::new(s, terrain, per_spring)?,
            )),
            _ => Stepper::PerSpring(per_spring::PerSpring::new(s, integrator)?),
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
