//! The midpoint method (RK2) on y = (x, v), y' = (v, a(x, v)):
//! y_m = y + (h/2) y'(y), then y ← y + h y'(y_m).

use softbody_scene::State;

use super::{axpy, axpy_into};
use crate::Workspace;

/// One step.
pub fn step(ws: &mut Workspace, state: &mut State) {
    let h = ws.model.simulation.dt;
    ws.accelerations(&state.x, &state.v);
    let mut xm = std::mem::take(&mut ws.stage_x);
    let mut vm = std::mem::take(&mut ws.stage_v);
    axpy_into(&mut xm, &state.x, 0.5 * h, &state.v);
    axpy_into(&mut vm, &state.v, 0.5 * h, &ws.a);
    ws.accelerations(&xm, &vm);
    axpy(&mut state.x, h, &vm);
    axpy(&mut state.v, h, &ws.a);
    ws.stage_x = xm;
    ws.stage_v = vm;
}
