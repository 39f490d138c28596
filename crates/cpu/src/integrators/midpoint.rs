//! The midpoint method (RK2) on y = (x, v), y' = (v, a(x, v)):
//! y_m = y + (h/2) y'(y), then y ← y + h y'(y_m).
//!
//! Two fused passes: the first writes y_m, the second the new state (collision response and
//! finiteness check included).

use glam::DVec3;
use softbody_scene::{Model, State};

use super::{Passes, Stage};
use crate::body_contact::PairForces;
use crate::vec_bytes;
use softbody_terrain::Surface;

/// The midpoint method and its scratch: the passes and the midpoint state y_m.
pub struct Midpoint {
    passes: Passes,
    mid_x: Vec<DVec3>,
    mid_v: Vec<DVec3>,
}

impl Midpoint {
    /// Sized for `model`.
    pub fn new(model: &Model) -> Midpoint {
        let n = model.len();
        Midpoint {
            passes: Passes::new(model),
            mid_x: vec![DVec3::ZERO; n],
            mid_v: vec![DVec3::ZERO; n],
        }
    }

    /// The fused passes it steps with.
    pub(crate) fn passes(&self) -> &Passes {
        &self.passes
    }

    /// The same, to change (for tests of the row updates).
    #[cfg(test)]
    pub(crate) fn passes_mut(&mut self) -> &mut Passes {
        &mut self.passes
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        self.passes.memory_bytes() + vec_bytes(&self.mid_x) + vec_bytes(&self.mid_v)
    }

    /// One step, collision response included; returns the first particle that is not finite.
    pub fn step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        pairs: &impl PairForces,
        state: &mut State,
    ) -> Option<usize> {
        let h = model.simulation.dt;
        let rows = self.passes.rows;
        let (plan, kernel, next_x, next_v) = self.passes.parts();
        let (x, v) = (&state.x[..], &state.v[..]);
        let half = Stage {
            scene: (model, surfaces, pairs),
            input: (x, v),
            start: (x, v),
            last: false,
            update: |_, x, v, a| (x + 0.5 * h * v, v + 0.5 * h * a),
        };
        half.pass(
            (plan, kernel, rows),
            (&mut self.mid_x[..], &mut self.mid_v[..]),
        );
        let (xm, vm) = (&self.mid_x[..], &self.mid_v[..]);
        let whole = Stage {
            scene: (model, surfaces, pairs),
            input: (xm, vm),
            start: (x, v),
            last: true,
            update: |i: usize, _, vm, a| (x[i] + h * vm, v[i] + h * a),
        };
        let bad = whole.pass((plan, kernel, rows), (&mut next_x[..], &mut next_v[..]));
        self.passes.swap_into(state);
        bad
    }
}
