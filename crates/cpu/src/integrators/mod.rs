//! Time integrators. Each advances the state by one step h = dt; the explicit family
//! (explicit Euler, symplectic Euler, midpoint, RK4) evaluates accelerations (gravity, drag,
//! springs, [`crate::contact`]) and ends with [`crate::collision_response`]; implicit Euler
//! handles contact inside its solve.
//!
//! Each integrator is a type owning its scratch, one module each; [`Stepper`] holds the one a
//! run uses. Adding an integrator is a module here, a variant of [`Stepper`], and its WGSL twin
//! on the GPU (see ARCHITECTURE.md, "Add an integrator").
//!
//! Each explicit stage is one fused `pipeline::pass`: spring forces at the stage's (x, v),
//! then per particle its acceleration and the stage update, written to other arrays than the
//! ones read ([`Passes`] double-buffers the state). The last stage also applies the collision
//! response and checks finiteness (`finish`). Updates have no reductions, so any split gives
//! the same bits.

pub mod explicit_euler;
pub mod implicit_euler;
pub mod midpoint;
pub mod rk4;
pub mod symplectic_euler;

use glam::DVec3;
use softbody_scene::{History, Integrator, Model, State, Statistics, StepError, Timings};
use softbody_terrain::Surface;

use crate::body_contact::{NoPairs, PairForces, Partners};
use crate::collision_response::respond_one;
use crate::forces::acceleration_with;
use crate::pipeline::{Plan, RouteKind, pass};
use crate::spring_forces::Kernel;
use crate::vec_bytes;

/// The integrator of a run with its scratch.
pub enum Stepper {
    /// [`explicit_euler`]: its scratch is the passes'.
    ExplicitEuler(Passes),
    /// [`symplectic_euler`]: its scratch is the passes'.
    SymplecticEuler(Passes),
    /// [`midpoint`].
    Midpoint(midpoint::Midpoint),
    /// [`rk4`].
    Rk4(rk4::Rk4),
    /// [`implicit_euler`].
    ImplicitEuler(Box<implicit_euler::ImplicitEuler>),
}

/// The stage the explicit integrators' fused passes are timed as.
pub const EXPLICIT_STAGE: &str = "fused passes";

impl Stepper {
    /// The model's integrator, sized for it. Call it in the thread pool that will step it: the
    /// passes split the particles by its thread count.
    pub fn new(model: &Model) -> Stepper {
        match model.simulation.integrator {
            Integrator::ExplicitEuler => Stepper::ExplicitEuler(Passes::new(model)),
            Integrator::SymplecticEuler => Stepper::SymplecticEuler(Passes::new(model)),
            Integrator::Midpoint => Stepper::Midpoint(midpoint::Midpoint::new(model)),
            Integrator::Rk4 => Stepper::Rk4(rk4::Rk4::new(model)),
            Integrator::ImplicitEuler => {
                Stepper::ImplicitEuler(Box::new(implicit_euler::ImplicitEuler::new(model)))
            }
        }
    }

    /// Advances `state` by one step, timing its stages into `timings`, and returns the first
    /// particle with a non-finite position or velocity afterwards, and which it is.
    pub fn step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        pairs: Option<&Partners>,
        state: &mut State,
        timings: &mut Timings,
    ) -> Option<(usize, &'static str)> {
        // Each integrator once without forces between particles and once with them.
        macro_rules! with_pairs {
            (|$q:ident| $body:expr) => {
                match pairs {
                    None => {
                        let $q = &NoPairs;
                        $body
                    }
                    Some($q) => $body,
                }
            };
        }
        let explicit = |timings: &mut Timings, step: &mut dyn FnMut() -> Option<usize>| {
            timings.time(EXPLICIT_STAGE, step)
        };
        let bad = match self {
            Stepper::ExplicitEuler(p) => explicit(timings, &mut || {
                with_pairs!(|q| explicit_euler::step(p, model, surfaces, q, state))
            }),
            Stepper::SymplecticEuler(p) => explicit(timings, &mut || {
                with_pairs!(|q| symplectic_euler::step(p, model, surfaces, q, state))
            }),
            Stepper::Midpoint(s) => explicit(timings, &mut || {
                with_pairs!(|q| s.step(model, surfaces, q, state))
            }),
            Stepper::Rk4(s) => explicit(timings, &mut || {
                with_pairs!(|q| s.step(model, surfaces, q, state))
            }),
            Stepper::ImplicitEuler(s) => {
                s.step(model, surfaces, pairs, state, timings);
                return timings.time("finiteness", || crate::first_non_finite(state));
            }
        };
        bad.map(|i| (i, crate::non_finite_what(state, i)))
    }

    /// Bytes of scratch held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        match self {
            Stepper::ExplicitEuler(p) | Stepper::SymplecticEuler(p) => p.memory_bytes(),
            Stepper::Midpoint(s) => s.memory_bytes(),
            Stepper::Rk4(s) => s.memory_bytes(),
            Stepper::ImplicitEuler(s) => s.memory_bytes(),
        }
    }

    /// What the next step starts from besides the state (nothing for the explicit
    /// integrators).
    pub fn history(&self) -> History {
        match self {
            Stepper::ImplicitEuler(s) => s.history(),
            _ => History::default(),
        }
    }

    /// Takes up [`Stepper::history`]'s.
    pub fn restore(&mut self, history: &History) -> Result<(), StepError> {
        match self {
            Stepper::ImplicitEuler(s) => s.restore(history),
            _ if history.parts.is_empty() => Ok(()),
            _ => Err(StepError::Invalid(
                "restore: the history is an implicit integrator's, this solver's integrator is \
                 explicit"
                    .to_owned(),
            )),
        }
    }

    /// The integrator's own counters (implicit Euler's CG iterations and solves; zero for the
    /// others).
    pub fn statistics(&self) -> Statistics {
        let kernel = |p: &Passes| p.plan.kernel_name();
        match self {
            Stepper::ImplicitEuler(s) => Statistics {
                kernel: "matrix-free",
                ..s.statistics.clone()
            },
            Stepper::ExplicitEuler(p) | Stepper::SymplecticEuler(p) => Statistics {
                kernel: kernel(p),
                ..Statistics::default()
            },
            Stepper::Midpoint(s) => Statistics {
                kernel: kernel(s.passes()),
                ..Statistics::default()
            },
            Stepper::Rk4(s) => Statistics {
                kernel: kernel(s.passes()),
                ..Statistics::default()
            },
        }
    }
}

