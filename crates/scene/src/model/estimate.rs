//! What a solver will hold for a scene, estimated before anything is built, and the sizes the
//! model's u32 indices allow.

use crate::scene::{BodyShape, Scene};

#[cfg(doc)]
use super::Model;

/// Most particles a scene may hold (indices are u32).
pub const MAX_PARTICLES: u64 = u32::MAX as u64 - 1;
/// Most springs a scene may hold (the adjacency stores `2·spring + side` in a u32).
pub const MAX_SPRINGS: u64 = (u32::MAX >> 1) as u64;

/// Upper estimate of what a solver holds per particle: state, mass, adjacency offsets and the
/// largest integrator scratch (implicit Euler's vectors and its multigrid hierarchy, about
/// 600 B per particle; RK4 keeps four stage derivatives and a trial state).
pub const BYTES_PER_PARTICLE: u64 = 1024;
/// Upper estimate per spring: topology, parameters, two adjacency entries, per-spring force and
/// the implicit solver's Jacobian data.
pub const BYTES_PER_SPRING: u64 = 144;

/// Estimated bytes a solver needs for a scene of this size (saturating), springs listed.
pub fn estimated_bytes(particles: u64, springs: u64) -> u64 {
    particles
        .saturating_mul(BYTES_PER_PARTICLE)
        .saturating_add(springs.saturating_mul(BYTES_PER_SPRING))
}

/// What the CPU solver holds per particle for a model of cuboids only (springs kept as
/// stencils, no list: see [`Model`]) under `integrator`, in the limit of large bodies. The
/// explicit integrators: 44 B of the model (masses 16, the contact arrays 28) and 48 B per
/// state they keep (the state and the passes' second state; midpoint one stage state more,
/// RK4 two). Implicit Euler lists no springs on lattices either, but keeps its right-hand
/// sides, CG's vectors, the diagonal blocks and their inverses, 1/ℓ per spring and the
/// multigrid's levels (the first coarse level's 27 blocks per node, and its sources naming
/// each spring twice): 1,340–1,388 B per particle on cubes from 22³ to 200³ (BENCHMARKS.md,
/// "Memory"), and since 2026-11-29 24 B more (the positions the multigrid's kept values were
/// computed at) and 72 B more (the earlier steps' Δv that the warm start combines, and a
/// copy of the last): 1,412 B on the 40³ cube, so 1.5 kB. `crates/cpu/tests/lean.rs` holds
/// the solver to it.
///
/// The figure is the CPU solver's. A GPU solver's needs are not estimated: its host keeps the
/// model and stages the uploads, and a software adapter's buffers are in this machine's memory
/// too.
pub fn lean_bytes_per_particle(integrator: crate::Integrator) -> u64 {
    use crate::Integrator::*;
    let states = match integrator {
        ExplicitEuler | SymplecticEuler => 2,
        Midpoint => 3,
        Rk4 => 4,
        ImplicitEuler => return 1_500,
    };
    44 + 48 * states
}

/// Estimated bytes a solver needs for `scene` (saturating): [`lean_bytes_per_particle`] for
/// one cuboid without self-contact (a quarter more for the explicit stencil's slabs, a few
/// planes per thread; implicit Euler's dense factor of its coarsest level, at most 2.9 MB
/// whatever the size, is left out), else [`estimated_bytes`].
pub fn estimated_scene_bytes(scene: &Scene) -> u64 {
    let particles = scene.particle_count();
    match scene.bodies.as_slice() {
        [body] if matches!(body.shape, BodyShape::Cuboid(_)) && !body.self_contact => {
            let bytes = lean_bytes_per_particle(scene.simulation.integrator);
            particles.saturating_mul(bytes + bytes / 4)
        }
        _ => estimated_bytes(particles, scene.spring_counts().total()),
    }
}
