//! The system's product on models of cuboids, particle by particle, without a spring list:
//!
//! (A p)_i = m_i(1 + h·drag) p_i + Σ_{springs (i, b)} z_s − Σ_{springs (a, i)} z_s,
//! z_s = B_s (p_a − p_b), B_s = β uuᵀ + γ I,
//!
//! the matrix of [`super::system`], each spring's block recomputed by [`block`] from the
//! positions and the spring's 1/ℓ (the one value per spring stored at the step's start).
//!
//! Why: the per-spring product writes z_s for every spring and gathers it back through the
//! adjacency, and reads u, β, γ and both ends' indices: about 200 B per spring and product, so
//! the 46³ cube's 1.5 M springs stream some 300 MB through memory for each of its ~100
//! products a step. Here a product reads the positions, p and one f64 per spring (1/ℓ), about
//! 180 B per particle, and each block is computed twice (once per end) in a few
//! multiply-adds — the square root and division were paid once, in [`LatticeProduct::linearise`].
//!
//! Both ends of a spring compute z_s in the same operations from the same inputs
//! (d = x_a − x_b, 1/ℓ, p_a − p_b), so their terms are exact negatives and the matrix is
//! exactly symmetric, as CG needs. A particle's sum runs in a fixed order (the body's offsets
//! in [`OFFSETS`] order, each as first end then as second end), so the bits do not depend on
//! the thread count; they differ from the per-spring product's in rounding only.

use std::ops::Range;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;
use softbody_scene::topology::OFFSETS;

use crate::spring_forces::Isa;

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
    if inv_len > 0.0 {
        (1.0 - rest * inv_len).max(0.0)
    } else {
        0.0
    }
}

/// The springs of one lattice offset.
#[derive(Debug, Clone, Copy)]
struct Offset {
    /// (di, dj, dk).
    delta: [isize; 3],
    /// The partner's index minus the particle's.
    step: isize,
    rest: f64,
    /// (h k_d, h² k_s).
    coefficients: (f64, f64),
}

/// One cuboid body.
#[derive(Debug)]
struct Body {
    first: usize,
    dims: [usize; 3],
    offsets: Vec<Offset>,
    /// 1/ℓ of each spring at the step's start, offset after offset, each indexed by its first
    /// end within the body (entries whose partner lies outside the lattice are unused).
    inv_len: Vec<f64>,
}

impl Body {
    fn len(&self) -> usize {
        self.dims.iter().product()
    }
}

/// The lattice product's data: per body its lattice and per spring 1/ℓ.
#[derive(Debug)]
pub struct LatticeProduct {
    bodies: Vec<Body>,
    /// The positions of the linearisation.
    x: Vec<DVec3>,
    isa: Isa,
}

impl LatticeProduct {
    /// For `model` when every body is a full lattice (a cuboid); `None` otherwise.
    pub fn new(model: &Model) -> Option<LatticeProduct> {
        let lattices = model.lattices();
        let cuboids = !lattices.is_empty()
            && lattices.len() == model.bodies.len()
            && lattices.iter().all(|l| l.mask.is_none());
        if !cuboids {
            return None;
        }
        let h = model.simulation.dt;
        let bodies = lattices
            .iter()
            .map(|l| {
                let dims = l.dims.map(|d| d as usize);
                let offsets: Vec<Offset> = (l.springs.iter())
                    .map(|s| {
                        let delta = OFFSETS[s.offset].0.map(|d| d as isize);
                        let [nx, ny, _] = dims.map(|d| d as isize);
                        Offset {
                            delta,
                            step: delta[0] + nx * (delta[1] + ny * delta[2]),
                            rest: s.rest,
                            coefficients: (h * s.damping, h * h * s.stiffness),
                        }
                    })
                    .collect();
                let n: usize = dims.iter().product();
                Body {
                    first: l.first as usize,
                    dims,
                    inv_len: vec![0.0; offsets.len() * n],
                    offsets,
                }
            })
            .collect();
        Some(LatticeProduct {
            bodies,
            x: vec![DVec3::ZERO; model.len()],
            isa: Isa::detect(),
        })
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        crate::vec_bytes(&self.x)
            + self
                .bodies
                .iter()
                .map(|b| crate::vec_bytes(&b.inv_len))
                .sum::<u64>()
    }

    /// Linearises at the positions `x`: keeps them and each spring's 1/ℓ.
    pub fn linearise(&mut self, x: &[DVec3]) {
        self.x.clear();
        self.x.extend_from_slice(x);
        for body in &mut self.bodies {
            let [nx, ny, nz] = body.dims;
            let (first, offsets) = (body.first, &body.offsets);
            body.inv_len
                .par_chunks_mut(nx * ny)
                .enumerate()
                .for_each(|(plane, inv)| {
                    let (s, k) = (offsets[plane / nz], plane % nz);
                    for (j, row) in inv.chunks_mut(nx).enumerate() {
                        if let Some(r) = first_ends(s.delta, body.dims, j, k) {
                            let a = first + nx * (j + ny * k);
                            let b = a.wrapping_add_signed(s.step);
                            for i in r {
                                row[i] = inverse_length(x[a + i] - x[b + i]);
                            }
                        }
                    }
                });
        }
    }