/// What every explicit integrator holds: the fused passes' plan for the model and the second
/// state buffer a pass writes the next state into (the buffers are then swapped).
pub struct Passes {
    plan: Plan,
    kernel: Kernel,
    next_x: Vec<DVec3>,
    next_v: Vec<DVec3>,
}

impl Passes {
    /// Sized and planned for `model`, in the current thread pool.
    pub(crate) fn new(model: &Model) -> Passes {
        let n = model.len();
        let plan = Plan::new(model);
        // The stencil reads each offset's parameters from the lattice, the others the list.
        let kernel = match plan.route() {
            RouteKind::Stencil => Kernel::per_spring(),
            _ => Kernel::new(model.springs()),
        };
        Passes {
            plan,
            kernel,
            next_x: vec![DVec3::ZERO; n],
            next_v: vec![DVec3::ZERO; n],
        }
    }

    /// Bytes held on the heap.
    pub(crate) fn memory_bytes(&self) -> u64 {
        self.plan.memory_bytes() + vec_bytes(&self.next_x) + vec_bytes(&self.next_v)
    }

    /// One step of a single-stage Euler method in one fused pass: spring forces, then per
    /// particle the gathered forces, gravity, drag and contact, `update(x, v, a, h) -> (x', v')`,
    /// the collision response and the finiteness check. Returns the first particle that is not
    /// finite.
    pub(crate) fn euler_step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        pairs: &impl PairForces,
        state: &mut State,
        update: impl Fn(DVec3, DVec3, DVec3, f64) -> (DVec3, DVec3) + Sync,
    ) -> Option<usize> {
        let h = model.simulation.dt;
        let (x, v) = (&state.x[..], &state.v[..]);
        let bad = pass(
            &mut self.plan,
            self.kernel,
            model,
            x,
            v,
            (&mut self.next_x[..], &mut self.next_v[..]),
            // Inlined into the pass's block loop: a call per particle costs more than the
            // update.
            #[inline(always)]
            |i, springs, (xn, vn)| {
                let f = springs + pairs.force(model, i, x, v);
                let a = acceleration_with(model, surfaces, i, x[i], v[i], f);
                (*xn, *vn) = update(x[i], v[i], a, h);
                finish(model, surfaces, i, (x[i], v[i]), xn, vn)
            },
        );
        self.swap_into(state);
        bad
    }

    /// The plan, the kernel and the second state buffer, apart: the stages of a multi-stage
    /// method run their own passes (RK4 alternates the buffer with its stage buffer).
    pub(crate) fn parts(&mut self) -> (&mut Plan, Kernel, &mut Vec<DVec3>, &mut Vec<DVec3>) {
        (
            &mut self.plan,
            self.kernel,
            &mut self.next_x,
            &mut self.next_v,
        )
    }

    /// Makes the second state buffer the state.
    pub(crate) fn swap_into(&mut self, state: &mut State) {
        std::mem::swap(&mut state.x, &mut self.next_x);
        std::mem::swap(&mut state.v, &mut self.next_v);
    }
}

/// The end of an explicit step for particle i, which started it at `x_start`: its collision
/// response (unless it is pinned), then whether its position and velocity are finite.
#[inline(always)]
pub(crate) fn finish(
    model: &Model,
    surfaces: &[Surface],
    i: usize,
    start: (DVec3, DVec3),
    x: &mut DVec3,
    v: &mut DVec3,
) -> bool {
    let eps = model.simulation.contact_distance;
    // Clear of every surface (and with none): the response would change nothing.
    if !surfaces.iter().all(|s| s.clear_of(*x, eps)) && model.inv_mass[i] != 0.0 {
        respond_one(surfaces, eps, model.simulation.dt, start, x, v);
    }
    all_finite(*x, *v)
}

/// `x.is_finite() && v.is_finite()` in a few instructions: c − c is +0 for a finite c and NaN
/// for an infinite or NaN one, so the six differences sum to 0 exactly when all are finite.
#[inline(always)]
#[allow(clippy::eq_op, reason = "c − c is the test")]
fn all_finite(x: DVec3, v: DVec3) -> bool {
    let d = (x - x) + (v - v);
    d.x + d.y + d.z == 0.0
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::all_finite;

    #[test]
    fn all_finite_is_is_finite() {
        let values = [
            0.0,
            -0.0,
            1.5,
            -f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for &a in &values {
            for &b in &values {
                for k in 0..6 {
                    let mut c = [1.0; 6];
                    c[k] = a;
                    c[(k + 1) % 6] = b;
                    let (x, v) = (DVec3::new(c[0], c[1], c[2]), DVec3::new(c[3], c[4], c[5]));
                    assert_eq!(all_finite(x, v), x.is_finite() && v.is_finite(), "{x} {v}");
                }
            }
        }
    }
}
