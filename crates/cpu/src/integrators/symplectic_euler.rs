//! Symplectic (semi-implicit) Euler: v' = v + h a(x, v), x' = x + h v'.

use softbody_scene::{Model, State};
use softbody_terrain::Surface;

use super::Passes;
use crate::body_contact::PairForces;

/// One step, collision response included; returns the first particle that is not finite.
pub fn step(
    passes: &mut Passes,
    model: &Model,
    surfaces: &[Surface],
    pairs: &impl PairForces,
    state: &mut State,
) -> Option<usize> {
    passes.euler_step(model, surfaces, pairs, state, |x, v, a, h| {
        let v_next = v + h * a;
        (x + h * v_next, v_next)
    })
}
