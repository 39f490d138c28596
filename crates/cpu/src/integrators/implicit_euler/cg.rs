//! Filtered, preconditioned conjugate gradients (Baraff and Witkin's "modified PCG").
//!
//! Solves A Δv = b where some velocity components are prescribed: each particle has a
//! [`Constraint`] whose filter S_i projects onto the free directions (all of them, the plane
//! orthogonal to a contact normal, or none), and the prescribed part of Δv is `z` (zero in the
//! free directions). CG then runs in the free subspace: residuals and search directions are
//! filtered, so Δv keeps the prescribed components exactly and S(A Δv − b) → 0. The
//! preconditioner is block Jacobi, S P⁻¹ S, which is symmetric positive definite on that
//! subspace.
//!
//! Convergence: stop when rᵀP⁻¹r ≤ tol²·max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀), i.e. the preconditioned
//! residual is `tol` relative to the filtered right-hand side or to the initial residual,
//! whichever is larger; or after `max_iterations`; or when round-off makes the residual grow
//! a millionfold over its smallest value.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;

pub use softbody_scene::implicit::Constraint;

use super::system::System;
use crate::forces::PARTICLE_CHUNK;
use crate::reduce::chunked_sum;

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CgOutcome {
    /// Iterations taken.
    pub iterations: u32,
    /// sqrt(rᵀP⁻¹r / max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀)) at the end (0 when both are 0).
    pub relative_residual: f64,
}

/// CG's vectors, allocated once.
#[derive(Debug, Default)]
pub struct Scratch {
    r: Vec<DVec3>,
    c: Vec<DVec3>,
    q: Vec<DVec3>,
}

impl Scratch {
    /// Sized for `n` particles.
    pub fn new(n: usize) -> Scratch {
        Scratch {
            r: vec![DVec3::ZERO; n],
            c: vec![DVec3::ZERO; n],
            q: vec![DVec3::ZERO; n],
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        [&self.r, &self.c, &self.q]
            .into_iter()
            .map(crate::vec_bytes)
            .sum()
    }
}

fn dot(a: &[DVec3], b: &[DVec3]) -> f64 {
    chunked_sum(a.len(), |i| a[i].dot(b[i]))
}

/// Solves for `dv` (which holds a warm start on entry; its constrained part is replaced by `z`).
#[allow(clippy::too_many_arguments)]
pub fn solve(
    system: &mut System,
    model: &Model,
    constraints: &[Constraint],
    b: &[DVec3],
    z: &[DVec3],
    dv: &mut [DVec3],
    scratch: &mut Scratch,
    tolerance: f64,
    max_iterations: u32,
) -> CgOutcome {
    let Scratch { r, c, q } = scratch;
    // Moved out for the solve so that `system` can lend its per-spring scratch to `apply`.
    let inv_diag = std::mem::take(&mut system.inv_diag);
    let inv = &inv_diag;
    dv.par_iter_mut()
        .zip(constraints.par_iter().zip(z.par_iter()))
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(dv, (s, z))| *dv = s.filter(*dv) + *z);
    let delta0 = chunked_sum(b.len(), |i| {
        let sb = constraints[i].filter(b[i]);
        sb.dot(constraints[i].filter(inv[i] * sb))
    });
    system.apply(model, dv, q);
    r.par_iter_mut()
        .zip(c.par_iter_mut())
        .enumerate()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(i, (r, c))| {
            let s = constraints[i];
            *r = s.filter(b[i] - q[i]);
            *c = s.filter(inv[i] * *r);
        });
    let mut delta = dot(r, c);
    // Relative to the larger of the right-hand side and the warm start's residual: a body at
    // rest has S·b ≈ 0 while its prescribed contact velocities still leave a residual, and a
    // target relative to S·b alone would lie below round-off, where CG stagnates and then
    // diverges.
    let scale = delta0.max(delta);
    let target = tolerance * tolerance * scale;
    let mut smallest = delta;
    let mut iterations = 0;
    while delta > target && iterations < max_iterations {
        system.apply(model, c, q);
        q.par_iter_mut()
            .zip(constraints.par_iter())
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(q, s)| *q = s.filter(*q));
        let cq = dot(c, q);
        if !(cq > 0.0 && cq.is_finite()) {
            break; // only reachable through round-off once the residual is at machine precision
        }
        let alpha = delta / cq;
        dv.par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(c.par_iter().zip(q.par_iter()))
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|((dv, r), (c, q))| {
                *dv += alpha * *c;
                *r -= alpha * *q;
            });
        let delta_new = chunked_sum(r.len(), |i| r[i].dot(inv[i] * r[i]));
        // In exact arithmetic the residual never grows by orders of magnitude; in floating
        // point it does once round-off dominates: stop there rather than follow it.
        if !delta_new.is_finite() || delta_new > 1e6 * smallest {
            delta = smallest;
            break;
        }
        smallest = smallest.min(delta_new);
        let beta = delta_new / delta;
        delta = delta_new;
        c.par_iter_mut()
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, c)| *c = constraints[i].filter(inv[i] * r[i] + beta * *c));
        iterations += 1;
    }
    system.inv_diag = inv_diag;
    CgOutcome {
        iterations,
        relative_residual: if scale > 0.0 {
            (delta.max(0.0) / scale).sqrt()
        } else {
            0.0
        },
    }
}
