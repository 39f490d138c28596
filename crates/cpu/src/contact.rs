//! Contact and friction forces of the explicit integrators.
//!
//! With f the gravity, drag and spring force on a particle, for each surface where the signed
//! distance φ < ε and the particle pushes into it (N·f < 0):
//!
//! - contact: `−(N·f) N`, which cancels the push;
//! - friction, with f_n = −N·f > 0 and the slip velocity v_t = v − (v·N)N:
//!   - `coulomb`: kinetic `−μ f_n v_t/|v_t|`; when that would stop the slip within this step
//!     (m|v_t|/h ≤ μ f_n, so it never reverses v_t) the contact sticks instead, and friction
//!     holds back the tangential force and the remaining slip, `−f_t − m v_t/h`, up to μ f_n
//!     (static friction: a body on a slope shallower than atan μ stays put);
//!   - `viscous` (the classic course formula): `−k_f f_n v_t`, capped at m|v_t|/h so that it
//!     too never reverses the slip in one step.
//!
//! Every surface sees the same f (gravity, drag and springs): contact forces of one surface do
//! not feed the next.

use glam::DVec3;
use softbody_scene::FrictionModel;
use softbody_terrain::Surface;

/// The contact and friction force on one particle (mass m, position x, velocity v, applied
/// force f) for step size h.
///
/// Out of line: the explicit passes call it only for particles that are not clear of every
/// surface (`Surface::clear_of`), and their per-particle update stays small.
#[inline(never)]
pub fn contact_force(
    surfaces: &[Surface],
    eps: f64,
    h: f64,
    m: f64,
    x: DVec3,
    v: DVec3,
    f: DVec3,
) -> DVec3 {
    let mut total = DVec3::ZERO;
    for s in surfaces {
        let Some(c) = s.query(x, eps) else { continue };
        let n = c.normal;
        let fn_dot = n.dot(f);
        if fn_dot >= 0.0 {
            continue;
        }
        let press = -fn_dot;
        total += press * n;
        let vt = v - v.dot(n) * n;
        total += friction(
            s.friction_model,
            s.friction,
            press,
            h,
            m,
            vt,
            f - fn_dot * n,
        );
    }
    total
}

/// Friction force for a contact pressed with `press`, slip `vt` and tangential applied force
/// `ft`.
#[inline(never)]
pub fn friction(
    model: FrictionModel,
    mu: f64,
    press: f64,
    h: f64,
    m: f64,
    vt: DVec3,
    ft: DVec3,
) -> DVec3 {
    let stop = m / h; // force per unit slip speed that stops the slip in one step
    match model {
        FrictionModel::Coulomb => {
            let limit = mu * press;
            let speed = vt.length();
            if stop * speed > limit {
                -limit * vt / speed
            } else {
                (-ft - stop * vt).clamp_length_max(limit)
            }
        }
        FrictionModel::Viscous => (-mu * press * vt).clamp_length_max(stop * vt.length()),
    }
}
