//! Symplectic (semi-implicit) Euler: v' = v + h a(x, v), x' = x + h v'.

use softbody_scene::State;

use super::axpy;
use crate::Workspace;

/// One step.
pub fn step(ws: &mut Workspace, state: &mut State) {
    let h = ws.model.simulation.dt;
    ws.accelerations(&state.x, &state.v);
    axpy(&mut state.v, h, &ws.a);
    axpy(&mut state.x, h, &state.v);
}
