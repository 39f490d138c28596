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
//! same scheme as the spring forces, so it is deterministic for any thread count. On a model
//! of lattice bodies (cuboids, mesh bodies) the product and the springs' share of the assembly are [`LatticeSystem`]'s
//! instead: per particle over the lattice offsets, each block recomputed from the positions
//! and the spring's stored 1/ℓ, no spring list built or read (the per-spring arrays here stay
//! empty).
//!
//! Pairs of bodies in contact at the start of the step ([`Partners`]) enter the same way, as
//! springs along their normal n that only push: with the penalty F n on a (F > 0,
//! [`crate::body_contact`]), stiffness k and damping c, ∂f_a/∂x_a = −k nnᵀ (the transverse term
//! k(R − d)/d (I − nnᵀ) dropped, as for a compressed spring) and ∂f_a/∂v_a = −c nnᵀ, so the
//! pair's block is β nnᵀ with β = h c + h² k and its share of the right-hand side
//! h(F − h k (v_a − v_b)·n) n. A pair whose penalty does not push at the start (F ≤ 0) is left
//! out of the step's system.

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use softbody_scene::{Adjacency, Model};

use super::lattice::{LatticeSystem, block, inverse_length, transverse};
use crate::body_contact::{PENALTY_IMPLICIT, Partners, penalty_law};
use crate::forces::PARTICLE_CHUNK;
use crate::spring_forces::{self, gather, gather_block};

const SPRING_CHUNK: usize = 4096;

/// The linearisation at the start of a step.
#[derive(Debug, Default)]
pub struct System {
    /// Unit direction u of each spring (on the spring list's route; these per-spring arrays are
    /// empty on the lattices').
    pub u: Vec<DVec3>,
    /// β of each spring.
    pub beta: Vec<f64>,
    /// γ of each spring.
    pub gamma: Vec<f64>,
    /// Per-spring scratch: forces while assembling b, then products z_s.
    pub per_spring: Vec<DVec3>,
    /// m_i (1 + h·drag): the mass part of each diagonal block.
    pub mass_diag: Vec<f64>,
    /// Diagonal blocks (mass, springs and pairs; what the multigrid coarsens).
    pub diag: Vec<DMat3>,
    /// Inverse diagonal blocks (block-Jacobi preconditioner).
    pub inv_diag: Vec<DMat3>,
    /// The pairs of bodies in contact, when the model has contact between bodies.
    pub pairs: Option<PairBlocks>,
    /// The product and the springs' sums without a spring list, on a model of cuboids.
    pub lattice: Option<LatticeSystem>,
    /// Assemblies so far.
    assembly: u64,
}

/// The pairs' share of the system: the step's pairs and their adjacency (copied from the
/// [`Partners`], reusing the buffers), per pair its normal n and β (0 for a pair left out),
/// and the per-pair scratch.
#[derive(Debug, Default)]
pub struct PairBlocks {
    /// The pairs (a, b), sorted.
    pub ends: Vec<[u32; 2]>,
    /// Each particle's `2·pair + side` entries.
    pub adjacency: Adjacency,
    /// n of each pair.
    pub n: Vec<DVec3>,
    /// β of each pair.
    pub beta: Vec<f64>,
    /// Per-pair scratch: (F − h k (v_a − v_b)·n) n while assembling b, then products.
    pub per_pair: Vec<DVec3>,
}

impl PairBlocks {
    fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        vec_bytes(&self.ends)
            + vec_bytes(&self.adjacency.offsets)
            + vec_bytes(&self.adjacency.entries)
            + vec_bytes(&self.n)
            + vec_bytes(&self.beta)
            + vec_bytes(&self.per_pair)
    }

    /// Linearises each pair's penalty at (x, v).
    fn assemble(&mut self, model: &Model, partners: &Partners, x: &[DVec3], v: &[DVec3]) {
        let h = model.simulation.dt;
        self.ends.clear();
        self.ends.extend_from_slice(partners.pairs());
        self.adjacency.clone_from(partners.adjacency());
        let pairs = &self.ends;
        self.n.resize(pairs.len(), DVec3::ZERO);
        self.beta.resize(pairs.len(), 0.0);
        self.per_pair.resize(pairs.len(), DVec3::ZERO);
        (&mut self.n, &mut self.beta, &mut self.per_pair, pairs)
            .into_par_iter()
            .for_each(|(n, beta, g, &[a, b])| {
                let (a, b) = (a as usize, b as usize);
                (*n, *beta, *g) = match penalty_law(model, PENALTY_IMPLICIT, [a, b], x, v) {
                    Some(p) => {
                        let un = (v[a] - v[b]).dot(p.normal);
                        (
                            p.normal,
                            h * p.damping + h * h * p.stiffness,
                            (p.force - h * p.stiffness * un) * p.normal,
                        )
                    }
                    None => (DVec3::ZERO, 0.0, DVec3::ZERO),
                };
            });
    }

    /// z_p = β_p n_p n_p·(p_a − p_b) for each pair.
    fn products(&mut self, p: &[DVec3]) {
        self.per_pair
            .par_iter_mut()
            .zip(self.ends.par_iter())
            .zip(self.n.par_iter().zip(self.beta.par_iter()))
            .for_each(|((z, &[a, b]), (n, &beta))| {
                *z = beta * n.dot(p[a as usize] - p[b as usize]) * *n;
            });
    }
}

