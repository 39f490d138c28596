//! Spring forces, computed once per spring and gathered per particle.
//!
//! For spring s = (a, b, r, k_s, k_d), with d = x_a − x_b and l = d/|d|:
//!
//! f_a = −[k_s(|d| − r) + k_d((v_a − v_b)·l)] l,  f_b = −f_a.
//!
//! [`compute`] writes f_a of every spring (in parallel, each spring independent);
//! [`gather`] sums them per particle over its adjacency run in ascending spring order. No
//! particle is written by two threads and every sum has one fixed order, so the result is the
//! same bits for any thread count (the GPU twin, `shaders/spring_forces.wgsl`, does the same).

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Adjacency, Springs};

/// Fewest springs per rayon task: enough to amortise scheduling.
const SPRING_CHUNK: usize = 4096;

/// Force on particle `a` of one spring.
#[inline(always)]
pub fn spring_force(
    xa: DVec3,
    xb: DVec3,
    va: DVec3,
    vb: DVec3,
    rest: f64,
    ks: f64,
    kd: f64,
) -> DVec3 {
    let d = xa - xb;
    let len = d.length();
    // Validation refuses zero-length springs at rest; a spring crushed to zero length later has
    // no direction, and exerting no force is the only choice that does not invent one.
    if len == 0.0 {
        return DVec3::ZERO;
    }
    // One division: with u = 1/|d|, l = u·d and (v_a − v_b)·l = u((v_a − v_b)·d), so
    // f_a = −u[k_s(|d| − r) + k_d·u((v_a − v_b)·d)]·d. Division and square root are the slow
    // operations of a spring; this keeps one of each.
    let u = 1.0 / len;
    let w = va - vb;
    let wd = (w.x * d.x + w.y * d.y) + w.z * d.z;
    (-(ks * (len - rest) + kd * (wd * u)) * u) * d
}

/// Writes the force on `a` of every spring into `out` (per-spring stiffness and damping).
pub fn compute(springs: &Springs, x: &[DVec3], v: &[DVec3], out: &mut [DVec3]) {
    Kernel::per_spring().compute(springs, x, v, out);
}

/// A particle's running sum of spring forces during a sweep ([`Kernel::sweep`]), padded to 32
/// bytes and aligned to them, so that the vector path reads, subtracts and writes it whole
/// with one instruction each (the fourth lane is scratch: it receives z again).
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(32))]
pub struct Sum {
    /// The sum.
    pub f: DVec3,
    /// Scratch lane.
    pad: f64,
}

impl Sum {
    /// +0.
    pub const ZERO: Sum = Sum {
        f: DVec3::ZERO,
        pad: 0.0,
    };
}

/// Where a sweep stands ([`Kernel::sweep`]): the particle whose springs it is taking, and that
/// particle's running sum.
#[derive(Debug, Clone, Copy)]
pub struct Cursor {
    /// The particle.
    pub p: usize,
    /// Its running sum of spring forces.
    pub sum: DVec3,
}

impl Cursor {
    /// Takes the force `f` of a spring from `a` to `b` (springs come in ascending order, sorted
    /// by `a`, with `a < b`): hands the particles before `a` to `done` with their sums (they
    /// are complete), adds `f` to a's sum and subtracts it from b's when b lies in `sums`
    /// (the running sums of particles `start..start + sums.len()`).
    #[inline(always)]
    pub fn take(
        &mut self,
        a: usize,
        b: usize,
        f: DVec3,
        sums: &mut [Sum],
        start: usize,
        done: &mut impl FnMut(usize, DVec3),
    ) {
        if a != self.p {
            self.advance(a, sums, start, done);
        }
        self.sum += f;
        if let Some(t) = sums.get_mut(b.wrapping_sub(start)) {
            t.f -= f;
        }
    }

    /// Hands particles up to (not including) `until` to `done` with their sums.
    #[inline(always)]
    pub fn advance(
        &mut self,
        until: usize,
        sums: &[Sum],
        start: usize,
        done: &mut impl FnMut(usize, DVec3),
    ) {
        while self.p < until {
            done(self.p, self.sum);
            self.p += 1;
            if let Some(s) = sums.get(self.p - start) {
                self.sum = s.f;
            }
        }
    }
}

