//! The system's product on models of cuboids, particle by particle, without a spring list:
//!
//! (A p)_i = m_i(1 + h·drag) p_i + Σ_{springs (i, b)} z_s − Σ_{springs (a, i)} z_s,
//! z_s = B_s (p_a − p_b), B_s = β uuᵀ + γ I,
//!
//! the matrix of [`super::system`], each spring's block recomputed from the positions and the
//! spring's 1/ℓ, the one value per spring stored at the step's start (`block` here is the one
//! definition of u, β, γ, which the assembly uses too).
//!
//! Why: the per-spring product writes z_s for every spring and gathers it back through the
//! adjacency, and reads u, β, γ and both ends' indices: about 150 B per spring and product,
//! so the 46³ cube's 1.5 M springs stream ~220 MB through memory for each of its ~95
//! products a step. Here a product reads the positions and p (one array per axis), and 1/ℓ:
//! about 200 B per particle, and each block costs a few multiply-adds at each of its two ends;
//! the square root and the division were paid once, in [`LatticeProduct::linearise`].
//! 46³: 0.83 → 0.38 s a step (BENCHMARKS.md).
//!
//! Both ends of a spring compute z_s in the same operations from the same inputs
//! (d = x_a − x_b, 1/ℓ, p_a − p_b), so their terms are exact negatives and the matrix is
//! exactly symmetric, as CG needs. A particle's sum runs in a fixed order (the mass term, then
//! the body's offsets in [`OFFSETS`] order, each as first end then as second end), so the bits
//! do not depend on the thread count; they differ from the per-spring product's in rounding
//! only.

use std::ops::Range;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;
use softbody_scene::topology::OFFSETS;

use crate::forces::PARTICLE_CHUNK;
use crate::integrators::prefetch;
use crate::pipeline::all_cuboids;
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
    /// end within the body; 0 where the offset's partner lies outside the lattice (never
    /// written: the products' loops read these entries and must get z = 0 from them).
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
    /// The positions of the linearisation, by axis.
    x: Axes,
    /// The vector of the product under way, by axis.
    p: Axes,
    /// The product's sums, by axis.
    sums: Axes,
    isa: Isa,
}

/// One array per axis (structure of arrays: the product's loops load whole vectors of
/// consecutive particles instead of shuffling x, y, z out of `DVec3`s).
type Axes = [Vec<f64>; 3];

impl LatticeProduct {
    /// For `model` when every body is a full lattice (a cuboid); `None` otherwise.
    pub fn new(model: &Model) -> Option<LatticeProduct> {
        if !all_cuboids(model) {
            return None;
        }
        let h = model.simulation.dt;
        let bodies = (model.lattices().iter())
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
            x: axes(model.len()),
            p: axes(model.len()),
            sums: axes(model.len()),
            isa: Isa::detect(),
        })
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        [&self.x, &self.p, &self.sums]
            .iter()
            .flat_map(|a| a.iter())
            .map(crate::vec_bytes)
            .sum::<u64>()
            + self
                .bodies
                .iter()
                .map(|b| crate::vec_bytes(&b.inv_len))
                .sum::<u64>()
    }

    /// Linearises at the positions `x`: keeps them and each spring's 1/ℓ.
    pub fn linearise(&mut self, x: &[DVec3]) {
        split(x, &mut self.x);
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
    pub fn apply(&mut self, mass_diag: &[f64], p: &[DVec3], out: &mut [DVec3]) {
        split(p, &mut self.p);
        let [x, p] = [&self.x, &self.p].map(|a| [&a[0][..], &a[1][..], &a[2][..]]);
        let [sx, sy, sz] = &mut self.sums;
        let isa = self.isa;
        for body in &self.bodies {
            let [nx, ny, _] = body.dims;
            let (range, plane) = (body.first..body.first + body.len(), nx * ny);
            (sx[range.clone()].par_chunks_mut(plane))
                .zip(sy[range.clone()].par_chunks_mut(plane))
                .zip(sz[range.clone()].par_chunks_mut(plane))
                .zip(out[range].par_chunks_mut(plane))
                .enumerate()
                .for_each(|(k, (((sx, sy), sz), out))| {
                    let sums = [sx, sy, sz];
                    plane_of(isa, body, (mass_diag, x, p), k, sums, out)
                });
        }
    }
}

/// The diagonal's mass part, and the positions x and the vector p by axis.
type Inputs<'a> = (&'a [f64], [&'a [f64]; 3], [&'a [f64]; 3]);

/// An array per axis from `DVec3`s.
fn split(v: &[DVec3], out: &mut Axes) {
    let [x, y, z] = out;
    (x, y, z, v)
        .into_par_iter()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(x, y, z, v)| (*x, *y, *z) = (v.x, v.y, v.z));
}

fn axes(n: usize) -> Axes {
    std::array::from_fn(|_| vec![0.0; n])
}

