//! Energies of a state: kinetic ½Σm|v|², gravitational −Σm g·x, elastic ½Σk_s(|d| − r)².
//!
//! Sums are [`chunked_sum`]s: the same bits for any thread count.

use glam::DVec3;
use softbody_scene::{Energies, Model, State};

use crate::reduce::chunked_sum;

/// The three energies of `state`.
pub fn energies(model: &Model, state: &State) -> Energies {
    let g: DVec3 = model.simulation.gravity;
    let (m, x, v) = (&model.mass, &state.x, &state.v);
    let s = &model.springs;
    Energies {
        kinetic: 0.5 * chunked_sum(m.len(), |i| m[i] * v[i].length_squared()),
        gravitational: -chunked_sum(m.len(), |i| m[i] * g.dot(x[i])),
        elastic: 0.5
            * chunked_sum(s.len(), |k| {
                let stretch = x[s.a[k] as usize].distance(x[s.b[k] as usize]) - s.rest[k];
                s.stiffness[k] * stretch * stretch
            }),
    }
}
