//! Collision response after each completed step of the explicit integrators.
//!
//! For each particle and surface with φ < ε: if N·v < 0 the normal velocity is reflected and
//! scaled by the restitution, v ← v_t − k_r v_n; if φ < 0 the particle is moved back onto the
//! surface, x ← x − φN. Pinned particles are left alone.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;
use softbody_terrain::Surface;

/// Applies the response to every particle.
pub fn respond(model: &Model, surfaces: &[Surface], x: &mut [DVec3], v: &mut [DVec3]) {
    if surfaces.is_empty() {
        return;
    }
    let eps = model.simulation.contact_distance;
    x.par_iter_mut()
        .zip(v.par_iter_mut())
        .zip(model.inv_mass.par_iter())
        .with_min_len(1024)
        .for_each(|((x, v), &w)| {
            if w != 0.0 {
                respond_one(surfaces, eps, x, v);
            }
        });
}

/// The response of one particle.
///
/// Out of line: the explicit passes call it only for particles that are not clear of every
/// surface (`Surface::clear_of`), and their per-particle update stays small.
#[inline(never)]
pub fn respond_one(surfaces: &[Surface], eps: f64, x: &mut DVec3, v: &mut DVec3) {
    for s in surfaces {
        let Some(c) = s.query(*x, eps) else { continue };
        let vn = v.dot(c.normal);
        if vn < 0.0 {
            *v -= (1.0 + s.restitution) * vn * c.normal;
        }
        if c.phi < 0.0 {
            *x -= c.phi * c.normal;
        }
    }
}
