//! The spring pass in 256-bit vectors: four springs per group, each lane doing exactly the
//! scalar [`spring_force`]'s IEEE operations in its order (`vdivpd`, `vsqrtpd` are correctly
//! rounded like their scalar forms; nothing is fused).

use std::arch::x86_64::*;

use glam::DVec3;
use softbody_scene::Springs;

use super::{Cursor, LANES, Sum, spring_force};

/// Loads x, y, z of `p` into lanes 0..3 (lane 3 = 0) without reading past it.
#[inline]
#[target_feature(enable = "avx2")]
fn load3(p: &DVec3) -> __m256d {
    // SAFETY: DVec3 is three contiguous f64 (`#[repr(C)]`); the mask reads only those.
    unsafe {
        _mm256_maskload_pd(
            (p as *const DVec3).cast::<f64>(),
            _mm256_setr_epi64x(-1, -1, -1, 0),
        )
    }
}

/// (x, y, z, 0).
#[inline]
#[target_feature(enable = "avx2")]
fn pack(p: DVec3) -> __m256d {
    _mm256_setr_pd(p.x, p.y, p.z, 0.0)
}

/// x, y, z of lanes 0..3.
#[inline]
#[target_feature(enable = "avx2")]
fn unpack(r: __m256d) -> DVec3 {
    let mut out = [0.0; 4];
    // SAFETY: four f64 into a four-element array.
    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), r) };
    DVec3::new(out[0], out[1], out[2])
}

/// Rows (x, y, z, ·) of four vectors → (x0..x3), (y0..y3), (z0..z3).
#[inline]
#[target_feature(enable = "avx2")]
fn transpose_in(r: [__m256d; 4]) -> [__m256d; 3] {
    let t0 = _mm256_unpacklo_pd(r[0], r[1]);
    let t1 = _mm256_unpackhi_pd(r[0], r[1]);
    let t2 = _mm256_unpacklo_pd(r[2], r[3]);
    let t3 = _mm256_unpackhi_pd(r[2], r[3]);
    [
        _mm256_permute2f128_pd::<0x20>(t0, t2),
        _mm256_permute2f128_pd::<0x20>(t1, t3),
        _mm256_permute2f128_pd::<0x31>(t0, t2),
    ]
}

/// A running sum as (x, y, z, ·).
#[inline]
#[target_feature(enable = "avx2")]
fn load(s: &Sum) -> __m256d {
    // SAFETY: a `Sum` is four f64 (`#[repr(C)]`), aligned to 32 bytes.
    unsafe { _mm256_load_pd((s as *const Sum).cast::<f64>()) }
}

/// Writes all four lanes of `r` into `s`.
#[inline]
#[target_feature(enable = "avx2")]
fn store(s: &mut Sum, r: __m256d) {
    // SAFETY: as for `load`; every lane is a field.
    unsafe { _mm256_store_pd((s as *mut Sum).cast::<f64>(), r) }
}

/// Adds the force `row` of a spring to the running sum `sum` of its first end and
/// subtracts it from `*t`, its second end's; returns the new running sum.
///
/// # Safety
/// `t` points to a `Sum` that nothing else accesses meanwhile.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn take(sum: __m256d, row: __m256d, t: *mut Sum) -> __m256d {
    // SAFETY: the caller's promise.
    let t = unsafe { &mut *t };
    store(t, _mm256_sub_pd(load(t), row));
    _mm256_add_pd(sum, row)
}