/// One plane's products, compiled for the widest vectors the CPU runs.
fn plane_of(
    isa: Isa,
    body: &Body,
    inputs: Inputs<'_>,
    k: usize,
    sums: [&mut [f64]; 3],
    out: &mut [DVec3],
) {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the CPU has AVX-512F (`Isa::detect`).
        Isa::Avx512 => return unsafe { plane_avx512(body, inputs, k, sums, out) },
        // SAFETY: the CPU has AVX2 (as above).
        Isa::Avx2 => return unsafe { plane_avx2(body, inputs, k, sums, out) },
        Isa::Scalar => {}
    }
    plane_terms(body, inputs, k, sums, out);
}

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
unsafe fn plane_avx512(
    body: &Body,
    inputs: Inputs<'_>,
    k: usize,
    sums: [&mut [f64]; 3],
    out: &mut [DVec3],
) {
    plane_terms(body, inputs, k, sums, out);
}

/// [`plane_terms`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn plane_avx2(
    body: &Body,
    inputs: Inputs<'_>,
    k: usize,
    sums: [&mut [f64]; 3],
    out: &mut [DVec3],
) {
    plane_terms(body, inputs, k, sums, out);
}

/// Plane k of the product into `out` (the plane's), summed in `sums` (the plane's): per
/// particle the mass term, then per offset the spring it starts, then the one it ends.
///
/// Where every offset's partners of the whole plane lie in the body (all but the planes
/// nearest the body's faces), the plane runs in groups of [`LANES`] consecutive particles that
/// keep their own positions, p and sums in registers through all offsets ([`fused_terms`]).
/// Elsewhere each offset runs over the plane in its own loop, its run cut where partners leave
/// the body. Both give each particle the same terms in the same order, so the same bits.
///
/// Either way a loop pairs particles at a constant index step, so near the lattice's edges in
/// i or j it pairs a particle with one of another row: there the particle has no spring of the
/// offset, its stored 1/ℓ is 0, which makes z = 0 ([`product`]).
#[inline(always)]
fn plane_terms(
    body: &Body,
    (mass_diag, x, p): Inputs<'_>,
    k: usize,
    mut sums: [&mut [f64]; 3],
    out: &mut [DVec3],
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
    let whole = body.offsets.iter().all(|s| runs(s) == [Some((q0, q1)); 2]);
    if whole {
        let plane = (q1 - q0) as usize;
        let g = first + q0 as usize;
        let groups = plane / LANES * LANES;
        for t in (0..groups).step_by(LANES) {
            let sums = fused_terms::<LANES>(body, (mass_diag, x, p), g + t, q0 as usize + t);
            for (l, o) in out[t..t + LANES].iter_mut().enumerate() {
                *o = DVec3::new(sums[0][l], sums[1][l], sums[2][l]);
            }
        }
        for (t, o) in out.iter_mut().enumerate().skip(groups) {
            let sums = fused_terms::<1>(body, (mass_diag, x, p), g + t, q0 as usize + t);
            *o = DVec3::new(sums[0][0], sums[1][0], sums[2][0]);
        }
        return;
    }
    let plane = first + q0 as usize..first + q1 as usize;
    for (sum, p) in sums.iter_mut().zip(p) {
        let (sum, p, m) = (&mut sum[..], &p[plane.clone()], &mass_diag[plane.clone()]);
        for t in 0..sum.len() {
            sum[t] = m[t] * p[t];
        }
    }
    for (o, s) in body.offsets.iter().enumerate() {
        for (side, run) in runs(s).into_iter().enumerate() {
            let Some((t0, t1)) = run else { continue };
            let step = if side == 0 { s.step } else { -s.step };
            let run = (t0 - q0) as usize..(t1 - q0) as usize;
            let (t, u) = (first + t0 as usize, (first as isize + t0 + step) as usize);
            let [sx, sy, sz] = &mut sums;
            let sums = [&mut sx[run.clone()], &mut sy[run.clone()], &mut sz[run]];
            let (x0, x1) = (x.map(|a| &a[t..]), x.map(|a| &a[u..]));
            let (p0, p1) = (p.map(|a| &a[t..]), p.map(|a| &a[u..]));
            if side == 0 {
                terms::<true>(sums, (x0, x1), (p0, p1), &inv(o)[t0 as usize..], s);
            } else {
                terms::<false>(sums, (x1, x0), (p1, p0), &inv(o)[(t0 + step) as usize..], s);
            }
        }
    }
    for (t, o) in out.iter_mut().enumerate() {
        *o = DVec3::new(sums[0][t], sums[1][t], sums[2][t]);
    }
}

/// Particles per group of [`fused_terms`]: one 512-bit vector of f64.
const LANES: usize = 8;

/// How far ahead [`fused_terms`] prefetches, in particles.
const AHEAD: usize = 8 * LANES;