/// The spring pass, set up once per model: whether every spring shares one stiffness and one
/// damping (then the pass streams only the end points and rest lengths), and whether the CPU
/// runs AVX2 (then each group of [`LANES`] springs is computed in 256-bit registers).
///
/// Every variant performs, per spring, exactly the operations of [`spring_force`] in the same
/// order (IEEE division and square root, no fused multiply-add), so all give the same bits.
#[derive(Debug, Clone, Copy)]
pub struct Kernel {
    /// `Some((k_s, k_d))` when every spring has these.
    uniform: Option<(f64, f64)>,
    avx2: bool,
}

/// Springs computed side by side.
pub const LANES: usize = 4;

impl Kernel {
    /// The kernel for `springs`.
    pub fn new(springs: &Springs) -> Kernel {
        let uniform = match (springs.stiffness.first(), springs.damping.first()) {
            (Some(&ks), Some(&kd))
                if springs
                    .stiffness
                    .iter()
                    .all(|&k| k.to_bits() == ks.to_bits())
                    && springs.damping.iter().all(|&k| k.to_bits() == kd.to_bits()) =>
            {
                Some((ks, kd))
            }
            _ => None,
        };
        Kernel {
            uniform,
            ..Kernel::per_spring()
        }
    }

    /// A kernel that reads every spring's stiffness and damping.
    pub fn per_spring() -> Kernel {
        Kernel {
            uniform: None,
            avx2: avx2(),
        }
    }

    /// Writes the force on `a` of every spring into `out`, in parallel.
    pub fn compute(self, springs: &Springs, x: &[DVec3], v: &[DVec3], out: &mut [DVec3]) {
        assert_eq!(out.len(), springs.len());
        let chunk = spring_chunk(springs.len());
        out.par_chunks_mut(chunk)
            .enumerate()
            .for_each(|(c, chunk_out)| self.range(springs, x, v, c * chunk, chunk_out));
    }

    /// Forces of springs `first..first + out.len()` into `out`, on this thread.
    #[inline]
    pub fn range(
        self,
        springs: &Springs,
        x: &[DVec3],
        v: &[DVec3],
        first: usize,
        out: &mut [DVec3],
    ) {
        self.check(springs, x, v, first, out.len());
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: AVX2 was detected at run time; `check` vouched for the ranges.
            unsafe { avx::range(springs, self.uniform, x, v, first, out) };
            return;
        }
        for (k, f) in out.iter_mut().enumerate() {
            *f = self.one(springs, x, v, first + k);
        }
    }

    /// The forces of springs `first..first + len` (ascending, sorted by `a`, each with a < b
    /// and b among the particles of `sums`, `start..start + sums.len()`), taken by `cursor` in
    /// order ([`Cursor::take`]); returns the cursor.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn sweep(
        self,
        springs: &Springs,
        x: &[DVec3],
        v: &[DVec3],
        first: usize,
        len: usize,
        sums: &mut [Sum],
        start: usize,
        cursor: Cursor,
        done: &mut impl FnMut(usize, DVec3),
    ) -> Cursor {
        self.check(springs, x, v, first, len);
        let inside = |&b: &u32| (b as usize).wrapping_sub(start) < sums.len();
        assert!(springs.b[first..first + len].iter().all(inside));
        // SAFETY: just checked.
        unsafe { self.sweep_checked(springs, x, v, first, len, sums, start, cursor, done) }
    }

    /// [`Kernel::sweep`] without its checks of the springs' ranges.
    ///
    /// # Safety
    /// What [`Kernel::check`] checks holds: springs `first..first + len` exist with their rest
    /// lengths (and parameters, unless uniform), and every end point indexes `x` and `v`; and
    /// every second end b of these springs lies in `start..start + sums.len()`.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(crate) unsafe fn sweep_checked(
        self,
        springs: &Springs,
        x: &[DVec3],
        v: &[DVec3],
        first: usize,
        len: usize,
        sums: &mut [Sum],
        start: usize,
        mut cursor: Cursor,
        done: &mut impl FnMut(usize, DVec3),
    ) -> Cursor {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: AVX2 was detected at run time; the caller vouched for the ranges.
            return unsafe {
                avx::sweep(
                    springs,
                    self.uniform,
                    x,
                    v,
                    first,
                    len,
                    sums,
                    start,
                    cursor,
                    done,
                )
            };
        }
        for s in first..first + len {
            let f = self.one(springs, x, v, s);
            let (a, b) = (springs.a[s] as usize, springs.b[s] as usize);
            cursor.take(a, b, f, sums, start, done);
        }
        cursor
    }

    /// The force of spring `s`, by [`spring_force`].
    #[inline]
    fn one(self, springs: &Springs, x: &[DVec3], v: &[DVec3], s: usize) -> DVec3 {
        let (a, b) = (springs.a[s] as usize, springs.b[s] as usize);
        let (ks, kd) = match self.uniform {
            Some(p) => p,
            None => (springs.stiffness[s], springs.damping[s]),
        };
        spring_force(x[a], x[b], v[a], v[b], springs.rest[s], ks, kd)
    }

    /// Panics unless springs `first..first + len` exist with all their data and every end point
    /// indexes `x` and `v`: the vector paths rely on it.
    #[inline]
    fn check(self, springs: &Springs, x: &[DVec3], v: &[DVec3], first: usize, len: usize) {
        let r = first..first + len;
        let (a, b) = (&springs.a[r.clone()], &springs.b[r.clone()]);
        let _ = &springs.rest[r.clone()];
        if self.uniform.is_none() {
            let _ = (&springs.stiffness[r.clone()], &springs.damping[r]);
        }
        let top = a.iter().zip(b).map(|(&a, &b)| a.max(b)).max().unwrap_or(0) as usize;
        assert!(len == 0 || (top < x.len() && top < v.len()));
    }
}

