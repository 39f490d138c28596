//! Symplectic (semi-implicit) Euler: v' = v + h a(x, v), x' = x + h v'.
//!
//! One fused pass: spring forces, then per particle the gathered forces, gravity, drag and
//! contact, the update, the collision response and the finiteness check.

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
            *vn = v[i] + h * a;
            *xn = x[i] + h * *vn;
            finish(model, surfaces, i, xn, vn)
        },
    );
    std::mem::swap(&mut state.x, &mut ws.next_x);
    std::mem::swap(&mut state.v, &mut ws.next_v);
    bad
}
