//! The step's system on models of lattice bodies (cuboids and mesh bodies), particle by
//! particle, without a spring list: the product
//!
//! (A p)_i = m_i(1 + h·drag) p_i + Σ_{springs (i, b)} z_s − Σ_{springs (a, i)} z_s,
//! z_s = B_s (p_a − p_b), B_s = β uuᵀ + γ I,
//!
//! the springs' shares of the assembly, per particle Σ_{(i, b)} g_s − Σ_{(a, i)} g_s with
//! g_s = f_s − h K_s (v_a − v_b) (the right-hand side's) and Σ B_s over its springs (the
//! diagonal block's), and single blocks B_s for the multigrid's first coarse level
//! ([`LatticeSystem::spring`]): the matrix of [`super::system`], each spring's block recomputed
//! from the positions and the spring's 1/ℓ, the one value per spring stored at the step's start
//! (`block` here is the one definition of u, β, γ, which the spring list's assembly uses too).
//!
//! Why: the per-spring product writes z_s for every spring and gathers it back through the
//! adjacency, and reads u, β, γ and both ends' indices: about 150 B per spring and product,
//! so the 46³ cube's 1.5 M springs stream ~220 MB through memory for each of its ~95
//! products a step. Here a product reads the positions and p (one array per axis), and 1/ℓ:
//! about 200 B per particle, and each block costs a few multiply-adds at each of its two ends;
//! the square root and the division were paid once, in [`LatticeSystem::linearise`].
//! 46³: 0.83 → 0.38 s a step (BENCHMARKS.md). The assembly likewise keeps no per-spring
//! arrays (the spring list's holds 64 B per spring: u, β, γ, and g_s).
//!
//! Both ends of a spring take its term from the same operations on the same inputs
//! (d = x_a − x_b, 1/ℓ, p_a − p_b or v_a − v_b), so their terms are exact negatives (z_s, g_s)
//! or equal (B_s), and the matrix is exactly symmetric, as CG needs. On a body's inner planes
//! each term is computed once, at the spring's first end, and handed to its second through a
//! ring per offset (`slab_terms`: the product 1.5× faster at 22³ and 46³); the planes
//! nearest the faces compute it at both ends. A particle's sums run in a fixed order (its own
//! term, then the body's offsets in [`OFFSETS`] order, each as first end then as second end),
//! so the bits do not depend on the thread count or on which planes the slabs hold; they
//! differ from the spring list's in rounding only.
//!
//! A mesh body's lattice has points without particles. The loops run over every point of
//! every lattice (the *slots*) as over a cuboid's: the positions and operands are copied into
//! slot order (zero where a point has no particle), 1/ℓ is stored 0 where the mask has no
//! spring, which makes its terms zero, and the sums are read back by each particle's slot.
//! The lattices' points outnumber the particles (the 8 mm torus: 105,861 points for 62,168
//! particles), but the loops keep their constant partner steps, their vectors and their slabs.

use std::ops::Range;

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use softbody_scene::Model;
use softbody_scene::topology::OFFSETS;

use crate::forces::PARTICLE_CHUNK;
use crate::spring_forces::Isa;

use super::system::{direction, outer};

/// 1/ℓ of a spring of ends x_a − x_b = `d` (0 for a spring crushed to zero length, which
/// [`block`] then gives no direction and no transverse stiffness).
#[inline(always)]
pub(crate) fn inverse_length(d: DVec3) -> f64 {
    let len = d.length();
    if len > 0.0 { 1.0 / len } else { 0.0 }
}

/// A spring's block B = β uuᵀ + γ I at d = x_a − x_b, with 1/ℓ `inv_len`, rest length `rest`
/// and `(h k_d, h² k_s)`: u = d/ℓ, α = max(0, 1 − r/ℓ) (0 for ℓ = 0), β = h k_d + h² k_s (1 − α),
/// γ = h² k_s α. Returns (u, β, γ); the one definition of the block, for the assembly and
/// both products.
#[inline(always)]
pub(crate) fn block(
    d: DVec3,
    inv_len: f64,
    rest: f64,
    (hkd, h2ks): (f64, f64),
) -> (DVec3, f64, f64) {
    let alpha = transverse(inv_len, rest);
    (d * inv_len, hkd + h2ks * (1.0 - alpha), h2ks * alpha)
}

/// α = max(0, 1 − r/ℓ), the share of k_s that acts across a stretched spring (0 for ℓ = 0).
#[inline(always)]
pub(crate) fn transverse(inv_len: f64, rest: f64) -> f64 {
    // Computed before the test, not inside it: in a vectorised loop a load of `rest` under the
    // lanes' condition became a masked gather of one address, the product's slowest
    // instruction.
    let alpha = (1.0 - rest * inv_len).max(0.0);
    if inv_len > 0.0 { alpha } else { 0.0 }
}

/// The springs of one lattice offset.
#[derive(Debug, Clone, Copy)]
struct Offset {
    /// Its bit in a mask's spring bits (bit o of [`OFFSETS`]' offset o).
    bit: u16,
    /// (di, dj, dk).
    delta: [isize; 3],
    /// The partner's index minus the particle's.
    step: isize,
    rest: f64,
    /// (k_s, k_d).
    parameters: (f64, f64),
    /// (h k_d, h² k_s).
    coefficients: (f64, f64),
}

/// One lattice body.
#[derive(Debug)]
struct Body {
    /// Its first slot.
    first: usize,
    dims: [usize; 3],
    offsets: Vec<Offset>,
    /// A mesh body's spring bits per point ([`softbody_scene::model::LatticeMask::springs`]);
    /// `None` for a cuboid, whose every spring with its partner in the lattice exists.
    springs: Option<Vec<u16>>,
    /// 1/ℓ of each spring at the step's start, offset after offset, each indexed by its first
    /// end within the body; 0 where the offset's partner lies outside the lattice (never
    /// written: the loops read these entries and must get zero terms from them).
    inv_len: Vec<f64>,
}

impl Body {
    fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// The planes k whose every particle has every offset's partners, at +step and −step, in
    /// the body's index range (as a particle of another row where its own spring is missing):
    /// every plane but a few nearest the faces (k in 2..nz − 2 with bending or shear springs).
    fn inner_planes(&self) -> Range<usize> {
        let plane = (self.dims[0] * self.dims[1]) as isize;
        let n = self.len() as isize;
        let nz = self.dims[2];
        let whole = |k: usize| {
            let q0 = plane * k as isize;
            self.offsets.iter().all(|s| {
                let planes = 0..nz as isize;
                planes.contains(&(k as isize + s.delta[2]))
                    && planes.contains(&(k as isize - s.delta[2]))
                    && q0 >= s.step.abs()
                    && q0 + plane + s.step.abs() <= n
            })
        };
        let start = (0..nz).find(|&k| whole(k)).unwrap_or(nz);
        let end = (start..nz).find(|&k| !whole(k)).unwrap_or(nz);
        debug_assert!(
            (end..nz).all(|k| !whole(k)),
            "the inner planes are contiguous"
        );
        start..end
    }
}