/// Springs per rayon task: at least [`SPRING_CHUNK`], and about four tasks per thread on
/// large models.
fn spring_chunk(springs: usize) -> usize {
    let tasks = 4 * rayon::current_num_threads();
    springs
        .div_ceil(tasks)
        .clamp(SPRING_CHUNK, 1 << 16)
        .next_multiple_of(LANES)
}

fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Sum of the spring forces on particle `i`.
#[inline(always)]
pub fn gather(adjacency: &Adjacency, per_spring: &[DVec3], i: usize) -> DVec3 {
    let mut f = DVec3::ZERO;
    for &e in adjacency.of(i) {
        // f − p is f + (−p) in IEEE arithmetic: flip the sign bit instead of branching.
        let sign = ((e & 1) as u64) << 63;
        let p = per_spring[(e >> 1) as usize];
        f += DVec3::new(
            f64::from_bits(p.x.to_bits() ^ sign),
            f64::from_bits(p.y.to_bits() ^ sign),
            f64::from_bits(p.z.to_bits() ^ sign),
        );
    }
    f
}

/// Where [`gather_block`] reads per-spring forces from.
///
/// # Safety
/// `at(s)` either panics or returns a pointer to a `DVec3` (three `f64`) that stays valid and
/// that no thread writes while the gather that asked for it runs.
pub unsafe trait Forces: Sync {
    /// The force of spring `s`.
    fn at(&self, s: usize) -> *const f64;
}

// SAFETY: a shared slice is immutable while borrowed; indexing checks the bounds.
unsafe impl Forces for [DVec3] {
    #[inline(always)]
    fn at(&self, s: usize) -> *const f64 {
        (&self[s] as *const DVec3).cast()
    }
}

/// [`gather`] through [`Forces`].
#[inline(always)]
fn gather_from<F: Forces + ?Sized>(adjacency: &Adjacency, per_spring: &F, i: usize) -> DVec3 {
    let mut f = DVec3::ZERO;
    for &e in adjacency.of(i) {
        // SAFETY: `Forces` promises a readable DVec3 that nobody writes meanwhile.
        let p = unsafe { per_spring.at((e >> 1) as usize).cast::<DVec3>().read() };
        f += if e & 1 == 0 { p } else { -p };
    }
    f
}

/// Sums of the spring forces on particles `first..first + out.len()`: [`gather`] for each, four
/// particles side by side (independent addition chains; each particle's own sum keeps its
/// order, so the bits are [`gather`]'s).
pub fn gather_block<F: Forces + ?Sized>(
    adjacency: &Adjacency,
    per_spring: &F,
    first: usize,
    out: &mut [DVec3],
) {
    #[cfg(target_arch = "x86_64")]
    {
        sse::gather_block(adjacency, per_spring, first, out);
    }
    #[cfg(not(target_arch = "x86_64"))]
    for (k, f) in out.iter_mut().enumerate() {
        *f = gather_from(adjacency, per_spring, first + k);
    }
}

