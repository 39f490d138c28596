//! Classic fourth-order Runge–Kutta on y = (x, v), y' = (v, a(x, v)):
//! k1 = y'(y), k2 = y'(y + h/2 k1), k3 = y'(y + h/2 k2), k4 = y'(y + h k3),
//! y ← y + h/6 (k1 + 2k2 + 2k3 + k4).
//!
//! The weighted sum is accumulated as the stages go, so the scratch is one stage state, one
//! acceleration and the two sums: five vectors per particle, not eight.

use softbody_scene::State;

use super::{axpy, axpy_into};
use crate::Workspace;

/// One step.
pub fn step(ws: &mut Workspace, state: &mut State) {
    let h = ws.model.simulation.dt;
    let mut xs = std::mem::take(&mut ws.stage_x);
    let mut vs = std::mem::take(&mut ws.stage_v);
    let mut sum_x = std::mem::take(&mut ws.sum_x);
    let mut sum_v = std::mem::take(&mut ws.sum_v);

    // k1 at y.
    ws.accelerations(&state.x, &state.v);
    sum_x.copy_from_slice(&state.v);
    sum_v.copy_from_slice(&ws.a);
    axpy_into(&mut xs, &state.x, 0.5 * h, &state.v);
    axpy_into(&mut vs, &state.v, 0.5 * h, &ws.a);
    // k2 and k3 at y + h/2 k1 and y + h/2 k2; k4 at y + h k3.
    for (weight, next) in [(2.0, 0.5 * h), (2.0, h)] {
        ws.accelerations(&xs, &vs);
        axpy(&mut sum_x, weight, &vs);
        axpy(&mut sum_v, weight, &ws.a);
        axpy_into(&mut xs, &state.x, next, &vs);
        axpy_into(&mut vs, &state.v, next, &ws.a);
    }
    ws.accelerations(&xs, &vs);
    axpy(&mut sum_x, 1.0, &vs);
    axpy(&mut sum_v, 1.0, &ws.a);

    axpy(&mut state.x, h / 6.0, &sum_x);
    axpy(&mut state.v, h / 6.0, &sum_v);
    ws.stage_x = xs;
    ws.stage_v = vs;
    ws.sum_x = sum_x;
    ws.sum_v = sum_v;
}
