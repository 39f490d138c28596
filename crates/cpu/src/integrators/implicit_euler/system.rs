//! The linear system of one backward-Euler step, matrix-free:
//!
//! (M − h ∂f/∂v − h² ∂f/∂x) Δv = h (f + h ∂f/∂x v).
//!
//! For spring s with d = x_a − x_b, length ℓ, u = d/ℓ:
//! ∂f_a/∂v_a = −k_d uuᵀ and ∂f_a/∂x_a = −K with K = k_s[uuᵀ + α(I − uuᵀ)], α = max(0, 1 − r/ℓ).
//! The exact stiffness term has α = 1 − r/ℓ, negative for a compressed spring, which makes the
//! matrix indefinite; clamping it at zero (dropping the transverse term of compressed springs)
//! keeps K positive semi-definite, so the system matrix is symmetric positive definite and CG
//! applies. The spring's block in the matrix is
//! B = h k_d uuᵀ + h² K = β uuᵀ + γ I with β = h k_d + h² k_s (1 − α), γ = h² k_s α,
//! added to the (a, a) and (b, b) blocks and subtracted from (a, b) and (b, a). Drag adds
//! h·drag·m I to each diagonal block.
//!
//! A product A p is a per-spring pass (z_s = B_s (p_a − p_b)) and a per-particle gather, the
//! same scheme as the spring forces, so it is deterministic for any thread count.

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use softbody_scene::Model;

use crate::forces::PARTICLE_CHUNK;
use crate::spring_forces::{self, gather, gather_block};

const SPRING_CHUNK: usize = 4096;

/// Per-spring data of the linearisation at the start of a step.
#[derive(Debug, Default)]
pub struct System {
    /// Unit direction u of each spring.
    pub u: Vec<DVec3>,
    /// β of each spring.
    pub beta: Vec<f64>,
    /// γ of each spring.
    pub gamma: Vec<f64>,
    /// Per-spring scratch: forces while assembling b, then products z_s.
    pub per_spring: Vec<DVec3>,
    /// m_i (1 + h·drag): the mass part of each diagonal block.
    pub mass_diag: Vec<f64>,
    /// Inverse diagonal blocks (block-Jacobi preconditioner).
    pub inv_diag: Vec<DMat3>,
}

impl System {
    /// Sized for `model`.
    pub fn new(model: &Model) -> System {
        let (n, s) = (model.len(), model.springs.len());
        System {
            u: vec![DVec3::ZERO; s],
            beta: vec![0.0; s],
            gamma: vec![0.0; s],
            per_spring: vec![DVec3::ZERO; s],
            mass_diag: vec![0.0; n],
            inv_diag: vec![DMat3::IDENTITY; n],
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        vec_bytes(&self.u)
            + vec_bytes(&self.beta)
            + vec_bytes(&self.gamma)
            + vec_bytes(&self.per_spring)
            + vec_bytes(&self.mass_diag)
            + vec_bytes(&self.inv_diag)
    }

    /// Linearises at (x, v) and writes the right-hand side h(f + h ∂f/∂x v) into `b`.
    pub fn assemble(&mut self, model: &Model, x: &[DVec3], v: &[DVec3], b: &mut [DVec3]) {
        let h = model.simulation.dt;
        let springs = &model.springs;
        // Per spring: its force f_s and its stiffness product y_s = K_s (v_a − v_b); store
        // g_s = f_s − h y_s, so that b_i = h (gravity + drag + Σ± g_s) in one gather, since
        // (∂f/∂x v)_i = −Σ± y_s.
        (
            self.per_spring.par_chunks_mut(SPRING_CHUNK),
            self.u.par_chunks_mut(SPRING_CHUNK),
        )
            .into_par_iter()
            .zip(
                self.beta
                    .par_chunks_mut(SPRING_CHUNK)
                    .zip(self.gamma.par_chunks_mut(SPRING_CHUNK)),
            )
            .enumerate()
            .for_each(|(c, ((g, u), (beta, gamma)))| {
                for k in 0..g.len() {
                    let s = c * SPRING_CHUNK + k;
                    let (a, bb) = (springs.a[s] as usize, springs.b[s] as usize);
                    let (ks, kd, rest) =
                        (springs.stiffness[s], springs.damping[s], springs.rest[s]);
                    let d = x[a] - x[bb];
                    let len = d.length();
                    let dir = if len > 0.0 { d / len } else { DVec3::ZERO };
                    let alpha = if len > 0.0 {
                        (1.0 - rest / len).max(0.0)
                    } else {
                        0.0
                    };
                    let w = v[a] - v[bb];
                    let y = ks * (1.0 - alpha) * dir.dot(w) * dir + ks * alpha * w;
                    let f = spring_forces::spring_force(x[a], x[bb], v[a], v[bb], rest, ks, kd);
                    g[k] = f - h * y;
                    u[k] = dir;
                    beta[k] = h * kd + h * h * ks * (1.0 - alpha);
                    gamma[k] = h * h * ks * alpha;
                }
            });
        let sim = &model.simulation;
        let per_spring = &self.per_spring;
        let (u, beta, gamma) = (&self.u, &self.beta, &self.gamma);
        b.par_iter_mut()
            .zip(
                self.mass_diag
                    .par_iter_mut()
                    .zip(self.inv_diag.par_iter_mut()),
            )
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (b, (md, inv)))| {
                let m = model.mass[i];
                *b = h
                    * (m * sim.gravity - sim.drag * m * v[i]
                        + gather(&model.adjacency, per_spring, i));
                *md = m * (1.0 + h * sim.drag);
                let mut block = DMat3::from_diagonal(DVec3::splat(*md));
                for &e in model.adjacency.of(i) {
                    let s = (e >> 1) as usize;
                    let us = u[s];
                    block += DMat3::from_cols(us * us.x, us * us.y, us * us.z) * beta[s]
                        + DMat3::from_diagonal(DVec3::splat(gamma[s]));
                }
                *inv = block.inverse();
            });
    }

    /// out = A p.
    pub fn apply(&mut self, model: &Model, p: &[DVec3], out: &mut [DVec3]) {
        let springs = &model.springs;
        let (u, beta, gamma) = (&self.u, &self.beta, &self.gamma);
        assert!(springs.b.len() == springs.len() && u.len() == springs.len());
        assert!(beta.len() == springs.len() && gamma.len() == springs.len());
        self.per_spring
            .par_chunks_mut(SPRING_CHUNK)
            .enumerate()
            .for_each(|(c, z)| {
                let r = c * SPRING_CHUNK..c * SPRING_CHUNK + z.len();
                let ends = springs.a[r.clone()].iter().zip(&springs.b[r.clone()]);
                let coefficients = u[r.clone()].iter().zip(&beta[r.clone()]).zip(&gamma[r]);
                for ((z, (&a, &b)), ((u, &beta), &gamma)) in
                    z.iter_mut().zip(ends).zip(coefficients)
                {
                    let w = p[a as usize] - p[b as usize];
                    *z = beta * u.dot(w) * *u + gamma * w;
                }
            });
        let per_spring = &self.per_spring[..];
        let md = &self.mass_diag;
        const BLOCK: usize = 64;
        out.par_chunks_mut(PARTICLE_CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (k, out) in out.chunks_mut(BLOCK).enumerate() {
                    let first = c * PARTICLE_CHUNK + k * BLOCK;
                    // Σ± z_s per particle, four particles side by side: `gather`'s bits.
                    gather_block(&model.adjacency, per_spring, first, out);
                    for (j, o) in out.iter_mut().enumerate() {
                        let i = first + j;
                        *o = md[i] * p[i] + *o;
                    }
                }
            });
    }
}
