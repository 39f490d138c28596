//! Classic fourth-order Runge–Kutta on y = (x, v), y' = (v, a(x, v)):
//! k1 = y'(y), k2 = y'(y + h/2 k1), k3 = y'(y + h/2 k2), k4 = y'(y + h k3),
//! y ← y + h/6 (k1 + 2k2 + 2k3 + k4).
//!
//! The weighted sum is accumulated as the stages go. Each stage is one fused pass that reads
//! the stage state and writes the next one (the stage buffer and the passes' second state
//! buffer take turns) along with the running sums; the last writes the new state, collision
//! response and finiteness check included.

use glam::DVec3;
use softbody_scene::{Model, State};

use super::{Passes, Stage};
use crate::body_contact::PairForces;
use crate::forces::acceleration_with;
use crate::pipeline::pass;
use crate::vec_bytes;
use softbody_terrain::Surface;

/// RK4 and its scratch: the passes, the stage state and the running weighted sums.
pub struct Rk4 {
    passes: Passes,
    stage_x: Vec<DVec3>,
    stage_v: Vec<DVec3>,
    sum_x: Vec<DVec3>,
    sum_v: Vec<DVec3>,
}

impl Rk4 {
    /// Sized for `model`.
    pub fn new(model: &Model) -> Rk4 {
        let zeros = || vec![DVec3::ZERO; model.len()];
        Rk4 {
            passes: Passes::new(model),
            stage_x: zeros(),
            stage_v: zeros(),
            sum_x: zeros(),
            sum_v: zeros(),
        }
    }

    /// The fused passes it steps with.
    pub(crate) fn passes(&self) -> &Passes {
        &self.passes
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        self.passes.memory_bytes()
            + [&self.stage_x, &self.stage_v, &self.sum_x, &self.sum_v]
                .into_iter()
                .map(vec_bytes)
                .sum::<u64>()
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

        // k1 at y.
        pass(
            plan,
            kernel,
            model,
            (x, v),
            (
                &mut self.stage_x[..],
                &mut self.stage_v[..],
                &mut self.sum_x[..],
                &mut self.sum_v[..],
            ),
            |i, springs, (xs, vs, sum_x, sum_v)| {
                let f = springs + pairs.force(model, i, x, v);
                let a = acceleration_with(model, surfaces, i, x[i], v[i], f);
                *sum_x = v[i];
                *sum_v = a;
                *xs = x[i] + 0.5 * h * v[i];
                *vs = v[i] + 0.5 * h * a;
                true
            },
        );
        // k2 and k3 at y + h/2 k1 and y + h/2 k2; the next stage at y + h/2 k2 and y + h k3.
        for (weight, next) in [(2.0, 0.5 * h), (2.0, h)] {
            let (xs, vs) = (&self.stage_x[..], &self.stage_v[..]);
            pass(
                plan,
                kernel,
                model,
                (xs, vs),
                (
                    &mut next_x[..],
                    &mut next_v[..],
                    &mut self.sum_x[..],
                    &mut self.sum_v[..],
                ),
                |i, springs, (xn, vn, sum_x, sum_v)| {
                    let f = springs + pairs.force(model, i, xs, vs);
                    let a = acceleration_with(model, surfaces, i, xs[i], vs[i], f);
                    *sum_x += weight * vs[i];
                    *sum_v += weight * a;
                    *xn = x[i] + next * vs[i];
                    *vn = v[i] + next * a;
                    true
                },
            );
            std::mem::swap(&mut self.stage_x, next_x);
            std::mem::swap(&mut self.stage_v, next_v);
        }
        // k4 at y + h k3, and the new state.
        let (sum_x, sum_v) = (&self.sum_x[..], &self.sum_v[..]);
        let last = Stage {
            scene: (model, surfaces, pairs),
            input: (&self.stage_x[..], &self.stage_v[..]),
            start: (x, v),
            last: true,
            update: |i: usize, _, vs, a| {
                let sx = sum_x[i] + 1.0 * vs;
                let sv = sum_v[i] + 1.0 * a;
                (x[i] + h / 6.0 * sx, v[i] + h / 6.0 * sv)
            },
        };
        // Particle by particle: by rows, with its four arrays read by index, the stage was
        // slower (7.0–7.8 against 7.3–7.8 M particle-steps/s at 46³, one thread).
        let bad = last.pass((plan, kernel, None), (&mut next_x[..], &mut next_v[..]));
        self.passes.swap_into(state);
        bad
    }
}
