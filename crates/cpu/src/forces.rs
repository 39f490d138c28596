//! The force pipeline of the explicit integrators: a(x, v) = f(x, v)/m with
//! f = gravity m g + drag −drag·m·v + springs (gathered) + contact and friction.
//!
//! Pinned particles get a = 0.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Model, Simulation};
use softbody_terrain::Surface;

use crate::contact::contact_force;
use crate::spring_forces;

/// Particles per rayon task in per-particle passes (the fewest in the fused passes, which size
/// their tasks with [`particle_chunk`]).
pub const PARTICLE_CHUNK: usize = 1024;

/// Particles per rayon task in the fused per-particle passes: about four tasks per thread, at
/// least 256 and at most 8192 particles. Only the speed depends on it.
pub fn particle_chunk(particles: usize) -> usize {
    let tasks = 4 * rayon::current_num_threads();
    particles.div_ceil(tasks).clamp(256, 8192)
}

/// Gravity, drag and spring force on particle i (springs already computed per spring).
#[inline(always)]
pub fn applied_force(model: &Model, per_spring: &[DVec3], v: DVec3, i: usize) -> DVec3 {
    let m = model.mass[i];
    let sim = &model.simulation;
    m * sim.gravity - sim.drag * m * v + spring_forces::gather(model.adjacency(), per_spring, i)
}

/// a(x, v) of particle i at position `x` and velocity `v`, the spring forces already computed
/// into `per_spring`.
#[inline(always)]
pub fn acceleration(
    model: &Model,
    surfaces: &[Surface],
    per_spring: &[DVec3],
    i: usize,
    x: DVec3,
    v: DVec3,
) -> DVec3 {
    if model.inv_mass[i] == 0.0 {
        return DVec3::ZERO;
    }
    let springs = spring_forces::gather(model.adjacency(), per_spring, i);
    acceleration_with(model, surfaces, i, x, v, springs)
}

/// a(x, v) of particle i with the sum of its spring forces `springs` already gathered: what
/// [`acceleration`] computes, in the same order.
#[inline(always)]
pub fn acceleration_with(
    model: &Model,
    surfaces: &[Surface],
    i: usize,
    x: DVec3,
    v: DVec3,
    springs: DVec3,
) -> DVec3 {
    let (m, w) = (model.mass[i], model.inv_mass[i]);
    acceleration_of(&model.simulation, (m, w), surfaces, x, v, springs)
}

/// a(x, v) of a particle of mass m and inverse mass w (0 where pinned) with the sum of its
/// spring forces `springs`: [`acceleration_with`] given the masses, so that a loop over a row
/// of particles reads them from slices it has checked once.
#[inline(always)]
pub fn acceleration_of(
    sim: &Simulation,
    (m, w): (f64, f64),
    surfaces: &[Surface],
    x: DVec3,
    v: DVec3,
    springs: DVec3,
) -> DVec3 {
    let f = m * sim.gravity - sim.drag * m * v + springs;
    let eps = sim.contact_distance;
    // Clear of every surface: no contact, contact_force's zero without its queries.
    let fc = if surfaces.iter().all(|s| s.clear_of(x, eps)) {
        DVec3::ZERO
    } else {
        contact_force(surfaces, eps, sim.dt, m, x, v, f)
    };
    // Computed for pinned particles too and then dropped: as a select rather than a branch
    // before the loads, a loop over a row of particles reads its inputs with plain vector
    // loads (masked loads of values just stored wait for the stores to retire).
    let a = (f + fc) * w;
    if w == 0.0 { DVec3::ZERO } else { a }
}

/// Writes a(x, v) of every particle into `a`; `per_spring` is scratch of one entry per spring.
pub fn accelerations(
    model: &Model,
    surfaces: &[Surface],
    x: &[DVec3],
    v: &[DVec3],
    per_spring: &mut [DVec3],
    a: &mut [DVec3],
) {
    accelerations_with(
        spring_forces::Kernel::per_spring(),
        model,
        surfaces,
        x,
        v,
        per_spring,
        a,
    );
}

/// [`accelerations`] with a spring kernel set up for the model.
pub fn accelerations_with(
    kernel: spring_forces::Kernel,
    model: &Model,
    surfaces: &[Surface],
    x: &[DVec3],
    v: &[DVec3],
    per_spring: &mut [DVec3],
    a: &mut [DVec3],
) {
    kernel.compute(model.springs(), x, v, per_spring);
    let per_spring = &*per_spring;
    let chunk = particle_chunk(a.len());
    a.par_chunks_mut(chunk).enumerate().for_each(|(c, a)| {
        for (k, a) in a.iter_mut().enumerate() {
            let i = c * chunk + k;
            *a = acceleration(model, surfaces, per_spring, i, x[i], v[i]);
        }
    });
}