/// The springs' sums of one particle in the assembly: Σ± g_s and the upper half of Σ B_s.
#[derive(Debug, Clone, Copy, Default)]
pub struct SpringSums {
    /// Σ_{(i, b)} g_s − Σ_{(a, i)} g_s, g_s = f_s − h K_s (v_a − v_b).
    pub force: DVec3,
    /// Σ B_s: xx, yy, zz, xy, xz, yz.
    pub block: [f64; 6],
}

impl SpringSums {
    /// Σ B_s as a matrix.
    pub fn block(&self) -> DMat3 {
        let [xx, yy, zz, xy, xz, yz] = self.block;
        DMat3::from_cols(
            DVec3::new(xx, xy, xz),
            DVec3::new(xy, yy, yz),
            DVec3::new(xz, yz, zz),
        )
    }
}

/// The system's data on the lattices: per body its lattice and per spring 1/ℓ.
#[derive(Debug)]
pub struct LatticeSystem {
    bodies: Vec<Body>,
    /// Where some lattice has points without particles, which slot holds which particle;
    /// `None` where every point is a particle (cuboids: slot i is particle i).
    slots: Option<Slots>,
    /// The positions of the linearisation, by axis and slot.
    x: Axes,
    /// The vector of the product (or the velocities of the assembly) under way, by axis and
    /// slot.
    p: Axes,
    /// The springs' sums of the last assembly, per slot.
    sums: Vec<SpringSums>,
    /// The product by slot, where slots are not particles (else empty).
    product: Vec<DVec3>,
    isa: Isa,
    /// Whether inner planes are swept in slabs, each spring's term computed once (else plane
    /// by plane like the faces', computed at both ends: the tests' reference).
    slabs: bool,
}

/// One array per axis (structure of arrays: the loops load whole vectors of consecutive
/// particles instead of shuffling x, y, z out of `DVec3`s).
type Axes = [Vec<f64>; 3];

/// The particles of the slots and the slots of the particles.
#[derive(Debug)]
struct Slots {
    /// Each slot's particle, [`LatticeMask::NONE`] where its point has none.
    ///
    /// [`LatticeMask::NONE`]: softbody_scene::model::LatticeMask::NONE
    particle: Vec<u32>,
    /// Each particle's slot.
    slot: Vec<u32>,
}

impl Slots {
    const NONE: u32 = softbody_scene::model::LatticeMask::NONE;

    /// The particle of slot `s` (`s` holds one: the springs' ends do).
    #[inline(always)]
    fn particle(&self, s: usize) -> usize {
        let p = self.particle[s];
        debug_assert!(p != Self::NONE, "slot {s} has no particle");
        p as usize
    }
}

/// Bits of a spring code ([`LatticeSystem::for_each_spring`]) that hold its offset.
const OFFSET_BITS: u32 = 4;
const _: () = assert!(OFFSETS.len() <= 1 << OFFSET_BITS);

impl LatticeSystem {
    /// For `model` when every body is a lattice (a cuboid or a mesh body); `None` otherwise,
    /// or when the lattices have 2³² points or more.
    pub fn new(model: &Model) -> Option<LatticeSystem> {
        let lattices = model.lattices();
        if lattices.is_empty() || lattices.len() != model.bodies.len() {
            return None;
        }
        let h = model.simulation.dt;
        let points = |l: &softbody_scene::model::Lattice| {
            l.dims.iter().map(|&d| d as usize).product::<usize>()
        };
        let total: usize = lattices.iter().map(points).sum();
        let slots = match lattices.iter().all(|l| l.mask.is_none()) {
            true => None,
            false => {
                u32::try_from(total).ok().filter(|&t| t != Slots::NONE)?;
                let mut particle = Vec::with_capacity(total);
                for l in lattices {
                    match &l.mask {
                        Some(mask) => particle.extend(mask.particle_of.iter().map(|&p| match p {
                            Slots::NONE => Slots::NONE,
                            p => l.first + p,
                        })),
                        None => particle.extend(l.first..l.first + points(l) as u32),
                    }
                }
                let mut slot = vec![0; model.len()];
                for (s, &p) in particle.iter().enumerate() {
                    if p != Slots::NONE {
                        slot[p as usize] = s as u32;
                    }
                }
                Some(Slots { particle, slot })
            }
        };
        let mut first = 0;
        let bodies = (lattices.iter())
            .map(|l| {
                let dims = l.dims.map(|d| d as usize);
                let offsets: Vec<Offset> = (l.springs.iter())
                    .map(|s| {
                        let delta = OFFSETS[s.offset].0.map(|d| d as isize);
                        let [nx, ny, _] = dims.map(|d| d as isize);
                        Offset {
                            bit: 1 << s.offset,
                            delta,
                            step: delta[0] + nx * (delta[1] + ny * delta[2]),
                            rest: s.rest,
                            parameters: (s.stiffness, s.damping),
                            coefficients: (h * s.damping, h * h * s.stiffness),
                        }
                    })
                    .collect();
                let n: usize = dims.iter().product();
                let body = Body {
                    first,
                    dims,
                    inv_len: vec![0.0; offsets.len() * n],
                    offsets,
                    springs: l.mask.as_ref().map(|m| m.springs.clone()),
                };
                first += n;
                body
            })
            .collect();
        Some(LatticeSystem {
            bodies,
            product: match slots {
                Some(_) => vec![DVec3::ZERO; total],
                None => Vec::new(),
            },
            slots,
            x: axes(total),
            p: axes(total),
            sums: vec![SpringSums::default(); total],
            isa: Isa::detect(),
            slabs: true,
        })
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        [&self.x, &self.p]
            .iter()
            .flat_map(|a| a.iter())
            .map(crate::vec_bytes)
            .sum::<u64>()
            + crate::vec_bytes(&self.sums)
            + crate::vec_bytes(&self.product)
            + self.slots.as_ref().map_or(0, |s| {
                crate::vec_bytes(&s.particle) + crate::vec_bytes(&s.slot)
            })
            + (self.bodies.iter())
                .map(|b| {
                    crate::vec_bytes(&b.inv_len) + b.springs.as_ref().map_or(0, crate::vec_bytes)
                })
                .sum::<u64>()
    }

