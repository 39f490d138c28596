//! Explicit (forward) Euler: x' = x + h v, v' = v + h a(x, v).
//!
//! One fused pass, as [`super::symplectic_euler`].

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
    let bad = pass(
        &mut ws.plan,
        ws.kernel,
        model,
        x,
        v,
        (&mut ws.next_x[..], &mut ws.next_v[..]),
        |i, springs, (xn, vn)| {
            let a = acceleration_with(model, surfaces, i, x[i], v[i], springs);
            *xn = x[i] + h * v[i];
            *vn = v[i] + h * a;
            finish(model, surfaces, i, xn, vn)
        },
    );
    std::mem::swap(&mut state.x, &mut ws.next_x);
    std::mem::swap(&mut state.v, &mut ws.next_v);
    bad
}
