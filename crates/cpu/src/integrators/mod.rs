//! Time integrators. Each advances the state by one step h = dt; the explicit family
//! (explicit Euler, symplectic Euler, midpoint, RK4) evaluates accelerations (gravity, drag,
//! springs, [`crate::contact`]) and ends with [`crate::collision_response`]; implicit Euler
//! handles contact inside its solve.
//!
//! Each explicit stage is one fused `pipeline::pass`: spring forces at
//! the stage's (x, v), then per particle its acceleration and the stage update, written to other
//! arrays than the ones read (the workspace double-buffers the state). The last stage also
//! applies the collision response and checks finiteness (`finish`). Updates have no
//! reductions, so any split gives the same bits.

pub mod explicit_euler;
pub mod implicit_euler;
pub mod midpoint;
pub mod rk4;
pub mod symplectic_euler;

use glam::DVec3;
use softbody_scene::{Model, State};
use softbody_terrain::Surface;

use crate::Workspace;
use crate::collision_response::respond_one;
use crate::forces::acceleration_with;
use crate::pipeline::pass;

/// The end of an explicit step for particle i: its collision response (unless it is pinned),
/// then whether its position and velocity are finite.
#[inline(always)]
pub(crate) fn finish(
    model: &Model,
    surfaces: &[Surface],
    i: usize,
    x: &mut DVec3,
    v: &mut DVec3,
) -> bool {
    let eps = model.simulation.contact_distance;
    // Clear of every surface (and with none): the response would change nothing.
    if !surfaces.iter().all(|s| s.clear_of(*x, eps)) && model.inv_mass[i] != 0.0 {
        respond_one(surfaces, eps, x, v);
    }
    all_finite(*x, *v)
}

/// `x.is_finite() && v.is_finite()` in a few instructions: c − c is +0 for a finite c and NaN
/// for an infinite or NaN one, so the six differences sum to 0 exactly when all are finite.
#[inline(always)]
#[allow(clippy::eq_op, reason = "c − c is the test")]
fn all_finite(x: DVec3, v: DVec3) -> bool {
    let d = (x - x) + (v - v);
    d.x + d.y + d.z == 0.0
}

/// One step of a single-stage Euler method in one fused pass: spring forces, then per particle
/// the gathered forces, gravity, drag and contact, `update(x, v, a, h) -> (x', v')`, the
/// collision response and the finiteness check. Returns the first particle that is not finite.
pub(crate) fn euler_step(
    ws: &mut Workspace,
    state: &mut State,
    update: impl Fn(DVec3, DVec3, DVec3, f64) -> (DVec3, DVec3) + Sync,
) -> Option<usize> {
    let h = ws.model.simulation.dt;
    let (model, surfaces) = (&ws.model, &ws.surfaces[..]);
    let (x, v) = (&state.x[..], &state.v[..]);
    let bad = pass(
        &mut ws.plan,
        ws.kernel,
        model,
        x,
        v,
        (&mut ws.next_x[..], &mut ws.next_v[..]),
        // Inlined into the pass's block loop: a call per particle costs more than the update.
        #[inline(always)]
        |i, springs, (xn, vn)| {
            let a = acceleration_with(model, surfaces, i, x[i], v[i], springs);
            (*xn, *vn) = update(x[i], v[i], a, h);
            finish(model, surfaces, i, xn, vn)
        },
    );
    std::mem::swap(&mut state.x, &mut ws.next_x);
    std::mem::swap(&mut state.v, &mut ws.next_v);
    bad
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::all_finite;

    #[test]
    fn all_finite_is_is_finite() {
        let values = [
            0.0,
            -0.0,
            1.5,
            -f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for &a in &values {
            for &b in &values {
                for k in 0..6 {
                    let mut c = [1.0; 6];
                    c[k] = a;
                    c[(k + 1) % 6] = b;
                    let (x, v) = (DVec3::new(c[0], c[1], c[2]), DVec3::new(c[3], c[4], c[5]));
                    assert_eq!(all_finite(x, v), x.is_finite() && v.is_finite(), "{x} {v}");
                }
            }
        }
    }
}
