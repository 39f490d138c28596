//! Symplectic (semi-implicit) Euler: v' = v + h a(x, v), x' = x + h v'.

use softbody_scene::State;

use crate::Workspace;

/// One step, collision response included; returns the first particle that is not finite.
pub fn step(ws: &mut Workspace, state: &mut State) -> Option<usize> {
    super::euler_step(ws, state, |x, v, a, h| {
        let v_next = v + h * a;
        (x + h * v_next, v_next)
    })
}
