//! [`gather_block`](super::gather_block) in 128-bit registers (SSE2, part of every x86-64): x and y of a sum in one
//! register, z in another; −p by flipping the sign bit, as in [`gather`](super::gather).

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