    /// Linearises at the positions `x`: keeps them and each spring's 1/ℓ.
    pub fn linearise(&mut self, x: &[DVec3]) {
        split(x, self.slots.as_ref(), &mut self.x);
        let [x, y, z] = [&self.x[0][..], &self.x[1][..], &self.x[2][..]];
        for body in &mut self.bodies {
            let [nx, ny, nz] = body.dims;
            let (first, offsets, springs) = (body.first, &body.offsets, &body.springs);
            body.inv_len
                .par_chunks_mut(nx * ny)
                .enumerate()
                .for_each(|(plane, inv)| {
                    let (s, k) = (offsets[plane / nz], plane % nz);
                    for (j, row) in inv.chunks_mut(nx).enumerate() {
                        if let Some(r) = first_ends(s.delta, body.dims, j, k) {
                            let q = nx * (j + ny * k);
                            let a = first + q;
                            let b = a.wrapping_add_signed(s.step);
                            for i in r {
                                let (a, b) = (a + i, b + i);
                                let d = DVec3::new(x[a] - x[b], y[a] - y[b], z[a] - z[b]);
                                let exists = springs.as_ref().is_none_or(|m| m[q + i] & s.bit != 0);
                                row[i] = if exists { inverse_length(d) } else { 0.0 };
                            }
                        }
                    }
                });
        }
    }

    /// Computes the springs' sums of the assembly at the linearisation's positions and the
    /// velocities `v`, per particle ([`LatticeSystem::sums`]).
    pub fn assemble(&mut self, v: &[DVec3], h: f64) {
        split(v, self.slots.as_ref(), &mut self.p);
        let mut sums = std::mem::take(&mut self.sums);
        self.traverse(&Assembly { h }, &mut sums, |t| SpringSums {
            force: DVec3::new(t[0], t[1], t[2]),
            block: [t[3], t[4], t[5], t[6], t[7], t[8]],
        });
        self.sums = sums;
    }

    /// The springs' sums of particle `i` in the last assembly.
    #[inline(always)]
    pub fn sums(&self, i: usize) -> &SpringSums {
        match &self.slots {
            Some(slots) => &self.sums[slots.slot[i] as usize],
            None => &self.sums[i],
        }
    }

    /// Makes `p` the operand of the next [`LatticeSystem::product`] (its copy by axis).
    pub fn set_operand(&mut self, p: &[DVec3]) {
        split(p, self.slots.as_ref(), &mut self.p);
    }

    /// c ← p + βc (CG's next search direction) and c the operand of the next
    /// [`LatticeSystem::product`]: in one pass where slots are particles.
    pub fn set_direction(&mut self, p: &[DVec3], beta: f64, c: &mut [DVec3]) {
        if self.slots.is_some() {
            (&mut *c, p)
                .into_par_iter()
                .with_min_len(PARTICLE_CHUNK)
                .for_each(|(c, p)| *c = direction(*p, beta, *c));
            return self.set_operand(c);
        }
        let [x, y, z] = &mut self.p;
        (x, y, z, c, p)
            .into_par_iter()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(x, y, z, c, p)| {
                *c = direction(*p, beta, *c);
                (*x, *y, *z) = (c.x, c.y, c.z);
            });
    }

    /// out = M(1 + h·drag) p + the springs' terms for the operand p, with `mass_diag` the
    /// diagonal's mass part, per particle.
    pub fn product(&mut self, mass_diag: &[f64], out: &mut [DVec3]) {
        let p = [&self.p[0][..], &self.p[1][..], &self.p[2][..]];
        let slots = self.slots.as_ref().map(|s| &s.particle[..]);
        let term = Product {
            mass_diag,
            p,
            slots,
        };
        let emit = |t: [f64; 3]| DVec3::new(t[0], t[1], t[2]);
        let Some(slots) = &self.slots else {
            return self.traverse(&term, out, emit);
        };
        let mut product = std::mem::take(&mut self.product);
        self.traverse(&term, &mut product, emit);
        out.par_iter_mut()
            .zip(&slots.slot)
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(o, &s)| *o = product[s as usize]);
        self.product = product;
    }

    /// Sums `term` per particle over the lattices, the second field the one in `self.p`, and
    /// writes each particle's sums through `emit` into `out`: a body's planes nearest its faces
    /// one by one ([`Work::Plane`]), its inner planes in one slab per thread ([`Work::Slab`]).
    fn traverse<T: Term<K>, const K: usize, O: Send>(
        &self,
        term: &T,
        out: &mut [O],
        emit: impl Fn([f64; K]) -> O + Sync,
    ) {
        let [x, y] = [&self.x, &self.p].map(|a| [&a[0][..], &a[1][..], &a[2][..]]);
        let isa = self.isa;
        for body in &self.bodies {
            let plane = body.dims[0] * body.dims[1];
            let inner = match self.slabs {
                true => body.inner_planes(),
                false => 0..0,
            };
            let out = &mut out[body.first..body.first + body.len()];
            let (below, rest) = out.split_at_mut(inner.start * plane);
            let (middle, above) = rest.split_at_mut(inner.len() * plane);
            let mut work: Vec<(Work, &mut [O])> = Vec::new();
            work.extend(
                below
                    .chunks_mut(plane)
                    .enumerate()
                    .map(|(k, o)| (Work::Plane(k), o)),
            );
            let slabs = rayon::current_num_threads().clamp(1, inner.len().max(1));
            let per_slab = inner.len().div_ceil(slabs).max(1);
            work.extend(
                middle
                    .chunks_mut(per_slab * plane)
                    .enumerate()
                    .map(|(i, o)| {
                        let start = inner.start + i * per_slab;
                        (Work::Slab(start..start + o.len() / plane), o)
                    }),
            );
            work.extend(
                above
                    .chunks_mut(plane)
                    .enumerate()
                    .map(|(k, o)| (Work::Plane(inner.end + k), o)),
            );
            work.into_par_iter()
                .for_each(|(work, out)| work_of(isa, body, term, (x, y), work, out, &emit));
        }
    }

    /// Calls `f(code, a, b)` for every spring (a, b) of the lattices, bodies and offsets in
    /// order, each offset's springs by their first end; `code` names the spring for
    /// [`LatticeSystem::spring`], below 2³¹. `None` when the model
    /// has more particles than such codes hold (2²⁷).
    pub fn for_each_spring(&self, mut f: impl FnMut(u32, usize, usize)) -> Option<()> {
        // A code with a bit to spare (the multigrid's sources add a side bit).
        let slots = self.x[0].len();
        if slots > (u32::MAX >> (OFFSET_BITS + 1)) as usize {
            return None;
        }
        for body in &self.bodies {
            let [nx, ny, nz] = body.dims;
            for (o, s) in body.offsets.iter().enumerate() {
                for (j, k) in (0..nz).flat_map(|k| (0..ny).map(move |j| (j, k))) {
                    let Some(run) = first_ends(s.delta, body.dims, j, k) else {
                        continue;
                    };
                    for i in run {
                        let q = i + nx * (j + ny * k);
                        if body.springs.as_ref().is_some_and(|m| m[q] & s.bit == 0) {
                            continue;
                        }
                        let a = body.first + q;
                        let code = (a as u32) << OFFSET_BITS | o as u32;
                        let (a, b) = self.particles(a, a.wrapping_add_signed(s.step));
                        f(code, a, b);
                    }
                }
            }
        }
        Some(())
    }

    /// The particles of the slots `a` and `b` (which hold particles).
    #[inline(always)]
    fn particles(&self, a: usize, b: usize) -> (usize, usize) {
        match &self.slots {
            Some(slots) => (slots.particle(a), slots.particle(b)),
            None => (a, b),
        }
    }

    /// The body, offset and first end of spring `code`.
    #[inline(always)]
    fn decode(&self, code: u32) -> (&Body, &Offset, usize) {
        let a = (code >> OFFSET_BITS) as usize;
        let body = match self.bodies.len() {
            1 => &self.bodies[0],
            _ => &self.bodies[self.bodies.partition_point(|b| b.first <= a) - 1],
        };
        (
            body,
            &body.offsets[(code & ((1 << OFFSET_BITS) - 1)) as usize],
            a,
        )
    }

    /// The ends (a, b) of spring `code` (particles) and its block B_s at the linearisation.
    #[inline(always)]
    pub fn spring(&self, code: u32) -> (usize, usize, DMat3) {
        let (body, s, a) = self.decode(code);
        let b = a.wrapping_add_signed(s.step);
        let o = (code & ((1 << OFFSET_BITS) - 1)) as usize;
        let inv = body.inv_len[o * body.len() + (a - body.first)];
        let x = &self.x;
        let d = DVec3::new(x[0][a] - x[0][b], x[1][a] - x[1][b], x[2][a] - x[2][b]);
        let (u, beta, gamma) = block(d, inv, s.rest, s.coefficients);
        let (a, b) = self.particles(a, b);
        // Exactly symmetric, as the list's blocks are: (u_r u_c) β.
        (
            a,
            b,
            outer(u, beta) + DMat3::from_diagonal(DVec3::splat(gamma)),
        )
    }
}