/// What a product multiplies: a vector, or CG's next search direction c ← p + βc.
enum Operand<'a> {
    Vector(&'a [DVec3]),
    Direction {
        p: &'a [DVec3],
        beta: f64,
        c: &'a mut [DVec3],
    },
}

/// CG's next search direction p + βc: one definition for both routes' updates.
#[inline(always)]
pub(crate) fn direction(p: DVec3, beta: f64, c: DVec3) -> DVec3 {
    p + beta * c
}

impl System {
    /// Sized for `model`.
    pub fn new(model: &Model) -> System {
        let lattice = LatticeSystem::new(model);
        let n = model.len();
        let s = if lattice.is_some() {
            0
        } else {
            model.springs().len()
        };
        System {
            u: vec![DVec3::ZERO; s],
            beta: vec![0.0; s],
            gamma: vec![0.0; s],
            per_spring: vec![DVec3::ZERO; s],
            mass_diag: vec![0.0; n],
            diag: vec![DMat3::IDENTITY; n],
            inv_diag: vec![DMat3::IDENTITY; n],
            pairs: model.contact.enabled().then(PairBlocks::default),
            lattice,
            assembly: 0,
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
            + vec_bytes(&self.diag)
            + vec_bytes(&self.inv_diag)
            + self.pairs.as_ref().map_or(0, PairBlocks::memory_bytes)
            + self.lattice.as_ref().map_or(0, LatticeSystem::memory_bytes)
    }

    /// Linearises at (x, v), with the pairs of bodies in contact `partners` (given exactly when
    /// the model has contact between bodies), and writes the right-hand side
    /// h(f + h ∂f/∂x v) into `b`, f including the `external` forces on the particles.
    pub fn assemble(
        &mut self,
        model: &Model,
        (partners, external): (Option<&Partners>, Option<&[DVec3]>),
        x: &[DVec3],
        v: &[DVec3],
        b: &mut [DVec3],
    ) {
        let h = model.simulation.dt;
        self.assembly += 1;
        if let (Some(blocks), Some(partners)) = (self.pairs.as_mut(), partners) {
            blocks.assemble(model, partners, x, v);
        }
        if let Some(lattice) = self.lattice.as_mut() {
            lattice.linearise(x);
            lattice.assemble(v, h);
        } else {
            self.assemble_springs(model, x, v);
        }
        let sim = &model.simulation;
        let (per_spring, u, beta, gamma) = (&self.per_spring, &self.u, &self.beta, &self.gamma);
        let lattice = self.lattice.as_ref();
        // Σ± g_s and Σ B_s of particle i's springs.
        let springs = |i: usize| match lattice {
            Some(lattice) => {
                let sums = lattice.sums(i);
                (sums.force, sums.block())
            }
            None => {
                let mut block = DMat3::ZERO;
                for &e in model.adjacency().of(i) {
                    let s = (e >> 1) as usize;
                    block += outer(u[s], beta[s]) + DMat3::from_diagonal(DVec3::splat(gamma[s]));
                }
                (gather(model.adjacency(), per_spring, i), block)
            }
        };
        let pairs = self.pairs.as_ref();
        b.par_iter_mut()
            .zip(
                self.mass_diag
                    .par_iter_mut()
                    .zip(self.diag.par_iter_mut().zip(self.inv_diag.par_iter_mut())),
            )
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (b, (md, (diag, inv))))| {
                let m = model.mass[i];
                let (force, springs_block) = springs(i);
                let mut f = m * sim.gravity - sim.drag * m * v[i] + force;
                if let Some(external) = external {
                    f += external[i];
                }
                *md = m * (1.0 + h * sim.drag);
                let mut block = DMat3::from_diagonal(DVec3::splat(*md)) + springs_block;
                if let Some(pairs) = pairs {
                    f += gather(&pairs.adjacency, &pairs.per_pair, i);
                    for &e in pairs.adjacency.of(i) {
                        let p = (e >> 1) as usize;
                        block += outer(pairs.n[p], pairs.beta[p]);
                    }
                }
                *b = h * f;
                *diag = block;
                *inv = block.inverse();
            });
    }

    /// The spring list's share of the assembly: per spring u, β, γ and
    /// g_s = f_s − h K_s (v_a − v_b).
    fn assemble_springs(&mut self, model: &Model, x: &[DVec3], v: &[DVec3]) {
        let h = model.simulation.dt;
        let springs = model.springs();
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
                    let inv_len = inverse_length(d);
                    (u[k], beta[k], gamma[k]) = block(d, inv_len, rest, (h * kd, h * h * ks));
                    let (dir, alpha) = (u[k], transverse(inv_len, rest));
                    let w = v[a] - v[bb];
                    let y = ks * (1.0 - alpha) * dir.dot(w) * dir + ks * alpha * w;
                    let f = spring_forces::spring_force(x[a], x[bb], v[a], v[bb], rest, ks, kd);
                    g[k] = f - h * y;
                }
            });
    }

    /// Which assembly the system holds (a count): what was computed from it stays valid while
    /// this does not change.
    pub fn assembly(&self) -> u64 {
        self.assembly
    }

    /// out = A p.
    pub fn apply(&mut self, model: &Model, p: &[DVec3], out: &mut [DVec3]) {
        self.apply_to(model, Operand::Vector(p), out);
    }

    /// c ← p + βc (CG's next search direction), then out = A c. On the lattices' route the
    /// update writes c's copy by axis for the product in the same pass (one pass over the
    /// vectors less per CG iteration).
    pub fn apply_direction(
        &mut self,
        model: &Model,
        p: &[DVec3],
        beta: f64,
        c: &mut [DVec3],
        out: &mut [DVec3],
    ) {
        self.apply_to(model, Operand::Direction { p, beta, c }, out);
    }

    fn apply_to(&mut self, model: &Model, operand: Operand<'_>, out: &mut [DVec3]) {
        let (p, by_axis): (&[DVec3], bool) = match operand {
            Operand::Vector(p) => (p, false),
            Operand::Direction { p, beta, c } => {
                match &mut self.lattice {
                    Some(lattice) => lattice.set_direction(p, beta, c),
                    None => c
                        .par_iter_mut()
                        .zip(p.par_iter())
                        .with_min_len(PARTICLE_CHUNK)
                        .for_each(|(c, p)| *c = direction(*p, beta, *c)),
                }
                (c, self.lattice.is_some())
            }
        };
        if let Some(pairs) = self.pairs.as_mut() {
            pairs.products(p);
        }
        let pairs = self.pairs.as_ref();
        match &mut self.lattice {
            Some(lattice) => {
                if !by_axis {
                    lattice.set_operand(p);
                }
                lattice.product(&self.mass_diag, out);
                if let Some(pairs) = pairs {
                    out.par_iter_mut()
                        .enumerate()
                        .with_min_len(PARTICLE_CHUNK)
                        .for_each(|(i, o)| *o += gather(&pairs.adjacency, &pairs.per_pair, i));
                }
            }
            None => self.apply_springs(model, p, out),
        }
    }

    /// out = A p by the spring list: z_s for each spring, then each particle's gather.
    fn apply_springs(&mut self, model: &Model, p: &[DVec3], out: &mut [DVec3]) {
        let springs = model.springs();
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
        let pairs = self.pairs.as_ref();
        const BLOCK: usize = 64;
        out.par_chunks_mut(PARTICLE_CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (k, out) in out.chunks_mut(BLOCK).enumerate() {
                    let first = c * PARTICLE_CHUNK + k * BLOCK;
                    // Σ± z_s per particle, four particles side by side: `gather`'s bits.
                    gather_block(model.adjacency(), per_spring, first, out);
                    for (j, o) in out.iter_mut().enumerate() {
                        let i = first + j;
                        *o = md[i] * p[i] + *o;
                        if let Some(pairs) = pairs {
                            *o += gather(&pairs.adjacency, &pairs.per_pair, i);
                        }
                    }
                }
            });
    }
}

/// β uuᵀ.
pub(crate) fn outer(u: DVec3, beta: f64) -> DMat3 {
    DMat3::from_cols(u * u.x, u * u.y, u * u.z) * beta
}
