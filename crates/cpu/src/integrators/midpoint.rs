//! The midpoint method (RK2) on y = (x, v), y' = (v, a(x, v)):
//! y_m = y + (h/2) y'(y), then y ← y + h y'(y_m).
//!
//! Two fused passes: the first writes y_m, the second the new state (collision response and
//! finiteness check included).

use softbody_scene::State;

use super::finish;
use crate::Workspace;
use crate::forces::acceleration_with;
use crate::pipeline::pass;

/// One step, collision response included; returns the first particle that is not finite.
pub fn step(ws: &mut Workspace, state: &mut State) -> Option<usize> {
    let h = ws.model.simulation.dt;
    let (model, surfaces) = (&ws.model, &ws.surfaces[..]);
    let (x, v) = (&state.x[..], &state.v[..]);
    pass(
        &mut ws.plan,
        ws.kernel,
        model,
        x,
        v,
        (&mut ws.stage_x[..], &mut ws.stage_v[..]),
        |i, springs, (xm, vm)| {
            let a = acceleration_with(model, surfaces, i, x[i], v[i], springs);
            *xm = x[i] + 0.5 * h * v[i];
            *vm = v[i] + 0.5 * h * a;
            true
        },
    );
    let (xm, vm) = (&ws.stage_x[..], &ws.stage_v[..]);
    let bad = pass(
        &mut ws.plan,
        ws.kernel,
        model,
        xm,
        vm,
        (&mut ws.next_x[..], &mut ws.next_v[..]),
        |i, springs, (xn, vn)| {
            let a = acceleration_with(model, surfaces, i, xm[i], vm[i], springs);
            *xn = x[i] + h * vm[i];
            *vn = v[i] + h * a;
            finish(model, surfaces, i, xn, vn)
        },
    );
    std::mem::swap(&mut state.x, &mut ws.next_x);
    std::mem::swap(&mut state.v, &mut ws.next_v);
    bad
}