/// What a traversal sums per particle: `K` components a spring, the first [`Term::ODD`] added
/// at its first end and subtracted at its second (equal and opposite: products, forces), the
/// rest added at both (the diagonal blocks).
trait Term<const K: usize>: Sync {
    const ODD: usize;

    /// The own terms of the `L` particles from i, where their sums start.
    fn start<const L: usize>(&self, i: usize) -> [[f64; L]; K];

    /// The spring's term at d = x_a − x_b, w = y_a − y_b (y the traversal's second field) and
    /// 1/ℓ; every component zero where 1/ℓ = 0 (a spring the lattice does not have, or one
    /// crushed to zero length).
    fn spring(&self, d: DVec3, w: DVec3, inv_len: f64, s: &Offset) -> [f64; K];
}

/// The product A p: the mass term, then ± z_s.
struct Product<'a> {
    /// Per particle.
    mass_diag: &'a [f64],
    /// Per slot.
    p: [&'a [f64]; 3],
    /// Each slot's particle, where slots are not particles ([`Slots::particle`]).
    slots: Option<&'a [u32]>,
}

impl Term<3> for Product<'_> {
    const ODD: usize = 3;

    #[inline(always)]
    fn start<const L: usize>(&self, i: usize) -> [[f64; L]; 3] {
        // A point without a particle gets 0: its sums are never read.
        let m: [f64; L] = match self.slots {
            None => self.mass_diag[i..i + L].try_into().unwrap(),
            Some(slots) => std::array::from_fn(|l| match slots[i + l] {
                Slots::NONE => 0.0,
                p => self.mass_diag[p as usize],
            }),
        };
        self.p.map(|p| {
            let p: &[f64; L] = p[i..i + L].try_into().unwrap();
            std::array::from_fn(|l| m[l] * p[l])
        })
    }

    #[inline(always)]
    fn spring(&self, d: DVec3, w: DVec3, inv_len: f64, s: &Offset) -> [f64; 3] {
        product(d, w, inv_len, s).to_array()
    }
}

/// The assembly's spring terms: ± g_s = f_s − h K_s (v_a − v_b), then B_s's upper half.
struct Assembly {
    h: f64,
}

impl Term<9> for Assembly {
    const ODD: usize = 3;

    #[inline(always)]
    fn start<const L: usize>(&self, _: usize) -> [[f64; L]; 9] {
        [[0.0; L]; 9]
    }

    /// With u = d/ℓ and ℓ = (d·d)/ℓ (no square root: 1/ℓ is the linearisation's),
    /// f = −(k_s(ℓ − r) + k_d (u·w)) u, the spring force of [`spring_force`] on a;
    /// K w = k_s(1 − α)(u·w) u + k_s α w; B = β uuᵀ + γ I ([`block`]).
    ///
    /// [`spring_force`]: crate::spring_forces::spring_force
    #[inline(always)]
    fn spring(&self, d: DVec3, w: DVec3, inv_len: f64, s: &Offset) -> [f64; 9] {
        let (ks, kd) = s.parameters;
        let (u, beta, gamma) = block(d, inv_len, s.rest, s.coefficients);
        let alpha = transverse(inv_len, s.rest);
        let len = d.dot(d) * inv_len;
        let uw = u.dot(w);
        let f = -(ks * (len - s.rest) + kd * uw) * u;
        let kw = (ks * (1.0 - alpha) * uw) * u + (ks * alpha) * w;
        let g = f - self.h * kw;
        let bu = beta * u;
        [
            g.x,
            g.y,
            g.z,
            bu.x * u.x + gamma,
            bu.y * u.y + gamma,
            bu.z * u.z + gamma,
            bu.x * u.y,
            bu.x * u.z,
            bu.y * u.z,
        ]
    }
}

