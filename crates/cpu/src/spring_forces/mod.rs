//! Spring forces, computed once per spring and gathered per particle.
//!
//! For spring s = (a, b, r, k_s, k_d), with d = x_a − x_b and l = d/|d|:
//!
//! f_a = −[k_s(|d| − r) + k_d((v_a − v_b)·l)] l,  f_b = −f_a.
//!
//! [`compute`] writes f_a of every spring (in parallel, each spring independent); [`gather`] sums
//! them per particle over its adjacency run in ascending spring order. No particle is written by
//! two threads and every sum has one fixed order, so the result is the same bits for any thread
//! count (the GPU twin, `crates/gpu/shaders/spring_forces.wgsl`, does the same).

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

/// The vector instructions a pass runs (the stencil's rows, the Euler methods' row updates),
/// each giving the same bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Isa {
    /// One particle at a time.
    Scalar,
    /// Four particles side by side in 256-bit vectors.
    Avx2,
    /// Eight particles side by side in 512-bit vectors (AVX-512F alone).
    Avx512,
}

impl Isa {
    /// The widest the CPU runs: AVX-512, then AVX2, then scalar.
    pub(crate) fn detect() -> Isa {
        [Isa::Avx512, Isa::Avx2]
            .into_iter()
            .find(|isa| isa.runs())
            .unwrap_or(Isa::Scalar)
    }

    /// Whether the CPU runs it (detected at run time; the vector paths rely on it).
    pub(crate) fn runs(self) -> bool {
        match self {
            Isa::Scalar => true,
            Isa::Avx2 => avx2(),
            Isa::Avx512 => avx512(),
        }
    }
}

/// Whether the CPU runs AVX2 (then the kernels use it).
pub(crate) fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU runs AVX-512F (then the lattice stencil uses it: [`stencil`]).
pub(crate) fn avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx512f")
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

#[cfg(target_arch = "x86_64")]
mod sse;

#[cfg(target_arch = "x86_64")]
mod avx;

pub(crate) mod stencil;