/// The forces of four springs, one per lane, from their end points' differences d = x_a − x_b
/// (`dx`, `dy`, `dz`) and w = v_a − v_b, rest lengths `r` and parameters: [`spring_force`]'s
/// IEEE operations in its order, u = 1/|d|, s = −(k_s(|d| − r) + k_d((w·d)u))u, f = s·d. Lanes
/// of zero length, and lanes where `live` is zero, exert no force (+0).
#[allow(clippy::too_many_arguments)]
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn forces(
    dx: __m256d,
    dy: __m256d,
    dz: __m256d,
    [wx, wy, wz]: [__m256d; 3],
    r: __m256d,
    ks: __m256d,
    kd: __m256d,
    live: __m256d,
) -> [__m256d; 3] {
    // |d| = sqrt((dx² + dy²) + dz²)
    let n = _mm256_sqrt_pd(_mm256_add_pd(
        _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)),
        _mm256_mul_pd(dz, dz),
    ));
    let u = _mm256_div_pd(_mm256_set1_pd(1.0), n);
    let wd = _mm256_add_pd(
        _mm256_add_pd(_mm256_mul_pd(wx, dx), _mm256_mul_pd(wy, dy)),
        _mm256_mul_pd(wz, dz),
    );
    let s = _mm256_mul_pd(
        _mm256_xor_pd(
            _mm256_add_pd(
                _mm256_mul_pd(ks, _mm256_sub_pd(n, r)),
                _mm256_mul_pd(kd, _mm256_mul_pd(wd, u)),
            ),
            _mm256_set1_pd(-0.0),
        ),
        u,
    );
    let live = _mm256_and_pd(_mm256_cmp_pd::<_CMP_NEQ_UQ>(n, _mm256_setzero_pd()), live);
    [dx, dy, dz].map(|d| _mm256_and_pd(_mm256_mul_pd(s, d), live))
}

/// The springs of one call: their slices from `first`, and their parameters.
struct Span<'a> {
    a: &'a [u32],
    b: &'a [u32],
    rest: &'a [f64],
    ks: &'a [f64],
    kd: &'a [f64],
    uniform: Option<(f64, f64)>,
    /// k_s and k_d in every lane (uniform parameters; zero otherwise).
    ks4: __m256d,
    kd4: __m256d,
    x: &'a [DVec3],
    v: &'a [DVec3],
}