/// An array per axis and slot from the particles' `DVec3`s (zero in a slot without a
/// particle).
fn split(v: &[DVec3], slots: Option<&Slots>, out: &mut Axes) {
    let [x, y, z] = out;
    let Some(slots) = slots else {
        return (x, y, z, v)
            .into_par_iter()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(x, y, z, v)| (*x, *y, *z) = (v.x, v.y, v.z));
    };
    (x, y, z, &slots.particle)
        .into_par_iter()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(x, y, z, &p)| {
            let v = match p {
                Slots::NONE => DVec3::ZERO,
                p => v[p as usize],
            };
            (*x, *y, *z) = (v.x, v.y, v.z);
        });
}

fn axes(n: usize) -> Axes {
    std::array::from_fn(|_| vec![0.0; n])
}

/// The positions and the second field by axis.
type Fields<'a> = ([&'a [f64]; 3], [&'a [f64]; 3]);

/// A piece of a body's traversal: one plane near its faces, or a slab of inner planes.
#[derive(Debug, Clone)]
enum Work {
    Plane(usize),
    Slab(Range<usize>),
}

/// A piece's sums, compiled for the widest vectors the CPU runs.
fn work_of<T: Term<K>, const K: usize, O>(
    isa: Isa,
    body: &Body,
    term: &T,
    fields: Fields<'_>,
    work: Work,
    out: &mut [O],
    emit: &impl Fn([f64; K]) -> O,
) {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the CPU has AVX-512F (`Isa::detect`).
        Isa::Avx512 => return unsafe { work_avx512(body, term, fields, work, out, emit) },
        // SAFETY: the CPU has AVX2 (as above).
        Isa::Avx2 => return unsafe { work_avx2(body, term, fields, work, out, emit) },
        Isa::Scalar => {}
    }
    work_terms(body, term, fields, work, out, emit);
}

/// [`work_terms`] compiled for AVX-512.
///
/// # Safety
/// The CPU has AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn work_avx512<T: Term<K>, const K: usize, O>(
    body: &Body,
    term: &T,
    fields: Fields<'_>,
    work: Work,
    out: &mut [O],
    emit: &impl Fn([f64; K]) -> O,
) {
    work_terms(body, term, fields, work, out, emit);
}

/// [`work_terms`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn work_avx2<T: Term<K>, const K: usize, O>(
    body: &Body,
    term: &T,
    fields: Fields<'_>,
    work: Work,
    out: &mut [O],
    emit: &impl Fn([f64; K]) -> O,
) {
    work_terms(body, term, fields, work, out, emit);
}

/// A piece's sums: a plane near the faces by [`plane_terms`], a slab by [`slab_terms`].
#[inline(always)]
fn work_terms<T: Term<K>, const K: usize, O>(
    body: &Body,
    term: &T,
    fields: Fields<'_>,
    work: Work,
    out: &mut [O],
    emit: &impl Fn([f64; K]) -> O,
) {
    match work {
        Work::Plane(k) => plane_terms(body, term, fields, k, out, emit),
        Work::Slab(planes) => slab_terms(body, term, fields, planes, out, emit),
    }
}

/// The i of row (j, k) whose spring of offset `delta` has its partner in the lattice.
fn first_ends(delta: [isize; 3], dims: [usize; 3], j: usize, k: usize) -> Option<Range<usize>> {
    let [di, dj, dk] = delta;
    let [nx, ny, nz] = dims.map(|d| d as isize);
    let (j, k) = (j as isize + dj, k as isize + dk);
    ((0..ny).contains(&j) && (0..nz).contains(&k))
        .then(|| (-di).max(0) as usize..(nx - di.max(0)) as usize)
}

/// Plane k's sums into `out` (the plane's), a plane near the body's faces: per particle its
/// own term, then per offset the spring it starts, then the one it ends; each offset over the
/// plane in its own loop, its run cut where partners leave the body. The inner planes'
/// particles get the same terms in the same order, so the same bits, from [`slab_terms`].
///
/// A loop pairs particles at a constant index step, so near the lattice's edges in i or j it
/// pairs a particle with one of another row: there the particle has no spring of the offset,
/// its stored 1/ℓ is 0, which makes the term zero ([`Term::spring`]).
#[inline(always)]
fn plane_terms<T: Term<K>, const K: usize, O>(
    body: &Body,
    term: &T,
    (x, y): Fields<'_>,
    k: usize,
    out: &mut [O],
    emit: &impl Fn([f64; K]) -> O,
) {
    let [nx, ny, nz] = body.dims.map(|d| d as isize);
    let (first, n) = (body.first, body.len() as isize);
    let q0 = (nx * ny) * k as isize;
    let q1 = q0 + nx * ny;
    let k = k as isize;
    let inv = |o: usize| &body.inv_len[o * n as usize..(o + 1) * n as usize];
    // Per offset and side (first ends, second ends): the run of the plane's particles whose
    // partner lies in the body, if the partner's plane exists.
    let runs = |s: &Offset| {
        [1, -1].map(|sign| {
            let step = sign * s.step;
            (0..nz)
                .contains(&(k + sign * s.delta[2]))
                .then(|| (q0.max(-step), q1.min(n - step)))
        })
    };
    let plane = (q1 - q0) as usize;
    // The plane's sums by component.
    let (mut sums, mut scratch) = (vec![0.0; K * plane], vec![0.0; K * CHUNK]);
    for t in 0..plane {
        let start = term.start::<1>(first + q0 as usize + t);
        for c in 0..K {
            sums[c * plane + t] = start[c][0];
        }
    }
    for (o, s) in body.offsets.iter().enumerate() {
        for (side, run) in runs(s).into_iter().enumerate() {
            let Some((t0, t1)) = run else { continue };
            let step = if side == 0 { s.step } else { -s.step };
            let run = (t0 - q0) as usize..(t1 - q0) as usize;
            let mut parts = sums.chunks_exact_mut(plane);
            let sums: [&mut [f64]; K] =
                std::array::from_fn(|_| &mut parts.next().unwrap()[run.clone()]);
            // Offsets step forward (their last non-zero component is positive), so a spring's
            // first end is its lower index: the run's first ends start at t0 on side 0, at
            // t0 − s.step on side 1.
            let from = (if side == 0 { t0 } else { t0 + step }) as usize;
            let (ends, inv) = (
                (first + from, s.step as usize),
                &inv(o)[from..][..run.len()],
            );
            let fields = (x, y);
            if side == 0 {
                run_terms::<T, K, true>(term, sums, fields, ends, inv, s, &mut scratch);
            } else {
                run_terms::<T, K, false>(term, sums, fields, ends, inv, s, &mut scratch);
            }
        }
    }
    for (t, o) in out.iter_mut().enumerate() {
        *o = emit(std::array::from_fn(|c| sums[c * plane + t]));
    }
}

