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
//! Warm start: the last step's Δv, projected with the solutions of the steps before it
//! (`project_warm_start`) onto the combination closest to this step's solution.
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
use super::{CG_MAX_ITERATIONS, CG_TOLERANCE};
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

/// At most this many solutions span the warm start: the one in `dv` and
/// `WARM_START_BASIS − 1` earlier ones.
pub const WARM_START_BASIS: usize = 3;
/// A basis vector of the warm start whose part not spanned by the ones before it has an
/// A-norm² below this fraction of its own is left out (a free fall's solutions are all the
/// same vector). Not larger: the parts that tell an impact's alternating solutions apart lie
/// at 1e-10–1e-12 of that, and leaving them out (1e-8) took the 22³ benchmark cube from 6.1 to
/// 7.0 iterations a step.
const INDEPENDENT: f64 = 1e-12;

/// One filtered solve of A Δv = b: A the `system`'s matrix on `model`, each particle's filter
/// and prescribed part `z` of Δv from `constraints`, the warm start projected with the
/// `earlier` solutions (at most [`WARM_START_BASIS`] − 1; none for a plain warm start) by
/// `project_warm_start`, stopping at `tolerance` or after `max_iterations`.
#[derive(Debug)]
pub struct CgProblem<'a> {
    /// The linear system, assembled; its `inv_diag` is P for block Jacobi.
    pub system: &'a mut System,
    /// The model the system was assembled for.
    pub model: &'a Model,
    /// Each particle's filter S_i.
    pub constraints: &'a [Constraint],
    /// The right-hand side.
    pub b: &'a [DVec3],
    /// The prescribed part of Δv (zero in the free directions).
    pub z: &'a [DVec3],
    /// Earlier steps' solutions, the latest first.
    pub earlier: &'a [&'a [DVec3]],
    /// P⁻¹.
    pub preconditioner: Preconditioner<'a>,
    /// The relative residual to stop at.
    pub tolerance: f64,
    /// The most iterations.
    pub max_iterations: u32,
}

impl<'a> CgProblem<'a> {
    /// The problem as a step poses it without a history: no earlier solutions, block Jacobi,
    /// [`CG_TOLERANCE`], at most [`CG_MAX_ITERATIONS`] (change any of them with `..`).
    pub fn new(
        system: &'a mut System,
        model: &'a Model,
        constraints: &'a [Constraint],
        b: &'a [DVec3],
        z: &'a [DVec3],
    ) -> CgProblem<'a> {
        CgProblem {
            system,
            model,
            constraints,
            b,
            z,
            earlier: &[],
            preconditioner: Preconditioner::BlockJacobi,
            tolerance: CG_TOLERANCE,
            max_iterations: CG_MAX_ITERATIONS,
        }
    }

    /// Solves for `dv`, which holds a warm start on entry (its constrained part is replaced by
    /// `z`), in `scratch`'s vectors.
    pub fn solve(mut self, dv: &mut [DVec3], scratch: &mut Scratch) -> CgOutcome {
        let Scratch { r, c, q, p } = scratch;
        p.resize(r.len(), DVec3::ZERO);
        if let Preconditioner::Multigrid(mg) = &mut self.preconditioner {
            mg.prepare(self.system, self.model, self.constraints);
        }
        if !self.earlier.is_empty() {
            self.project_warm_start(dv, c, q);
        }
        let CgProblem {
            system,
            model,
            constraints,
            b,
            z,
            earlier: _,
            mut preconditioner,
            tolerance,
            max_iterations,
        } = self;
        // Moved out for the solve so that `system` can lend its per-spring scratch to `apply`.
        let inv_diag = std::mem::take(&mut system.inv_diag);
        let inv = &inv_diag;
        // out = S P⁻¹ r for a filtered r; returns rᵀ out (every use of the preconditioner is
        // followed by that product, which the pass writing `out` sums at once).
        let apply = |preconditioner: &mut Preconditioner<'_>, r: &[DVec3], out: &mut [DVec3]| {
            match preconditioner {
                Preconditioner::BlockJacobi => fill_and_sum(out, |i| {
                    let z = constraints[i].filter(inv[i] * r[i]);
                    (z, r[i].dot(z))
                }),
                Preconditioner::Multigrid(mg) => mg.apply(constraints, r, out),
            }
        };
        // (S h M g)ᵀ P⁻¹ (S h M g), with q (free until the first product) holding the weight's
        // impulse S h M g. A multigrid keeps it with its values: the same values, constraints and
        // impulse give the same bits, and a kept one saves an application a solve.
        let hg = model.simulation.dt * model.simulation.gravity;
        let kept = match &preconditioner {
            Preconditioner::Multigrid(mg) => mg.weight_norm(hg),
            Preconditioner::BlockJacobi => None,
        };
        let weight = kept.unwrap_or_else(|| {
            q.par_iter_mut()
                .enumerate()
                .with_min_len(PARTICLE_CHUNK)
                .for_each(|(i, w)| *w = constraints[i].filter(model.mass[i] * hg));
            let weight = apply(&mut preconditioner, q, p);
            if let Preconditioner::Multigrid(mg) = &mut preconditioner {
                mg.keep_weight_norm(hg, weight);
            }
            weight
        });
        let mut precondition = |r: &[DVec3], out: &mut [DVec3]| apply(&mut preconditioner, r, out);
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

    /// Replaces the warm start u₀ in `dv` by the combination of u₀ and the `earlier` solutions u_j
    /// whose free part is closest to the solution in the A-norm (the solve then filters it and
    /// adds z; Fischer, "Projection techniques for iterative solution of Ax = b with successive
    /// right-hand sides", 1998): with the filtered basis d₀ = S u₀, d_j = S(u_j − u_{j−1}),
    ///
    /// Δv₀ = z + Σ_j x_j d_j,  G x = c,  G_ij = d_iᵀ A d_j,  c_i = d_iᵀ b − (A d_i)ᵀ z,
    ///
    /// the Galerkin condition d_iᵀ(A Δv₀ − b) = 0. The last warm start alone (x = e₀) is in that
    /// space, so the projection is never further from the solution. A stiff body's Δv alternates
    /// from step to step after an impact (a step that relaxes a deformation is followed by one
    /// that stops the motion it made), which a single warm start cannot follow: on the stiff 22³
    /// benchmark cube, three solutions take CG from 16.8 to 6.1 iterations a step. Costs one
    /// product per basis vector; `d` and `q` are scratch.
    fn project_warm_start(&mut self, dv: &mut [DVec3], d: &mut [DVec3], q: &mut [DVec3]) {
        let (model, constraints, b, z, earlier) =
            (self.model, self.constraints, self.b, self.z, self.earlier);
        let system = &mut *self.system;
        const K: usize = WARM_START_BASIS;
        assert!(earlier.len() < K, "at most {} earlier solutions", K - 1);
        let k = 1 + earlier.len();
        // The differences of successive solutions span the same space as the solutions, and
        // their Gram matrix keeps its precision where the solutions are nearly parallel (a stiff
        // body's Δv is its weight's impulse plus a small deformation part). Basis vector j at
        // particle p, from the warm start's value there:
        let basis = |j: usize, p: usize, u0: DVec3| match j {
            0 => u0,
            1 => earlier[0][p] - u0,
            _ => earlier[j - 1][p] - earlier[j - 2][p],
        };
        let mut gram = [[0.0; K]; K];
        let mut c = [0.0; K];
        for j in 0..k {
            d.par_iter_mut()
                .enumerate()
                .with_min_len(PARTICLE_CHUNK)
                .for_each(|(p, d)| *d = constraints[p].filter(basis(j, p, dv[p])));
            system.apply(model, d, q);
            for (i, row) in gram.iter_mut().enumerate().take(j) {
                row[j] = chunked_sum(d.len(), |p| {
                    constraints[p].filter(basis(i, p, dv[p])).dot(q[p])
                });
            }
            gram[j][j] = chunked_sum(d.len(), |p| d[p].dot(q[p]));
            c[j] = chunked_sum(d.len(), |p| d[p].dot(b[p]) - q[p].dot(z[p]));
        }
        let x = solve_gram(&gram, &c, k);
        dv.par_iter_mut()
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(p, v)| {
                *v = (0..k).fold(DVec3::ZERO, |sum, j| sum + x[j] * basis(j, p, *v))
            });
    }
}

