//! The midpoint method (RK2) on y = (x, v), y' = (v, a(x, v)):
//! y_m = y + (h/2) y'(y), then y ← y + h y'(y_m).
//!
//! Two fused passes: the first writes y_m, the second the new state (collision response and
//! finiteness check included).

use glam::DVec3;
use softbody_scene::{Model, State};

use super::{Passes, finish};
use crate::body_contact::PairForces;
use crate::forces::acceleration_with;
use crate::pipeline::pass;
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
        let (plan, kernel, next_x, next_v) = self.passes.parts();
        let (x, v) = (&state.x[..], &state.v[..]);
        pass(
            plan,
            kernel,
            model,
            (x, v),
            (&mut self.mid_x[..], &mut self.mid_v[..]),
            |i, springs, (xm, vm)| {
                let f = springs + pairs.force(model, i, x, v);
                let a = acceleration_with(model, surfaces, i, x[i], v[i], f);
                *xm = x[i] + 0.5 * h * v[i];
                *vm = v[i] + 0.5 * h * a;
                true
            },
        );
        let (xm, vm) = (&self.mid_x[..], &self.mid_v[..]);
        let bad = pass(
            plan,
            kernel,
            model,
            (xm, vm),
            (&mut next_x[..], &mut next_v[..]),
            |i, springs, (xn, vn)| {
                let f = springs + pairs.force(model, i, xm, vm);
                let a = acceleration_with(model, surfaces, i, xm[i], vm[i], f);
                *xn = x[i] + h * vm[i];
                *vn = v[i] + h * a;
                finish(model, surfaces, i, (x[i], v[i]), xn, vn)
            },
        );
        self.passes.swap_into(state);
        bad
    }
}
