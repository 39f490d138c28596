//! Classic fourth-order Runge–Kutta on y = (x, v), y' = (v, a(x, v)):
//! k1 = y'(y), k2 = y'(y + h/2 k1), k3 = y'(y + h/2 k2), k4 = y'(y + h k3),
//! y ← y + h/6 (k1 + 2k2 + 2k3 + k4).
//!
//! The weighted sum is accumulated as the stages go. Each stage is one fused pass that reads
//! the stage state and writes the next one (the stage buffer and the workspace's second state
//! buffer take turns) along with the running sums; the last writes the new state, collision
//! response and finiteness check included.

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

    // k1 at y.
    pass(
        &mut ws.plan,
        ws.kernel,
        model,
        x,
        v,
        (
            &mut ws.stage_x[..],
            &mut ws.stage_v[..],
            &mut ws.sum_x[..],
            &mut ws.sum_v[..],
        ),
        |i, springs, (xs, vs, sum_x, sum_v)| {
            let a = acceleration_with(model, surfaces, i, x[i], v[i], springs);
            *sum_x = v[i];
            *sum_v = a;
            *xs = x[i] + 0.5 * h * v[i];
            *vs = v[i] + 0.5 * h * a;
            true
        },
    );
    // k2 and k3 at y + h/2 k1 and y + h/2 k2; the next stage at y + h/2 k2 and y + h k3.
    for (weight, next) in [(2.0, 0.5 * h), (2.0, h)] {
        let (xs, vs) = (&ws.stage_x[..], &ws.stage_v[..]);
        pass(
            &mut ws.plan,
            ws.kernel,
            model,
            xs,
            vs,
            (
                &mut ws.next_x[..],
                &mut ws.next_v[..],
                &mut ws.sum_x[..],
                &mut ws.sum_v[..],
            ),
            |i, springs, (xn, vn, sum_x, sum_v)| {
                let a = acceleration_with(model, surfaces, i, xs[i], vs[i], springs);
                *sum_x += weight * vs[i];
                *sum_v += weight * a;
                *xn = x[i] + next * vs[i];
                *vn = v[i] + next * a;
                true
            },
        );
        std::mem::swap(&mut ws.stage_x, &mut ws.next_x);
        std::mem::swap(&mut ws.stage_v, &mut ws.next_v);
    }
    // k4 at y + h k3, and the new state.
    let (xs, vs) = (&ws.stage_x[..], &ws.stage_v[..]);
    let (sum_x, sum_v) = (&ws.sum_x[..], &ws.sum_v[..]);
    let bad = pass(
        &mut ws.plan,
        ws.kernel,
        model,
        xs,
        vs,
        (&mut ws.next_x[..], &mut ws.next_v[..]),
        |i, springs, (xn, vn)| {
            let a = acceleration_with(model, surfaces, i, xs[i], vs[i], springs);
            let sx = sum_x[i] + 1.0 * vs[i];
            let sv = sum_v[i] + 1.0 * a;
            *xn = x[i] + h / 6.0 * sx;
            *vn = v[i] + h / 6.0 * sv;
            finish(model, surfaces, i, xn, vn)
        },
    );
    std::mem::swap(&mut state.x, &mut ws.next_x);
    std::mem::swap(&mut state.v, &mut ws.next_v);
    bad
}