/// Solves G x = c for the symmetric positive semi-definite Gram matrix of the first `k` basis
/// vectors (upper triangle given) by an LDLᵀ factorisation that leaves out (x_j = 0) each
/// vector whose pivot is below [`INDEPENDENT`] of its diagonal entry, i.e. nearly spanned by
/// the ones before it. Non-finite coefficients give the plain warm start (x = e₀).
fn solve_gram(
    gram: &[[f64; WARM_START_BASIS]; WARM_START_BASIS],
    c: &[f64; WARM_START_BASIS],
    k: usize,
) -> [f64; WARM_START_BASIS] {
    const K: usize = WARM_START_BASIS;
    let g = |i: usize, j: usize| gram[i.min(j)][i.max(j)];
    let mut l = [[0.0; K]; K];
    let mut pivot = [0.0; K];
    let mut kept = [false; K];
    for j in 0..k {
        let v = g(j, j) - (0..j).map(|m| l[j][m] * l[j][m] * pivot[m]).sum::<f64>();
        if !(v.is_finite() && v > INDEPENDENT * g(j, j)) {
            continue; // l's column j stays 0
        }
        kept[j] = true;
        pivot[j] = v;
        for i in j + 1..k {
            l[i][j] = (g(i, j) - (0..j).map(|m| l[i][m] * l[j][m] * pivot[m]).sum::<f64>()) / v;
        }
    }
    let mut y = [0.0; K];
    for j in (0..k).filter(|&j| kept[j]) {
        y[j] = c[j] - (0..j).map(|m| l[j][m] * y[m]).sum::<f64>();
    }
    let mut x = [0.0; K];
    for j in (0..k).rev().filter(|&j| kept[j]) {
        x[j] = y[j] / pivot[j] - (j + 1..k).map(|i| l[i][j] * x[i]).sum::<f64>();
    }
    if x.iter().all(|x| x.is_finite()) {
        x
    } else {
        let mut plain = [0.0; K];
        plain[0] = 1.0;
        plain
    }
}
