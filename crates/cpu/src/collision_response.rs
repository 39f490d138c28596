//! Collision response after each completed step of the explicit integrators.
//!
//! For each particle and surface k (in order) with φ < ε at the particle's new position: if
//! N·v < 0 the normal velocity is reflected and scaled by the restitution, v ← v_t − k_r v_n,
//! on a fresh impact only; otherwise the particle just stops approaching, v ← v_t. If φ < 0 the
//! particle is moved back onto the surface, x ← x − φN. Pinned particles are left alone.
//!
//! A fresh impact: the particle started the step outside surface k's contact band
//! ([`band_mask`]), and it approaches faster than a fall from rest through the band at the
//! step's own normal acceleration a_n = −N·(v − v_start)/h would bring it: v_n² > 2 a_n ε.
//! Without the second condition a resting particle bounces at the band's edge forever: it
//! leaves the band by micrometres, the forces that press it down (its weight and the weight of
//! the body above, carried by its springs) bring it back within a step or two at a few a_n·h,
//! and restitution sends it out again — a kinetic-energy floor near 1e-6 J for a 1 kg cube.
//! With no force pressing (no gravity, a head-on collision) every approach is an impact.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;
use softbody_terrain::Surface;

/// Applies the response to every particle; `start` is the state at the start of the step.
pub fn respond(
    model: &Model,
    surfaces: &[Surface],
    start: &softbody_scene::State,
    x: &mut [DVec3],
    v: &mut [DVec3],
) {
    if surfaces.is_empty() {
        return;
    }
    let eps = model.simulation.contact_distance;
    x.par_iter_mut()
        .zip(v.par_iter_mut())
        .zip(model.inv_mass.par_iter().zip(&start.x).zip(&start.v))
        .with_min_len(1024)
        .for_each(|((x, v), ((&w, &x0), &v0))| {
            if w != 0.0 {
                respond_one(surfaces, eps, model.simulation.dt, (x0, v0), x, v);
            }
        });
}

/// Bit `min(k, 31)` for each surface k whose contact band (φ < ε) holds `x`: the surfaces
/// against which a particle that starts its step at `x` makes no fresh impact. Surfaces from
/// the 32nd on share the last bit (the GPU keeps the mask in one u32 per particle).
pub fn band_mask(surfaces: &[Surface], eps: f64, x: DVec3) -> u32 {
    surfaces
        .iter()
        .enumerate()
        .filter(|(_, s)| s.query(x, eps).is_some())
        .fold(0, |mask, (k, _)| mask | 1 << k.min(31))
}

/// The response of one particle that started the step at `(x_start, v_start)`.
///
/// Out of line: the explicit passes call it only for particles that are not clear of every
/// surface (`Surface::clear_of`), and their per-particle update stays small.
#[inline(never)]
pub fn respond_one(
    surfaces: &[Surface],
    eps: f64,
    h: f64,
    (x_start, v_start): (DVec3, DVec3),
    x: &mut DVec3,
    v: &mut DVec3,
) {
    // Computed once, and only for a particle that approaches a surface.
    let mut start_mask = None;
    for (k, s) in surfaces.iter().enumerate() {
        let Some(c) = s.query(*x, eps) else { continue };
        let vn = v.dot(c.normal);
        if vn < 0.0 {
            let mask = *start_mask.get_or_insert_with(|| band_mask(surfaces, eps, x_start));
            let (scale, _) = reflection(s, k, mask, (eps, h), (*v, v_start), c.normal);
            *v -= scale * vn * c.normal;
        }
        if c.phi < 0.0 {
            *x -= c.phi * c.normal;
        }
    }
}

/// The factor (1 + k_r) by which a particle approaching surface `s` (number `k`, v·N < 0) has
/// its normal velocity taken away, and whether the impact is fresh (k_r its restitution;
/// otherwise 0): `mask` is the [`band_mask`] of the step's start, `(v, v_start)` the velocity
/// now and at the start. The forward response and its transpose decide by this one rule.
#[inline]
pub(crate) fn reflection(
    s: &Surface,
    k: usize,
    mask: u32,
    (eps, h): (f64, f64),
    (v, v_start): (DVec3, DVec3),
    normal: DVec3,
) -> (f64, bool) {
    let vn = v.dot(normal);
    // Approach slower than a fall from rest through the band at the step's own acceleration is
    // band-scale jitter, not an impact.
    let a_n = (-(v - v_start).dot(normal) / h).max(0.0);
    let fresh = mask & 1 << k.min(31) == 0 && vn * vn > 2.0 * a_n * eps;
    let k_r = if fresh { s.restitution } else { 0.0 };
    (1.0 + k_r, fresh)
}
