//! Symplectic (semi-implicit) Euler: v' = v + h a(x, v), x' = x + h v'.

use softbody_scene::{Model, State};
use softbody_terrain::Surface;

use super::Passes;

/// Symplectic Euler and its scratch.
pub struct SymplecticEuler {
    pub(super) passes: Passes,
}

impl SymplecticEuler {
    /// Sized for `model`.
    pub fn new(model: &Model) -> SymplecticEuler {
        SymplecticEuler {
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
            .euler_step(model, surfaces, state, |x, v, a, h| {
                let v_next = v + h * a;
                (x + h * v_next, v_next)
            })
    }
}
