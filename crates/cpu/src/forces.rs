//! The force pipeline of the explicit integrators: a(x, v) = f(x, v)/m with
//! f = gravity m g + drag −drag·m·v + springs (gathered) + contact and friction.
//!
//! Pinned particles get a = 0.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;

use crate::contact::contact_force;
use crate::spring_forces;
use crate::terrain::Surface;

/// Particles per rayon task in per-particle passes.
pub const PARTICLE_CHUNK: usize = 1024;

/// Gravity, drag and spring force on particle i (springs already computed per spring).
#[inline(always)]
pub fn applied_force(model: &Model, per_spring: &[DVec3], v: DVec3, i: usize) -> DVec3 {
    let m = model.mass[i];
    let sim = &model.simulation;
    m * sim.gravity - sim.drag * m * v + spring_forces::gather(&model.adjacency, per_spring, i)
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
    spring_forces::compute(&model.springs, x, v, per_spring);
    let per_spring = &*per_spring;
    let sim = &model.simulation;
    a.par_iter_mut()
        .enumerate()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(i, a)| {
            let w = model.inv_mass[i];
            if w == 0.0 {
                *a = DVec3::ZERO;
                return;
            }
            let f = applied_force(model, per_spring, v[i], i);
            let fc = contact_force(
                surfaces,
                sim.contact_distance,
                sim.dt,
                model.mass[i],
                x[i],
                v[i],
                f,
            );
            *a = (f + fc) * w;
        });
}