    /// out = M(1 + h·drag) p + the springs' terms, with `mass_diag` the diagonal's mass part.
    pub fn apply(&self, mass_diag: &[f64], p: &[DVec3], out: &mut [DVec3]) {
        let x = &self.x[..];
        for body in &self.bodies {
            let [nx, ny, _] = body.dims;
            out[body.first..body.first + body.len()]
                .par_chunks_mut(nx * ny)
                .enumerate()
                .for_each(|(k, plane)| self.plane(body, (mass_diag, x, p), k, plane));
        }
    }

    /// One plane's products, compiled for the widest vectors the CPU runs.
    fn plane(&self, body: &Body, inputs: Inputs<'_>, k: usize, out: &mut [DVec3]) {
        #[cfg(target_arch = "x86_64")]
        match self.isa {
            // SAFETY: the CPU has AVX-512F (`Isa::detect`).
            Isa::Avx512 => return unsafe { plane_avx512(body, inputs, k, out) },
            // SAFETY: the CPU has AVX2 (as above).
            Isa::Avx2 => return unsafe { plane_avx2(body, inputs, k, out) },
            Isa::Scalar => {}
        }
        plane_terms(body, inputs, k, out);
    }
}

/// The diagonal's mass part, the positions x and the vector p.
type Inputs<'a> = (&'a [f64], &'a [DVec3], &'a [DVec3]);

/// The i of row (j, k) whose spring of offset `delta` has its partner in the lattice.
fn first_ends(delta: [isize; 3], dims: [usize; 3], j: usize, k: usize) -> Option<Range<usize>> {
    let [di, dj, dk] = delta;
    let [nx, ny, nz] = dims.map(|d| d as isize);
    let (j, k) = (j as isize + dj, k as isize + dk);
    ((0..ny).contains(&j) && (0..nz).contains(&k))
        .then(|| (-di).max(0) as usize..(nx - di.max(0)) as usize)
}

/// [`plane_terms`] compiled for AVX-512.
///
/// # Safety
/// The CPU has AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn plane_avx512(body: &Body, inputs: Inputs<'_>, k: usize, out: &mut [DVec3]) {
    plane_terms(body, inputs, k, out);
}

/// [`plane_terms`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_avx2(body: &Body, inputs: Inputs<'_>, k: usize, out: &mut [DVec3]) {
    plane_terms(body, inputs, k, out);
}

/// Plane k of the product into `out` (the plane's): the mass term, then per offset the springs
/// the plane's particles start, then those they end.
///
/// Each offset runs over the whole plane in one loop, long enough to vectorise without
/// remainders mattering: where a particle has no spring of the offset (its partner would lie
/// beyond the lattice's edge in i or j, so the loop pairs it with a particle of another row),
/// its stored 1/ℓ is 0, and [`block`] gives u = 0 and γ = 0, so z = 0 and the term adds
/// nothing. Only partners outside the body are cut off, by the run's ends.
#[inline(always)]
fn plane_terms(body: &Body, (mass_diag, x, p): Inputs<'_>, k: usize, out: &mut [DVec3]) {
    let [nx, ny, nz] = body.dims.map(|d| d as isize);
    let (first, n) = (body.first, body.len() as isize);
    let q0 = (nx * ny) * k as isize;
    let q1 = q0 + nx * ny;
    let plane = first + q0 as usize..first + q1 as usize;
    for ((o, m), p) in out.iter_mut().zip(&mass_diag[plane.clone()]).zip(&p[plane]) {
        *o = *m * *p;
    }
    let k = k as isize;
    for (s, inv) in body
        .offsets
        .iter()
        .zip(body.inv_len.chunks_exact(n as usize))
    {
        let dk = s.delta[2];
        // The particles t of the plane whose partner t + step (first ends) or t − step
        // (second ends) lies in the body.
        for (sign, present) in [
            (1, (0..nz).contains(&(k + dk))),
            (-1, (0..nz).contains(&(k - dk))),
        ] {
            if !present {
                continue;
            }
            let step = sign * s.step;
            let (t0, t1) = (q0.max(-step), q1.min(n - step));
            let run = (t0 - q0) as usize..(t1 - q0) as usize;
            let (t, u) = (first + t0 as usize, (first as isize + t0 + step) as usize);
            if sign > 0 {
                let inv = &inv[t0 as usize..];
                terms::<true>(
                    &mut out[run],
                    (&x[t..], &x[u..]),
                    (&p[t..], &p[u..]),
                    inv,
                    s,
                );
            } else {
                let inv = &inv[(t0 + step) as usize..];
                terms::<false>(
                    &mut out[run],
                    (&x[u..], &x[t..]),
                    (&p[u..], &p[t..]),
                    inv,
                    s,
                );
            }
        }
    }
}

/// out ± z_s for a run of springs of one offset (+ at first ends): z_s = B_s (p_a − p_b).
#[inline(always)]
fn terms<const FIRST: bool>(
    out: &mut [DVec3],
    (xa, xb): (&[DVec3], &[DVec3]),
    (pa, pb): (&[DVec3], &[DVec3]),
    inv_len: &[f64],
    s: &Offset,
) {
    let n = out.len();
    let (xa, xb, pa, pb, inv_len) = (&xa[..n], &xb[..n], &pa[..n], &pb[..n], &inv_len[..n]);
    for t in 0..n {
        let (u, beta, gamma) = block(xa[t] - xb[t], inv_len[t], s.rest, s.coefficients);
        let w = pa[t] - pb[t];
        let z = beta * u.dot(w) * u + gamma * w;
        if FIRST {
            out[t] += z;
        } else {
            out[t] -= z;
        }
    }
}