/// Particles per group of [`slab_terms`]: one 512-bit vector of f64.
const LANES: usize = 8;

/// Particles per chunk of [`slab_terms`]: the chunk's sums (K per particle) stay in L1 while
/// every offset passes over them.
const CHUNK: usize = 32 * LANES;

thread_local! {
    /// [`slab_terms`]' rings, kept by each thread from one traversal to the next (a ring of the
    /// 46³ cube's product is 0.6 MB, which a fresh allocation would map and fault in anew).
    static RINGS: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The sums of the inner planes `planes` into `out` (theirs), each spring's term computed once,
/// every offset's partners in the body. The slab is swept in chunks of [`CHUNK`] consecutive
/// particles, and each chunk offset by offset: first the terms of the springs its particles
/// start (each added to its first end's sum and kept in the offset's ring), then, from the
/// ring, those of the springs they end, `step` particles earlier — the terms those particles
/// would compute themselves (the same operations on the same inputs), so the same bits as
/// [`plane_terms`]' two computations and, in each particle's sums, the same order (its own
/// term, then per offset the spring it starts and the one it ends). The springs that end in
/// the slab's first `step` particles start before it and are computed first into the rings.
///
/// Why offset by offset: each pass is a plain loop over consecutive particles with one
/// partner step, which compiles to vector code without per-group bookkeeping (sweeping group
/// by group, all offsets at each, took about 250 instructions per group and offset, most of
/// them bounds checks and ring indices: by its timings about ten cycles a term at 22³, at the
/// Xeon's 2.1 GHz base clock).
///
/// The term of the spring starting at particle q lies in slot (q − q_s) mod R of its offset's
/// ring, R a multiple of [`CHUNK`] of at least step + [`CHUNK`]: a chunk's starts are one run
/// of slots; its ends, slots (q − step − q_s) mod R, are at most two.
#[inline(always)]
fn slab_terms<T: Term<K>, const K: usize, O>(
    body: &Body,
    term: &T,
    (x, y): Fields<'_>,
    planes: Range<usize>,
    out: &mut [O],
    emit: &impl Fn([f64; K]) -> O,
) {
    let (first, n) = (body.first, body.len());
    let plane = body.dims[0] * body.dims[1];
    let (q_s, q_e) = (planes.start * plane, planes.end * plane);
    let offsets = &body.offsets;
    // Per offset: its partner step, its ring's length R and where its components start.
    let steps: Vec<usize> = offsets.iter().map(|s| s.step.unsigned_abs()).collect();
    let lengths: Vec<usize> = (steps.iter())
        .map(|step| (step + CHUNK).next_multiple_of(CHUNK))
        .collect();
    let bases: Vec<usize> = (lengths.iter())
        .scan(0, |at, r| Some(std::mem::replace(at, *at + K * r)))
        .collect();
    let total = K * lengths.iter().sum::<usize>();
    // Taken out of the thread's keeping for the sweep (a closure run by `LocalKey::with` would
    // be compiled without the caller's target features).
    let mut ring = RINGS.take();
    if ring.len() < total {
        ring.resize(total, 0.0);
    }
    // A chunk's sums, component after component.
    let mut sums = vec![0.0; K * CHUNK];
    // The two `starts` calls below are not one closure: a closure here is compiled out of line
    // without the caller's target features (the product 15% slower, measured).
    for (o, s) in offsets.iter().enumerate() {
        let (step, r) = (steps[o], lengths[o]);
        let inv = &body.inv_len[o * n..(o + 1) * n];
        let ring = &mut ring[bases[o]..bases[o] + K * r];
        for q in (q_s - step..q_s).step_by(CHUNK) {
            let len = CHUNK.min(q_s - q);
            let write = r - (q_s - q);
            starts(
                term,
                (x, y),
                (first + q, step),
                &inv[q..q + len],
                s,
                (ring, write, r),
            );
        }
    }
    for c0 in (q_s..q_e).step_by(CHUNK) {
        let len = CHUNK.min(q_e - c0);
        let sums = &mut sums[..K * len];
        for i in 0..len {
            let own = term.start::<1>(first + c0 + i);
            for c in 0..K {
                sums[c * len + i] = own[c][0];
            }
        }
        for (o, s) in offsets.iter().enumerate() {
            let (step, r) = (steps[o], lengths[o]);
            let inv = &body.inv_len[o * n..(o + 1) * n];
            let ring = &mut ring[bases[o]..bases[o] + K * r];
            let write = (c0 - q_s) % r;
            starts(
                term,
                (x, y),
                (first + c0, step),
                &inv[c0..c0 + len],
                s,
                (ring, write, r),
            );
            for c in 0..K {
                let z = &ring[c * r + write..c * r + write + len];
                add::<true>(&mut sums[c * len..(c + 1) * len], z);
            }
            // The ends' slots: from `read` to the ring's end, then on from its start.
            let read = (c0 - q_s + r - step) % r;
            let split = len.min(r - read);
            for c in 0..K {
                let (ring, sum) = (&ring[c * r..(c + 1) * r], &mut sums[c * len..(c + 1) * len]);
                let (sum_a, sum_b) = sum.split_at_mut(split);
                if c < T::ODD {
                    add::<false>(sum_a, &ring[read..read + split]);
                    add::<false>(sum_b, &ring[..len - split]);
                } else {
                    add::<true>(sum_a, &ring[read..read + split]);
                    add::<true>(sum_b, &ring[..len - split]);
                }
            }
        }
        for (i, o) in out[c0 - q_s..c0 - q_s + len].iter_mut().enumerate() {
            *o = emit(std::array::from_fn(|c| sums[c * len + i]));
        }
    }
    RINGS.set(ring);
}

/// The terms of the springs of offset `s` from first ends a, a + 1, … (model indices; one per
/// entry of `inv_len`, their 1/ℓ) to second ends `step` further, into `out` = (ring, at, r)
/// by component (K runs from `at`, r apart), [`LANES`] springs at a time.
///
/// The lanes are read and written without a bounds check each (one check of the whole run
/// first): with the checks, most of this loop's instructions were index comparisons.
#[inline(always)]
fn starts<T: Term<K>, const K: usize>(
    term: &T,
    (x, y): Fields<'_>,
    (a, step): (usize, usize),
    inv_len: &[f64],
    s: &Offset,
    (out, at, r): (&mut [f64], usize, usize),
) {
    let len = inv_len.len();
    let fields: [&[f64]; 6] = [x[0], x[1], x[2], y[0], y[1], y[2]];
    assert!(fields.iter().all(|v| v.len() >= a + step + len));
    assert!(at + len <= r && out.len() >= K * r);
    let groups = len / LANES * LANES;
    for i in (0..groups).step_by(LANES) {
        // SAFETY: i + LANES ≤ len, so the lanes read from a + i and a + i + step lie below
        // a + step + len in every field, and those from i in `inv_len` below len; the lanes
        // written from c·r + at + i lie below c·r + at + len ≤ K·r, in `out` (all asserted
        // above).
        let lane = |f: usize, at: usize| unsafe { *fields[f].get_unchecked(at) };
        let inv: [f64; LANES] = unsafe { *inv_len.as_ptr().add(i).cast() };
        let mut z = [[0.0; LANES]; K];
        for l in 0..LANES {
            let (p, q) = (a + i + l, a + i + l + step);
            let d = DVec3::new(lane(0, p), lane(1, p), lane(2, p))
                - DVec3::new(lane(0, q), lane(1, q), lane(2, q));
            let w = DVec3::new(lane(3, p), lane(4, p), lane(5, p))
                - DVec3::new(lane(3, q), lane(4, q), lane(5, q));
            let t = term.spring(d, w, inv[l], s);
            for c in 0..K {
                z[c][l] = t[c];
            }
        }
        for (c, z) in z.into_iter().enumerate() {
            // SAFETY: as above.
            unsafe {
                out.as_mut_ptr()
                    .add(c * r + at + i)
                    .cast::<[f64; LANES]>()
                    .write(z)
            };
        }
    }
    for i in groups..len {
        let (p, q) = (a + i, a + i + step);
        let point = |v: [&[f64]; 3], p: usize| DVec3::new(v[0][p], v[1][p], v[2][p]);
        let (d, w) = (point(x, p) - point(x, q), point(y, p) - point(y, q));
        let z = term.spring(d, w, inv_len[i], s);
        for (c, z) in z.into_iter().enumerate() {
            out[c * r + at + i] = z;
        }
    }
}

/// sum ± z, element by element (+ if `PLUS`).
#[inline(always)]
fn add<const PLUS: bool>(sum: &mut [f64], z: &[f64]) {
    for (sum, z) in sum.iter_mut().zip(z) {
        if PLUS {
            *sum += z;
        } else {
            *sum -= z;
        }
    }
}

/// z_s = B_s w for a spring at d = x_a − x_b with 1/ℓ `inv_len` and w = p_a − p_b: with
/// u = d/ℓ, β(u·w)u + γ w = β (d·w)/ℓ² d + γ w ([`block`]'s β, γ; z = 0 where 1/ℓ = 0).
#[inline(always)]
fn product(d: DVec3, w: DVec3, inv_len: f64, s: &Offset) -> DVec3 {
    let (hkd, h2ks) = s.coefficients;
    let alpha = transverse(inv_len, s.rest);
    let (beta, gamma) = (hkd + h2ks * (1.0 - alpha), h2ks * alpha);
    (beta * inv_len * inv_len * d.dot(w)) * d + gamma * w
}

/// The sums of a run of springs of one offset, from first ends `a` to second ends `step`
/// further (model indices of the run's first spring), added at the first ends if `FIRST`, else
/// at the second: [`starts`]' terms, [`CHUNK`] at a time through `scratch` (K·[`CHUNK`]).
#[inline(always)]
fn run_terms<T: Term<K>, const K: usize, const FIRST: bool>(
    term: &T,
    mut sums: [&mut [f64]; K],
    fields: Fields<'_>,
    (a, step): (usize, usize),
    inv_len: &[f64],
    s: &Offset,
    scratch: &mut [f64],
) {
    let n = sums[0].len();
    for t in (0..n).step_by(CHUNK) {
        let len = CHUNK.min(n - t);
        starts(
            term,
            fields,
            (a + t, step),
            &inv_len[t..t + len],
            s,
            (scratch, 0, CHUNK),
        );
        for (c, sum) in sums.iter_mut().enumerate() {
            let (sum, z) = (&mut sum[t..t + len], &scratch[c * CHUNK..c * CHUNK + len]);
            if FIRST || c >= T::ODD {
                add::<true>(sum, z);
            } else {
                add::<false>(sum, z);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use softbody_scene::{Integrator, Model, Scene, SpringParams, State};
    use softbody_testkit::Rng;
    use softbody_testkit::scenes::*;

    use super::LatticeSystem;
    use crate::spring_forces::Isa;

    /// Two cuboids of `dims` points side by side (springs stretched and compressed: positions
    /// moved by up to 3 cm, velocities random), a diagonal's mass part and a vector p.
    fn two_cuboids(dims: [u32; 3], seed: u64) -> (Model, State, Vec<f64>, Vec<DVec3>) {
        let params = SpringParams {
            stiffness: 400.0,
            damping: 0.8,
        };
        let body = |name: &str, at: f64| {
            let mut body = cuboid_body(cuboid(
                DVec3::splat(0.4),
                dims,
                DVec3::new(at, 1.0, 0.0),
                2.0,
                params,
            ));
            body.name = name.into();
            body
        };
        let sim = simulation(Integrator::ImplicitEuler, 0.01);
        let bodies = vec![body("a", 0.0), body("b", 1.0)];
        let (model, mut state) = Model::build(&scene(sim, bodies, vec![]));
        perturbed(model, &mut state, seed)
    }

    /// `model` with `state` perturbed (positions moved by up to 3 cm, velocities random), a
    /// diagonal's mass part and a vector p.
    fn perturbed(
        model: Model,
        state: &mut State,
        seed: u64,
    ) -> (Model, State, Vec<f64>, Vec<DVec3>) {
        let mut rng = Rng::new(seed);
        let mass_diag: Vec<f64> = (0..model.len()).map(|_| 0.05 + rng.unit()).collect();
        state.x.iter_mut().for_each(|x| *x += rng.vec(0.03));
        state.v.iter_mut().for_each(|v| *v = rng.vec(1.0));
        let p: Vec<DVec3> = (0..model.len()).map(|_| rng.vec(1.0)).collect();
        (model, state.clone(), mass_diag, p)
    }

    /// Mesh bodies' masked lattices, perturbed as [`perturbed`]: a torus (a hole: rows of two
    /// runs, points without particles), and a torus, a star and a cuboid in one model.
    fn meshes(seed: u64) -> Vec<(Model, State, Vec<f64>, Vec<DVec3>)> {
        let mesh = |file: &str, cell: f64, x: f64| {
            format!(
                "[[body]]\nkind = \"mesh\"\nfile = \"{file}\"\ncell = {cell}\n\
                 center = [{x}, 1.0, 0.0]\nrotation = [30.0, 20.0, 10.0]\nmass = 3.0\n\
                 structural = {{ stiffness = 2000.0, damping = 5.0 }}\n\
                 shear = {{ stiffness = 1500.0, damping = 4.0 }}\n\
                 bending = {{ stiffness = 700.0, damping = 3.0 }}\n"
            )
        };
        let cuboid = "[[body]]\nkind = \"cuboid\"\ncenter = [3.0, 1.0, 0.0]\n\
                      size = [0.5, 0.4, 0.3]\nresolution = [5, 4, 3]\nmass = 2.0\n\
                      structural = { stiffness = 900.0, damping = 2.0 }\n";
        let sim = "[simulation]\nintegrator = \"implicit-euler\"\ndt = 0.01\nduration = 0.1\n";
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/test.toml");
        [
            mesh("torus.obj", 0.04, 0.0),
            mesh("torus.obj", 0.05, 0.0) + &mesh("star.obj", 0.06, 1.5) + cuboid,
        ]
        .iter()
        .map(|bodies| {
            let text = format!("{sim}{bodies}");
            let scene = Scene::from_toml(&text, path.as_ref()).expect("a valid scene");
            let (model, mut state) = Model::build(&scene);
            assert!(model.lattices().iter().any(|l| l.mask.is_some()));
            perturbed(model, &mut state, seed)
        })
        .collect()
    }

    /// Every vector path of the product gives the scalar path's bits: cuboids with inner planes
    /// (swept in slabs, with a remainder of fewer than eight particles) and cuboids too thin
    /// for them, two bodies side by side; mesh bodies.
    #[test]
    fn every_isa_gives_the_scalar_bits() {
        let cuboids = [[9, 7, 8], [12, 5, 6], [3, 2, 11], [17, 6, 5]].map(|d| two_cuboids(d, 3));
        for (model, state, mass_diag, p) in cuboids.into_iter().chain(meshes(3)) {
            let dims: Vec<_> = model.lattices().iter().map(|l| l.dims).collect();
            let product = |isa: Isa| {
                let mut lattice = LatticeSystem::new(&model).expect("lattices");
                lattice.isa = isa;
                lattice.linearise(&state.x);
                let mut out = vec![DVec3::NAN; model.len()];
                lattice.set_operand(&p);
                lattice.product(&mass_diag, &mut out);
                out.iter()
                    .flat_map(|v| v.to_array())
                    .map(f64::to_bits)
                    .collect::<Vec<_>>()
            };
            let scalar = product(Isa::Scalar);
            for isa in [Isa::Avx2, Isa::Avx512]
                .into_iter()
                .filter(|isa| isa.runs())
            {
                assert!(product(isa) == scalar, "{dims:?}: {isa:?} differs");
            }
        }
    }

    /// CG's search direction formed in the product's pass (`set_direction`) is p + βc, and
    /// its product the bits of that vector's product through `set_operand`.
    #[test]
    fn the_direction_formed_in_the_product_is_p_plus_beta_c() {
        let bits = |v: &[DVec3]| -> Vec<u64> {
            v.iter()
                .flat_map(|v| v.to_array())
                .map(f64::to_bits)
                .collect()
        };
        for (model, state, mass_diag, p) in [two_cuboids([9, 7, 8], 5)].into_iter().chain(meshes(5))
        {
            let c0: Vec<DVec3> = p.iter().map(|p| DVec3::new(p.z, -p.x, 0.5 * p.y)).collect();
            let beta = 0.37;
            let mut lattice = LatticeSystem::new(&model).expect("lattices");
            lattice.linearise(&state.x);
            let mut c = c0.clone();
            let mut fused = vec![DVec3::NAN; model.len()];
            lattice.set_direction(&p, beta, &mut c);
            lattice.product(&mass_diag, &mut fused);
            let expected: Vec<DVec3> = (p.iter().zip(&c0)).map(|(p, c)| *p + beta * *c).collect();
            let mut apart = vec![DVec3::NAN; model.len()];
            lattice.set_operand(&expected);
            lattice.product(&mass_diag, &mut apart);
            assert_eq!(bits(&c), bits(&expected));
            assert_eq!(bits(&fused), bits(&apart));
        }
    }

    /// The inner planes' slabs, each spring's term computed once and handed from its first end
    /// to its second through the rings, give the bits of every plane computing both ends, for
    /// the product and the assembly, on 1–4 threads (other slabs, other ring starts): cuboids
    /// with and without inner planes, a remainder after the last group, two bodies; mesh
    /// bodies.
    #[test]
    fn slabs_give_the_bits_of_both_ends_computed() {
        let cuboids = [[9, 7, 13], [4, 3, 9], [3, 2, 5], [17, 6, 8], [20, 9, 10]];
        let cuboids = cuboids.map(|d| two_cuboids(d, 11));
        for (model, state, mass_diag, p) in cuboids.into_iter().chain(meshes(11)) {
            let dims: Vec<_> = model.lattices().iter().map(|l| l.dims).collect();
            let run = |slabs: bool, threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| {
                    let mut lattice = LatticeSystem::new(&model).expect("lattices");
                    lattice.slabs = slabs;
                    lattice.linearise(&state.x);
                    let mut out = vec![DVec3::NAN; model.len()];
                    lattice.set_operand(&p);
                    lattice.product(&mass_diag, &mut out);
                    lattice.assemble(&state.v, 0.01);
                    let sums = (0..model.len())
                        .map(|i| lattice.sums(i))
                        .flat_map(|s| s.force.to_array().into_iter().chain(s.block));
                    (out.iter().flat_map(|v| v.to_array()).chain(sums))
                        .map(f64::to_bits)
                        .collect::<Vec<_>>()
                })
            };
            let reference = run(false, 1);
            for threads in 1..=4 {
                assert!(
                    run(true, threads) == reference,
                    "{dims:?}, {threads} threads"
                );
            }
        }
    }
}
