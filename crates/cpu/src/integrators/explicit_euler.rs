//! Explicit (forward) Euler: x' = x + h v, v' = v + h a(x, v).

use softbody_scene::State;

use crate::Workspace;

/// One step, collision response included; returns the first particle that is not finite.
pub fn step(ws: &mut Workspace, state: &mut State) -> Option<usize> {
    super::euler_step(ws, state, |x, v, a, h| (x + h * v, v + h * a))
}
