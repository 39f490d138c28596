//! The stencil's rows in 512-bit vectors: eight consecutive particles per group, each lane
//! doing exactly [`spring_force`](crate::spring_forces::spring_force)'s IEEE operations in its
//! order (`vdivpd`, `vsqrtpd` are correctly rounded like their scalar forms; nothing is fused),
//! and the sums' additions in the scalar path's order.
//!
//! It needs AVX-512F alone: the sign flip is an integer xor of the bits (the floating-point
//! xor is AVX-512DQ's; both flip the same bit), and the lanes without a force are zeroed by a
//! mask register (zero-masking writes +0, as the scalar path's `DVec3::ZERO`).

use std::arch::x86_64::*;

use super::{ROW_MULTIPLE, RowSpring, RowSprings, Slab, Sources, Stencil};

/// Particles side by side.
const LANES: usize = 8;
const _: () = assert!(ROW_MULTIPLE.is_multiple_of(LANES));

/// The forces of eight springs, one per lane, from their end points' differences
/// d = x_a − x_b (`dx`, `dy`, `dz`) and w = v_a − v_b, rest length `r` and parameters:
/// [`spring_force`](crate::spring_forces::spring_force)'s IEEE operations in its order,
/// u = 1/|d|, s = −(k_s(|d| − r) + k_d((w·d)u))u, f = s·d. Lanes of zero length, and lanes
/// not in `live`, exert no force (+0).
#[allow(clippy::too_many_arguments)]
#[inline]
#[target_feature(enable = "avx512f")]
fn forces(
    dx: __m512d,
    dy: __m512d,
    dz: __m512d,
    [wx, wy, wz]: [__m512d; 3],
    r: __m512d,
    ks: __m512d,
    kd: __m512d,
    live: __mmask8,
) -> [__m512d; 3] {
    // |d| = sqrt((dx² + dy²) + dz²)
    let n = _mm512_sqrt_pd(_mm512_add_pd(
        _mm512_add_pd(_mm512_mul_pd(dx, dx), _mm512_mul_pd(dy, dy)),
        _mm512_mul_pd(dz, dz),
    ));
    let u = _mm512_div_pd(_mm512_set1_pd(1.0), n);
    let wd = _mm512_add_pd(
        _mm512_add_pd(_mm512_mul_pd(wx, dx), _mm512_mul_pd(wy, dy)),
        _mm512_mul_pd(wz, dz),
    );
    let e = _mm512_add_pd(
        _mm512_mul_pd(ks, _mm512_sub_pd(n, r)),
        _mm512_mul_pd(kd, _mm512_mul_pd(wd, u)),
    );
    let minus_e = _mm512_castsi512_pd(_mm512_xor_si512(
        _mm512_castpd_si512(e),
        _mm512_set1_epi64(i64::MIN),
    ));
    let s = _mm512_mul_pd(minus_e, u);
    let live = _mm512_mask_cmp_pd_mask::<_CMP_NEQ_UQ>(live, n, _mm512_setzero_pd());
    [dx, dy, dz].map(|d| _mm512_maskz_mul_pd(live, s, d))
}

/// The forces of `springs` into the ring ([`Slab::compute_row`]).
///
/// # Safety
/// AVX-512F is available, and `springs` were made by [`Slab::row_springs`] for this slab and
/// stencil.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn compute_row(slab: &mut Slab, stencil: &Stencil, springs: &RowSprings) {
    let row = stencil.row;
    let (len, rl) = (slab.len, slab.ring_len);
    let state = slab.state.as_ptr();
    let ring = slab.ring.as_mut_ptr();
    // Group by group, every offset's springs: the group's own particles are read once for
    // all of them.
    for g in 0..row / LANES {
        let i = LANES * g;
        // SAFETY: `Slab::row_springs` checked that rows a0.., b0.. of every state array, row
        // out.. of every ring array and each offset's row of lane masks hold `row` slots, a
        // multiple of eight.
        unsafe {
            let a: [__m512d; 6] =
                std::array::from_fn(|c| _mm512_loadu_pd(state.add(c * len + springs.a0 + i)));
            for &RowSpring { r, b0, out } in springs.springs() {
                let off = &stencil.offsets[r];
                let d =
                    |c: usize| _mm512_sub_pd(a[c], _mm512_loadu_pd(state.add(c * len + b0 + i)));
                let (dx, dy, dz) = (d(0), d(1), d(2));
                let w = [d(3), d(4), d(5)];
                // Lanes without a spring exert no force.
                let mask = _mm512_loadu_epi64(stencil.lane_masks.as_ptr().add(r * row + i).cast());
                let live = _mm512_test_epi64_mask(mask, mask);
                let (rest, ks, kd) = (
                    _mm512_set1_pd(off.rest),
                    _mm512_set1_pd(off.ks),
                    _mm512_set1_pd(off.kd),
                );
                let [fx, fy, fz] = forces(dx, dy, dz, w, rest, ks, kd, live);
                let dst = ring.add(out + i);
                _mm512_storeu_pd(dst, fx);
                _mm512_storeu_pd(dst.add(rl), fy);
                _mm512_storeu_pd(dst.add(2 * rl), fz);
            }
        }
    }
}

/// The sums of a row ([`Slab::sum_row`]), r slots per component.
///
/// # Safety
/// AVX-512F is available, and `sources` were made by [`Slab::sources`] for this slab.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn sum_row(slab: &mut Slab, r: usize, sources: &Sources) {
    let ring = slab.ring.as_ptr();
    let sums = slab.sums.as_mut_ptr();
    let rl = slab.ring_len;
    for g in 0..r / LANES {
        let (mut sx, mut sy, mut sz) = (
            _mm512_setzero_pd(),
            _mm512_setzero_pd(),
            _mm512_setzero_pd(),
        );
        // SAFETY: `Slab::sources` checked that each component's row of r slots, a multiple of
        // eight, lies in the ring.
        unsafe {
            for &at in sources.back() {
                let p = ring.add(at + LANES * g);
                sx = _mm512_sub_pd(sx, _mm512_loadu_pd(p));
                sy = _mm512_sub_pd(sy, _mm512_loadu_pd(p.add(rl)));
                sz = _mm512_sub_pd(sz, _mm512_loadu_pd(p.add(2 * rl)));
            }
            for &at in sources.forth() {
                let p = ring.add(at + LANES * g);
                sx = _mm512_add_pd(sx, _mm512_loadu_pd(p));
                sy = _mm512_add_pd(sy, _mm512_loadu_pd(p.add(rl)));
                sz = _mm512_add_pd(sz, _mm512_loadu_pd(p.add(2 * rl)));
            }
        }
        // SAFETY: `sums` holds three rows of r slots.
        unsafe {
            _mm512_storeu_pd(sums.add(LANES * g), sx);
            _mm512_storeu_pd(sums.add(r + LANES * g), sy);
            _mm512_storeu_pd(sums.add(2 * r + LANES * g), sz);
        }
    }
}
