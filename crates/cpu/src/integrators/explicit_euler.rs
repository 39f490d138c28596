//! Explicit (forward) Euler: x' = x + h v, v' = v + h a(x, v).

use softbody_scene::{Model, State};
use softbody_terrain::Surface;

use super::Passes;

/// Explicit Euler and its scratch.
pub struct ExplicitEuler {
    pub(super) passes: Passes,
}

impl ExplicitEuler {
    /// Sized for `model`.
    pub fn new(model: &Model) -> ExplicitEuler {
        ExplicitEuler {
            passes: Passes::new(model),
        }
    }

    /// One step, collision response included; returns the first particle that is not finite.
    pub fn step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        state: &mut State,
    ) -> Option<usize> {
        self.passes
            .euler_step(model, surfaces, state, |x, v, a, h| (x + h * v, v + h * a))
    }
}