impl<'a> Span<'a> {
    #[target_feature(enable = "avx2")]
    fn new(
        springs: &'a Springs,
        uniform: Option<(f64, f64)>,
        x: &'a [DVec3],
        v: &'a [DVec3],
        first: usize,
        len: usize,
    ) -> Span<'a> {
        let r = first..first + len;
        let (ks, kd) = match uniform {
            Some(_) => (&[][..], &[][..]),
            None => (&springs.stiffness[r.clone()], &springs.damping[r.clone()]),
        };
        let (ks4, kd4) = uniform.unwrap_or_default();
        Span {
            a: &springs.a[r.clone()],
            b: &springs.b[r.clone()],
            rest: &springs.rest[r],
            ks,
            kd,
            uniform,
            ks4: _mm256_set1_pd(ks4),
            kd4: _mm256_set1_pd(kd4),
            x,
            v,
        }
    }

    /// The end points of springs o..o + 4 of the span.
    ///
    /// # Safety
    /// o + 4 ≤ the span's length.
    #[inline]
    unsafe fn ends(&self, o: usize) -> ([usize; LANES], [usize; LANES]) {
        // SAFETY: the caller's promise.
        unsafe {
            (
                std::array::from_fn(|l| *self.a.get_unchecked(o + l) as usize),
                std::array::from_fn(|l| *self.b.get_unchecked(o + l) as usize),
            )
        }
    }

    /// Forces of springs o..o + 4 of the span, from `a[l]` to `b[l]` ([`Span::ends`]), as
    /// rows (x, y, z, z). `UNIFORM`: the parameters are uniform (else read per spring).
    ///
    /// # Safety
    /// o + 4 ≤ the span's length, every end point indexes `x` and `v`, and `UNIFORM` is
    /// whether the span was made with uniform parameters.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn group<const UNIFORM: bool>(
        &self,
        o: usize,
        a: [usize; LANES],
        b: [usize; LANES],
    ) -> [__m256d; 4] {
        let zero = _mm256_setzero_pd();
        let mut dr = [zero; 4];
        let mut wr = [zero; 4];
        for l in 0..LANES {
            // SAFETY: the caller's promises.
            unsafe {
                dr[l] = _mm256_sub_pd(
                    load3(self.x.get_unchecked(a[l])),
                    load3(self.x.get_unchecked(b[l])),
                );
                wr[l] = _mm256_sub_pd(
                    load3(self.v.get_unchecked(a[l])),
                    load3(self.v.get_unchecked(b[l])),
                );
            }
        }
        let [dx, dy, dz] = transpose_in(dr);
        let [wx, wy, wz] = transpose_in(wr);
        // SAFETY: o + 4 ≤ the slices' length.
        let r = unsafe { _mm256_loadu_pd(self.rest.as_ptr().add(o)) };
        let (ks, kd) = if UNIFORM {
            (self.ks4, self.kd4)
        } else {
            // SAFETY: o + 4 ≤ the slices' length (per-spring parameters).
            unsafe {
                (
                    _mm256_loadu_pd(self.ks.as_ptr().add(o)),
                    _mm256_loadu_pd(self.kd.as_ptr().add(o)),
                )
            }
        };
        // Every lane is a spring.
        let every = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
        let [fx, fy, fz] = forces(dx, dy, dz, [wx, wy, wz], r, ks, kd, every);
        // Back to rows (x, y, z, z).
        let t0 = _mm256_unpacklo_pd(fx, fy);
        let t1 = _mm256_unpackhi_pd(fx, fy);
        let t2 = _mm256_unpacklo_pd(fz, fz);
        let t3 = _mm256_unpackhi_pd(fz, fz);
        [
            _mm256_permute2f128_pd::<0x20>(t0, t2),
            _mm256_permute2f128_pd::<0x20>(t1, t3),
            _mm256_permute2f128_pd::<0x31>(t0, t2),
            _mm256_permute2f128_pd::<0x31>(t1, t3),
        ]
    }

    /// The scalar force of spring o of the span.
    #[inline]
    fn one(&self, o: usize) -> DVec3 {
        let (a, b) = (self.a[o] as usize, self.b[o] as usize);
        let (ks, kd) = match self.uniform {
            Some(p) => p,
            None => (self.ks[o], self.kd[o]),
        };
        spring_force(
            self.x[a],
            self.x[b],
            self.v[a],
            self.v[b],
            self.rest[o],
            ks,
            kd,
        )
    }
}

/// # Safety
/// AVX2 is available; springs `first..first + out.len()` exist with their data, and every
/// end point indexes `x` and `v` ([`super::Kernel::check`]).
#[target_feature(enable = "avx2")]
pub(super) unsafe fn range(
    springs: &Springs,
    uniform: Option<(f64, f64)>,
    x: &[DVec3],
    v: &[DVec3],
    first: usize,
    out: &mut [DVec3],
) {
    let span = Span::new(springs, uniform, x, v, first, out.len());
    // SAFETY: the caller's promises; `UNIFORM` is how the span was made.
    unsafe {
        match uniform {
            Some(_) => range_span::<true>(&span, out),
            None => range_span::<false>(&span, out),
        }
    }
}

/// [`range`] over a span, with `UNIFORM` parameters or not.
///
/// # Safety
/// As for [`range`]; `out` has the span's length and `UNIFORM` is how the span was made.
#[target_feature(enable = "avx2")]
unsafe fn range_span<const UNIFORM: bool>(span: &Span, out: &mut [DVec3]) {
    let groups = out.len() / LANES;
    for g in 0..groups {
        let o = g * LANES;
        // SAFETY: o + 4 ≤ len; the caller vouched for the end points and `UNIFORM`.
        let rows = unsafe {
            let (a, b) = span.ends(o);
            span.group::<UNIFORM>(o, a, b)
        };
        let dst = out[o..o + LANES].as_mut_ptr().cast::<f64>();
        // SAFETY: out[o..o + 4] is 12 contiguous f64; rows 0..2 write 4 of them from
        // offsets 0, 3, 6 (each row's fourth lane is overwritten by the next row), the
        // last row 3 from offset 9.
        unsafe {
            _mm256_storeu_pd(dst, rows[0]);
            _mm256_storeu_pd(dst.add(3), rows[1]);
            _mm256_storeu_pd(dst.add(6), rows[2]);
            _mm256_maskstore_pd(dst.add(9), _mm256_setr_epi64x(-1, -1, -1, 0), rows[3]);
        }
    }
    for (o, f) in out.iter_mut().enumerate().skip(groups * LANES) {
        *f = span.one(o);
    }
}