/// [`gather_block`] in 128-bit registers (SSE2, part of every x86-64): x and y of a sum in one
/// register, z in another; −p by flipping the sign bit, as in [`gather`].
#[cfg(target_arch = "x86_64")]
mod sse {
    use std::arch::x86_64::*;

    use glam::DVec3;
    use softbody_scene::Adjacency;

    use super::{Forces, gather_from};

    /// Particles gathered side by side.
    const WAYS: usize = 4;

    // SAFETY (every `unsafe` below): SSE2 is part of the x86-64 baseline, so its intrinsics
    // are always available; the loads read the DVec3 that `Forces::at` vouches for.

    #[inline(always)]
    fn add<F: Forces + ?Sized>(acc: &mut (__m128d, __m128d), per_spring: &F, e: u32) {
        let p = per_spring.at((e >> 1) as usize);
        unsafe {
            let sign = _mm_castsi128_pd(_mm_set1_epi64x(((e & 1) as i64) << 63));
            // x and y together, then z.
            let (xy, z) = (_mm_loadu_pd(p), _mm_load_sd(p.add(2)));
            acc.0 = _mm_add_pd(acc.0, _mm_xor_pd(xy, sign));
            acc.1 = _mm_add_sd(acc.1, _mm_xor_pd(z, sign));
        }
    }

    #[inline(always)]
    fn store(acc: (__m128d, __m128d)) -> DVec3 {
        let mut xy = [0.0; 2];
        unsafe {
            _mm_storeu_pd(xy.as_mut_ptr(), acc.0);
            DVec3::new(xy[0], xy[1], _mm_cvtsd_f64(acc.1))
        }
    }

    #[inline]
    pub(super) fn gather_block<F: Forces + ?Sized>(
        adjacency: &Adjacency,
        per_spring: &F,
        first: usize,
        out: &mut [DVec3],
    ) {
        let (offsets, entries) = (&adjacency.offsets, &adjacency.entries[..]);
        let mut chunks = out.chunks_exact_mut(WAYS);
        let mut i = first;
        for out in &mut chunks {
            let o: [usize; WAYS + 1] = std::array::from_fn(|l| offsets[i + l] as usize);
            let runs: [&[u32]; WAYS] = std::array::from_fn(|l| &entries[o[l]..o[l + 1]]);
            let common = runs.iter().map(|r| r.len()).min().unwrap_or(0);
            let zero = unsafe { _mm_setzero_pd() };
            let mut acc = [(zero, zero); WAYS];
            #[allow(clippy::needless_range_loop, reason = "four runs walked side by side")]
            for j in 0..common {
                for l in 0..WAYS {
                    add(&mut acc[l], per_spring, runs[l][j]);
                }
            }
            for l in 0..WAYS {
                for &e in &runs[l][common..] {
                    add(&mut acc[l], per_spring, e);
                }
                out[l] = store(acc[l]);
            }
            i += WAYS;
        }
        for (k, f) in chunks.into_remainder().iter_mut().enumerate() {
            *f = gather_from(adjacency, per_spring, i + k);
        }
    }
}

/// The spring pass in 256-bit vectors: four springs per group, each lane doing exactly the
/// scalar [`spring_force`]'s IEEE operations in its order (`vdivpd`, `vsqrtpd` are correctly
/// rounded like their scalar forms; nothing is fused).
#[cfg(target_arch = "x86_64")]
mod avx {
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
            // |d| = sqrt((dx² + dy²) + dz²)
            let n = _mm256_sqrt_pd(_mm256_add_pd(
                _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)),
                _mm256_mul_pd(dz, dz),
            ));
            // As in `spring_force`: u = 1/|d|, s = −(k_s(|d| − r) + k_d((w·d)u))u, f = s·d.
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
            // Lanes of zero length exert no force.
            let live = _mm256_cmp_pd::<_CMP_NEQ_UQ>(n, zero);
            let fx = _mm256_and_pd(_mm256_mul_pd(s, dx), live);
            let fy = _mm256_and_pd(_mm256_mul_pd(s, dy), live);
            let fz = _mm256_and_pd(_mm256_mul_pd(s, dz), live);
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
}
