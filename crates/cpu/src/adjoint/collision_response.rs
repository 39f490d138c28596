//! The adjoint of [`crate::collision_response`], on the forward's branches (which surfaces the
//! particle is within, which it approaches, which impacts are fresh, which it has gone into).
//!
//! Surface by surface in reverse, with N = N(x) and ∂N/∂x = J at the position the forward
//! queried:
//!
//! - x ← x − φN: x̄ gains −N(N·x̄) (∂φ/∂x = N) and N̄ = −φ x̄;
//! - v ← v − (1 + k) (v·N) N: v̄ ← v̄ − (1 + k) N (N·v̄), N̄ −= (1 + k)[(N·v̄) v + (v·N) v̄], and on a
//!   fresh impact (k the restitution) k̄ = −(v·N)(N·v̄);
//! - then x̄ += Jᵀ N̄.

use glam::DVec3;
use softbody_terrain::{Contact, Surface};

use crate::collision_response::{band_mask, reflection};

/// The most surfaces one particle's response records without allocating.
const INLINE: usize = 8;

/// What the forward response did at one surface.
#[derive(Debug, Clone, Copy)]
struct Record {
    surface: usize,
    contact: Contact,
    x: DVec3,
    v: DVec3,
    /// (1 + k) when the normal velocity was reflected, and whether k is the restitution.
    reflect: Option<(f64, bool)>,
    pushed: bool,
}

/// The cotangents of the response's inputs (x, v before it) for the cotangents `(x_bar,
/// v_bar)` of its outputs, for a particle that started the step at `start` and ended it at
/// `(x, v)` before the response; each surface's restitution cotangent is added to
/// `restitution_bar` (one per surface). [`crate::collision_response::respond_one`] is the
/// forward.
#[allow(clippy::too_many_arguments)]
pub fn respond_one_vjp(
    surfaces: &[Surface],
    eps: f64,
    h: f64,
    (x_start, v_start): (DVec3, DVec3),
    (mut x, mut v): (DVec3, DVec3),
    (mut x_bar, mut v_bar): (DVec3, DVec3),
    restitution_bar: &mut [f64],
) -> (DVec3, DVec3) {
    if surfaces.iter().all(|s| s.clear_of(x, eps)) {
        return (x_bar, v_bar);
    }
    let mut records: smallvec::SmallVec<[Record; INLINE]> = smallvec::SmallVec::new();
    let mut start_mask = None;
    for (k, s) in surfaces.iter().enumerate() {
        let Some(c) = s.query(x, eps) else { continue };
        let mut record = Record {
            surface: k,
            contact: c,
            x,
            v,
            reflect: None,
            pushed: false,
        };
        let vn = v.dot(c.normal);
        if vn < 0.0 {
            let mask = *start_mask.get_or_insert_with(|| band_mask(surfaces, eps, x_start));
            let (scale, fresh) = reflection(s, k, mask, (eps, h), (v, v_start), c.normal);
            record.reflect = Some((scale, fresh));
            v -= scale * vn * c.normal;
        }
        if c.phi < 0.0 {
            record.pushed = true;
            x -= c.phi * c.normal;
        }
        records.push(record);
    }
    for r in records.iter().rev() {
        let n = r.contact.normal;
        let mut n_bar = DVec3::ZERO;
        if r.pushed {
            n_bar -= r.contact.phi * x_bar;
            x_bar -= n * n.dot(x_bar);
        }
        if let Some((scale, fresh)) = r.reflect {
            let vn = r.v.dot(n);
            let along = n.dot(v_bar);
            if fresh {
                restitution_bar[r.surface] -= vn * along;
            }
            n_bar -= scale * (along * r.v + vn * v_bar);
            v_bar -= scale * along * n;
        }
        let j = surfaces[r.surface].normal_jacobian(r.x);
        x_bar += j.transpose() * n_bar;
    }
    (x_bar, v_bar)
}