/// The sums of the `L` particles from `g` (model index; `q` within the body), every offset's
/// partners in the body: the mass term, then per offset the spring each starts and the one it
/// ends — [`plane_terms`]'s per-offset loops' terms, in their order.
#[inline(always)]
fn fused_terms<const L: usize>(
    body: &Body,
    (mass_diag, x, p): Inputs<'_>,
    g: usize,
    q: usize,
) -> [[f64; L]; 3] {
    let lanes = |a: &[f64], at: usize| -> [f64; L] { a[at..at + L].try_into().unwrap() };
    let (xo, po) = (x.map(|a| lanes(a, g)), p.map(|a| lanes(a, g)));
    let m = lanes(mass_diag, g);
    let mut sums: [[f64; L]; 3] = std::array::from_fn(|c| std::array::from_fn(|l| m[l] * po[c][l]));
    let n = body.len();
    for (s, inv) in body.offsets.iter().zip(body.inv_len.chunks_exact(n)) {
        let (b, a) = (
            g.wrapping_add_signed(s.step),
            g.wrapping_add_signed(-s.step),
        );
        let (xb, pb, inv_b) = (
            x.map(|v| lanes(v, b)),
            p.map(|v| lanes(v, b)),
            lanes(inv, q),
        );
        let (xa, pa) = (x.map(|v| lanes(v, a)), p.map(|v| lanes(v, a)));
        let inv_a = lanes(inv, q.wrapping_add_signed(-s.step));
        // 1/ℓ of the springs the particles start stream from memory on large bodies (their
        // second ends' were read one or two planes before), and a group's sixteen streams
        // are more than the hardware prefetchers follow.
        prefetch(inv.get(q + AHEAD..q + AHEAD + 1));
        for l in 0..L {
            let at = |v: &[[f64; L]; 3]| DVec3::new(v[0][l], v[1][l], v[2][l]);
            let z = product(at(&xo) - at(&xb), at(&po) - at(&pb), inv_b[l], s);
            for c in 0..3 {
                sums[c][l] += z[c];
            }
            let z = product(at(&xa) - at(&xo), at(&pa) - at(&po), inv_a[l], s);
            for c in 0..3 {
                sums[c][l] -= z[c];
            }
        }
    }
    sums
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

/// sums ± z_s for a run of springs of one offset (+ at first ends).
#[inline(always)]
fn terms<const FIRST: bool>(
    sums: [&mut [f64]; 3],
    (xa, xb): ([&[f64]; 3], [&[f64]; 3]),
    (pa, pb): ([&[f64]; 3], [&[f64]; 3]),
    inv_len: &[f64],
    s: &Offset,
) {
    let n = sums[0].len();
    let [sx, sy, sz] = sums.map(|a| &mut a[..n]);
    let [xa, xb, pa, pb] = [xa, xb, pa, pb].map(|v| v.map(|a| &a[..n]));
    let inv_len = &inv_len[..n];
    for t in 0..n {
        let d = DVec3::new(
            xa[0][t] - xb[0][t],
            xa[1][t] - xb[1][t],
            xa[2][t] - xb[2][t],
        );
        let w = DVec3::new(
            pa[0][t] - pb[0][t],
            pa[1][t] - pb[1][t],
            pa[2][t] - pb[2][t],
        );
        let z = product(d, w, inv_len[t], s);
        if FIRST {
            (sx[t], sy[t], sz[t]) = (sx[t] + z.x, sy[t] + z.y, sz[t] + z.z);
        } else {
            (sx[t], sy[t], sz[t]) = (sx[t] - z.x, sy[t] - z.y, sz[t] - z.z);
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use softbody_scene::{Integrator, Model, SpringParams};
    use softbody_testkit::Rng;
    use softbody_testkit::scenes::*;

    use super::LatticeProduct;
    use crate::spring_forces::Isa;

    /// Every vector path of the product gives the scalar path's bits: cuboids whose planes take
    /// the grouped loop (with a remainder of fewer than eight particles) and cuboids too thin
    /// for it, two bodies side by side, springs stretched and compressed.
    #[test]
    fn every_isa_gives_the_scalar_bits() {
        let params = SpringParams {
            stiffness: 400.0,
            damping: 0.8,
        };
        for dims in [[9, 7, 8], [12, 5, 6], [3, 2, 11], [17, 6, 5]] {
            let cube = |name: &str, at: f64| {
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
            let (model, mut state) =
                Model::build(&scene(sim, vec![cube("a", 0.0), cube("b", 1.0)], vec![]));
            let mut rng = Rng::new(3);
            let mass_diag: Vec<f64> = (0..model.len()).map(|_| 0.05 + rng.unit()).collect();
            state.x.iter_mut().for_each(|x| *x += rng.vec(0.03));
            let p: Vec<DVec3> = (0..model.len()).map(|_| rng.vec(1.0)).collect();
            let product = |isa: Isa| {
                let mut lattice = LatticeProduct::new(&model).expect("cuboids");
                lattice.isa = isa;
                lattice.linearise(&state.x);
                let mut out = vec![DVec3::NAN; model.len()];
                lattice.apply(&mass_diag, &p, &mut out);
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
}
