//! Filtered, preconditioned conjugate gradients (Baraff and Witkin's "modified PCG").
//!
//! Solves A Δv = b where some velocity components are prescribed: each particle has a
//! [`Constraint`] whose filter S_i projects onto the free directions (all of them, the plane
//! orthogonal to a contact normal, or none), and the prescribed part of Δv is `z` (zero in the
//! free directions). CG then runs in the free subspace: residuals and search directions are
//! filtered, so Δv keeps the prescribed components exactly and S(A Δv − b) → 0. The
//! preconditioner ([`Preconditioner`]) is block Jacobi, S P⁻¹ S with P the diagonal blocks, or
//! aggregation multigrid, S·MG·S ([`super::multigrid`]); both are symmetric positive definite
//! on that subspace, and one CG loop runs either.
//!
//! Convergence: stop when rᵀP⁻¹r ≤ tol²·max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀, wᵀP⁻¹w), i.e. the
//! preconditioned residual is `tol` relative to the filtered right-hand side, to the initial
//! residual or to the weight's impulse w = S h M g, whichever is largest; or after
//! `max_iterations`; or when round-off makes the residual grow a millionfold over its smallest
//! value.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;

pub use softbody_scene::implicit::Constraint;

use super::multigrid::Multigrid;
use super::system::System;
use crate::forces::PARTICLE_CHUNK;
use crate::reduce::{chunked_sum, fill_and_sum};

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CgOutcome {
    /// Iterations taken.
    pub iterations: u32,
    /// sqrt(rᵀP⁻¹r / max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀, wᵀP⁻¹w)) at the end (0 when all are 0).
    pub relative_residual: f64,
}

/// CG's preconditioner P⁻¹ (applied filtered: S P⁻¹ S).
#[derive(Debug)]
pub enum Preconditioner<'a> {
    /// The inverse of each particle's diagonal block.
    BlockJacobi,
    /// One multigrid cycle, its values computed for the solve's constraints at its start.
    Multigrid(&'a mut Multigrid),
}

/// CG's vectors, allocated once.
#[derive(Debug, Default)]
pub struct Scratch {
    r: Vec<DVec3>,
    c: Vec<DVec3>,
    q: Vec<DVec3>,
    /// The preconditioned residual.
    p: Vec<DVec3>,
}

impl Scratch {
    /// Sized for `n` particles.
    pub fn new(n: usize) -> Scratch {
        Scratch {
            r: vec![DVec3::ZERO; n],
            c: vec![DVec3::ZERO; n],
            q: vec![DVec3::ZERO; n],
            p: vec![DVec3::ZERO; n],
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        [&self.r, &self.c, &self.q, &self.p]
            .into_iter()
            .map(crate::vec_bytes)
            .sum()
    }
}

/// Solves for `dv` (which holds a warm start on entry; its constrained part is replaced by `z`),
/// preconditioned by `preconditioner`.
#[allow(clippy::too_many_arguments)]
pub fn solve(
    system: &mut System,
    model: &Model,
    constraints: &[Constraint],
    b: &[DVec3],
    z: &[DVec3],
    dv: &mut [DVec3],
    scratch: &mut Scratch,
    mut preconditioner: Preconditioner<'_>,
    tolerance: f64,
    max_iterations: u32,
) -> CgOutcome {
    let Scratch { r, c, q, p } = scratch;
    p.resize(r.len(), DVec3::ZERO);
    if let Preconditioner::Multigrid(mg) = &mut preconditioner {
        mg.prepare(system, model, constraints);
    }
    // Moved out for the solve so that `system` can lend its per-spring scratch to `apply`.
    let inv_diag = std::mem::take(&mut system.inv_diag);
    let inv = &inv_diag;
    // out = S P⁻¹ r for a filtered r; returns rᵀ out (every use of the preconditioner is
    // followed by that product, which the pass writing `out` sums at once).
    let mut precondition = |r: &[DVec3], out: &mut [DVec3]| match &mut preconditioner {
        Preconditioner::BlockJacobi => fill_and_sum(out, |i| {
            let z = constraints[i].filter(inv[i] * r[i]);
            (z, r[i].dot(z))
        }),
        Preconditioner::Multigrid(mg) => mg.apply(constraints, r, out),
    };
    dv.par_iter_mut()
        .zip(constraints.par_iter().zip(z.par_iter()))
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(dv, (s, z))| *dv = s.filter(*dv) + *z);
    // (Sb)ᵀ P⁻¹ (Sb), with r holding S b for the moment.
    r.par_iter_mut()
        .zip(constraints.par_iter().zip(b.par_iter()))
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(r, (s, b))| *r = s.filter(*b));
    let delta0 = precondition(r, p);
    system.apply(model, dv, q);
    r.par_iter_mut()
        .enumerate()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(i, r)| *r = constraints[i].filter(b[i] - q[i]));
    let mut delta = precondition(r, c);
    // (S h M g)ᵀ P⁻¹ (S h M g), with q (free until the first product) holding the weight's
    // impulse S h M g.
    let hg = model.simulation.dt * model.simulation.gravity;
    q.par_iter_mut()
        .enumerate()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(i, w)| *w = constraints[i].filter(model.mass[i] * hg));
    let weight = precondition(q, p);
    // Relative to the largest of the right-hand side, the warm start's residual and the
    // weight's impulse. A body at rest has S·b ≈ 0, its springs' forces and its weight
    // cancelling, while its prescribed contact velocities still leave a residual: a target
    // relative to S·b or to that residual alone lies at the rounding of those forces, where CG
    // works for nothing (51–61 iterations a step for the stiff 22³ cube at rest) or stagnates.
    let scale = delta0.max(delta).max(weight);
    let target = tolerance * tolerance * scale;
    let mut smallest = delta;
    let mut iterations = 0;
    // The next search direction is c ← p + βc, formed by the product that reads it
    // (`System::apply_direction`); the first is c itself (β = 0 would give the same values).
    let mut beta = None;
    while delta > target && iterations < max_iterations {
        match beta {
            None => system.apply(model, c, q),
            Some(beta) => system.apply_direction(model, p, beta, c, q),
        }
        // q = S A c, filtered where it is read (no pass of its own).
        let cq = chunked_sum(c.len(), |i| c[i].dot(constraints[i].filter(q[i])));
        if !(cq > 0.0 && cq.is_finite()) {
            break; // only reachable through round-off once the residual is at machine precision
        }
        let alpha = delta / cq;
        dv.par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(c.par_iter().zip(q.par_iter().zip(constraints.par_iter())))
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|((dv, r), (c, (q, s)))| {
                *dv += alpha * *c;
                *r -= alpha * s.filter(*q);
            });
        let delta_new = precondition(r, p);
        // In exact arithmetic the residual never grows by orders of magnitude; in floating
        // point it does once round-off dominates: stop there rather than follow it.
        if !(delta_new >= 0.0 && delta_new.is_finite()) || delta_new > 1e6 * smallest {
            delta = smallest;
            break;
        }
        smallest = smallest.min(delta_new);
        beta = Some(delta_new / delta);
        delta = delta_new;
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