/// # Safety
/// As for [`range`], for springs `first..first + len`; and each of their second ends b
/// lies in `start..start + sums.len()`.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn sweep(
    springs: &Springs,
    uniform: Option<(f64, f64)>,
    x: &[DVec3],
    v: &[DVec3],
    first: usize,
    len: usize,
    sums: &mut [Sum],
    start: usize,
    cursor: Cursor,
    done: &mut impl FnMut(usize, DVec3),
) -> Cursor {
    let span = Span::new(springs, uniform, x, v, first, len);
    // One loop per parameter layout: the uniform one keeps k_s and k_d in registers.
    // SAFETY: the caller's promises; `UNIFORM` is how the span was made.
    unsafe {
        match uniform {
            Some(_) => sweep_span::<true>(&span, sums, start, cursor, done),
            None => sweep_span::<false>(&span, sums, start, cursor, done),
        }
    }
}

/// [`sweep`] over a span, with `UNIFORM` parameters or not.
///
/// # Safety
/// As for [`sweep`]; `UNIFORM` is how the span was made.
#[target_feature(enable = "avx2")]
unsafe fn sweep_span<const UNIFORM: bool>(
    span: &Span,
    sums: &mut [Sum],
    start: usize,
    cursor: Cursor,
    done: &mut impl FnMut(usize, DVec3),
) -> Cursor {
    // The running sum lives in a register as (x, y, z, ·), and every force row is added
    // to it and subtracted from its second end's sum whole (a `Sum` is one vector): lane
    // by lane the same additions as `Cursor::take`, so the same bits, in a fraction of
    // the instructions.
    let Cursor { mut p, sum } = cursor;
    let mut sum = pack(sum);
    // Where particle 0's sum would be: particle b's is at `at + b` (wrapping arithmetic;
    // only sums of the chunk are dereferenced), one subtraction less per spring.
    let at = sums.as_mut_ptr().wrapping_sub(start);
    let len = span.a.len();
    let groups = len / LANES;
    for g in 0..groups {
        let o = g * LANES;
        // SAFETY: o + 4 ≤ len; the caller vouched for the end points and `UNIFORM`.
        let (a, b, rows) = unsafe {
            let (a, b) = span.ends(o);
            (a, b, span.group::<UNIFORM>(o, a, b))
        };
        // The springs come sorted by a, from p on: when the last lane starts at p, so do
        // all four, and no particle completes within the group (the common case).
        if a[LANES - 1] == p {
            for l in 0..LANES {
                // SAFETY: b lies in start..start + sums.len() (the caller's promise), and
                // no reference to `sums` is alive.
                sum = unsafe { take(sum, rows[l], at.wrapping_add(b[l])) };
            }
            continue;
        }
        for l in 0..LANES {
            // Particles before a[l] are complete (`Cursor::advance`).
            while p < a[l] {
                done(p, unpack(sum));
                p += 1;
                if let Some(s) = sums.get(p - start) {
                    sum = load(s);
                }
            }
            // SAFETY: as above.
            sum = unsafe { take(sum, rows[l], at.wrapping_add(b[l])) };
        }
    }
    let mut c = Cursor {
        p,
        sum: unpack(sum),
    };
    for o in groups * LANES..len {
        let (a, b) = (span.a[o] as usize, span.b[o] as usize);
        c.take(a, b, span.one(o), sums, start, done);
    }
    c
}
