//! The gradient of a loss over a whole run, in memory that grows as √T.
//!
//! The forward pass steps the [`CpuSolver`] and keeps its state every S steps (⌈T/S⌉
//! checkpoints), each with the solver's history (implicit Euler's warm start and contact
//! flags; nothing for the explicit integrators). The backward pass takes the segments from the
//! last to the first: it restores the segment's checkpoint, recomputes its S states with the
//! same solver (the same bits: the segment's last state must equal the next checkpoint, or the
//! run is refused as [`AdjointError::Recompute`]), and sweeps the segment's steps back with
//! `StepAdjoint::step` or `ImplicitAdjoint::step`, adding each frame's loss cotangent as it
//! passes the frame. At most ⌈T/S⌉ checkpoints and S + 2 states are held at once, besides the
//! model and O(N) scratch. S = √(cT/s) for checkpoints of c states' bytes and s states' bytes
//! a recomputed step, which makes the peak 2√(csT) states: 2√T + 2 for the explicit
//! integrators (c = s = 1); implicit Euler's checkpoints also hold its warm start (three Δv,
//! and the positions and constraints its multigrid was computed for: c ≈ 3.6), and where
//! bodies can touch its recomputed steps their Δv (s = 1.5).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::DVec3;
use softbody_scene::{Controls, History, Integrator, Model, Solver, State, StepError};
use softbody_terrain::Surface;

use super::Gradient;
use super::implicit_euler::{ImplicitAdjoint, Recorded};
use super::integrators::StepAdjoint;
use crate::CpuSolver;
use crate::integrators::implicit_euler::Candidate;

/// A loss made of one term per frame, ℓ_f(x_f, v_f; m).
pub trait Loss {
    /// The term of frame `frame` (its state `state`), its cotangents added to `bar`. Frames
    /// come from the last to the first.
    fn frame(&mut self, frame: u64, state: &State, bar: FrameBar<'_>) -> f64;
}

/// Where a frame's loss term adds its cotangents.
#[derive(Debug)]
pub struct FrameBar<'a> {
    /// ∂ℓ/∂x per particle.
    pub x: &'a mut [DVec3],
    /// ∂ℓ/∂v per particle.
    pub v: &'a mut [DVec3],
    /// ∂ℓ/∂m per particle (a loss weighted by the masses).
    pub mass: &'a mut [f64],
}

/// Why a gradient could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum AdjointError {
    /// A step of the forward run failed (it went unstable).
    #[error(transparent)]
    Step(#[from] StepError),
    /// The rayon pool could not be built.
    #[error("cannot start the thread pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
    /// The caller asked the run to stop (Ctrl-C in Python).
    #[error("stopped")]
    Stopped,
    /// A recomputed segment did not end on the forward run's state: a defect, not an input.
    #[error(
        "the recomputation of steps {from}..{to} did not give the forward run's state (a defect of the solver's determinism)"
    )]
    Recompute {
        /// The segment's first step.
        from: u64,
        /// Its end.
        to: u64,
    },
}

/// A check of the forward pass at each frame: the frame's index and the solver at its step.
pub type FrameCheck<'a> = &'a mut dyn FnMut(u64, &mut dyn Solver) -> Result<(), StepError>;

/// How [`gradient`] runs besides the model, its start and the loss.
#[derive(Default)]
pub struct Options<'a> {
    /// Threads (all cores if `None`; the result's bits do not depend on it).
    pub threads: Option<usize>,
    /// External forces on the particles, frame by frame ([`softbody_scene::controls`]).
    pub controls: Option<&'a Controls>,
    /// When set, the run ends at the next segment ([`AdjointError::Stopped`]).
    pub stop: Option<&'a AtomicBool>,
    /// Called at every frame of the forward pass, frame 0 first; its error ends the run
    /// (`softbody::grad` passes `run`'s energy guard, so that what `run` calls unstable has
    /// no gradient).
    pub check: Option<FrameCheck<'a>>,
}

/// What [`gradient`] computed.
#[derive(Debug, Clone)]
pub struct Backward {
    /// The loss, Σ of the frames' terms (summed from the last frame to the first).
    pub loss: f64,
    /// ∂L/∂x₀ per particle.
    pub x0: Vec<DVec3>,
    /// ∂L/∂v₀ per particle.
    pub v0: Vec<DVec3>,
    /// The model's values' gradient.
    pub gradient: Gradient,
    /// ∂L/∂u of each control force, laid out as [`Controls::forces`] (empty without them).
    pub controls: Vec<DVec3>,
    /// Steps of the run.
    pub steps: u64,
    /// Steps between checkpoints, S.
    pub interval: u64,
    /// The most states held at once (checkpoints and a segment's recomputed states).
    pub peak_states: u64,
    /// The most bytes held at once: the states, the model, the solver's and the adjoint's
    /// scratch and the gradient.
    pub peak_memory_bytes: u64,
    /// Seconds of the forward pass.
    pub forward_seconds: f64,
    /// Seconds of the backward pass, recomputation included.
    pub backward_seconds: f64,
    /// Implicit Euler's steps in which a contact turned from sticking to slipping, whose
    /// friction direction (the sticking solve's tangential impulse) the transpose holds: the
    /// gradient there lacks that direction's derivative (docs/physics.md, "Kinks").
    pub turned_steps: u64,
}

/// The loss of the run of `model` from `start` over `model.simulation.steps()` steps and its
/// gradient, run as `options` say.
pub fn gradient(
    model: &Model,
    start: &State,
    loss: &mut (dyn Loss + Send),
    options: Options<'_>,
) -> Result<Backward, AdjointError> {
    let stopped = || options.stop.is_some_and(|s| s.load(Ordering::Relaxed));
    let sim = &model.simulation;
    let steps = sim.steps();
    let frames = sim.frame_count();
    let n = model.len();
    let frame_steps: Vec<u64> = (0..frames).map(|f| sim.frame_step(f)).collect();
    let mut frame_at = std::collections::BTreeMap::new();
    for (f, &k) in frame_steps.iter().enumerate() {
        frame_at.insert(k, f as u64);
    }
    let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
    let mut solver = CpuSolver::new(model.clone(), start.clone(), options.threads)?;
    solver.set_controls(options.controls.cloned())?;
    let state_bytes = 2 * crate::vec_bytes(&start.x);
    let implicit = sim.integrator == Integrator::ImplicitEuler;
    let clock = Instant::now();
    // Each checkpoint with what the solver's next step starts from besides the state
    // (implicit Euler's warm start and contact flags; nothing for the explicit integrators),
    // so that a segment's recomputation gives the forward's bits.
    let mut checkpoints: Vec<(State, History)> = vec![(start.clone(), solver.history()?)];
    let history_bytes = |h: &History| h.parts.iter().map(|(_, b)| b.len() as u64).sum::<u64>();
    let interval = checkpoint_interval(
        steps,
        (state_bytes + history_bytes(&checkpoints[0].1)) as f64 / state_bytes.max(1) as f64,
        match implicit && model.contact.enabled() {
            true => 1.5,
            false => 1.0,
        },
    );
    let mut check = options.check;
    if let Some(check) = check.as_mut() {
        check(0, &mut solver)?;
    }
    let mut done = 0;
    let mut next_frame = 1;
    while done < steps {
        if stopped() {
            return Err(AdjointError::Stopped);
        }
        let end = done + interval.min(steps - done);
        // Each frame's step within the segment is checked as it is reached.
        while let Some(check) = check.as_mut()
            && let Some(&at) = frame_steps.get(next_frame)
            && at <= end
        {
            solver.advance(at - done)?;
            done = at;
            check(next_frame as u64, &mut solver)?;
            next_frame += 1;
        }
        solver.advance(end - done)?;
        done = end;
        if done < steps {
            checkpoints.push((solver.state()?.clone(), solver.history()?));
        }
    }
    let last = solver.state()?.clone();
    let forward_seconds = clock.elapsed().as_secs_f64();
    let checkpoint_bytes = checkpoints
        .iter()
        .map(|(_, h)| history_bytes(h))
        .max()
        .unwrap_or(0)
        + state_bytes;

    let clock = Instant::now();
    let mut grad = Gradient::zeros(model);
    let mut controls_bar = vec![DVec3::ZERO; options.controls.map_or(0, |c| c.forces().len())];
    let mut transpose = match implicit {
        true => Transpose::Implicit(Box::new(ImplicitAdjoint::new(model))),
        false => Transpose::Explicit(Box::new(StepAdjoint::new(model))),
    };
    let (mut x_bar, mut v_bar) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
    let mut total = 0.0;
    if let Some(&f) = frame_at.get(&steps) {
        let bar = FrameBar {
            x: &mut x_bar,
            v: &mut v_bar,
            mass: &mut grad.mass,
        };
        total += loss.frame(f, &last, bar);
    }
    let mut segment: Vec<State> = Vec::with_capacity(interval as usize + 1);
    // What implicit Euler's transpose takes of each step of the segment besides its states.
    let mut held: Vec<Recorded> = Vec::new();
    let mut turned_steps = 0;
    let (mut peak_states, mut peak_bytes) = (0, 0);
    // In the solver's pool throughout: its steps and the transposes run there without a
    // hand-over between threads at every step.
    let pool = solver.pool().clone();
    pool.install(|| -> Result<(), AdjointError> {
        for (j, (checkpoint, history)) in checkpoints.iter().enumerate().rev() {
            if stopped() {
                return Err(AdjointError::Stopped);
            }
            let from = j as u64 * interval;
            let to = (from + interval).min(steps);
            solver.restore(from, checkpoint, history)?;
            segment.truncate(0);
            segment.push(checkpoint.clone());
            held.truncate(0);
            for _ in from..to {
                solver.advance(1)?;
                segment.push(solver.state()?.clone());
                if implicit {
                    let step = Recorded::of(&solver, model);
                    turned_steps += u64::from(step.contacts.iter().any(Candidate::held_direction));
                    held.push(step);
                }
            }
            let expected = checkpoints.get(j + 1).map_or(&last, |(state, _)| state);
            if !same_bits(segment.last().expect("the segment's start"), expected) {
                return Err(AdjointError::Recompute { from, to });
            }
            // Checkpoints, the last state and the segment.
            peak_states = peak_states.max(checkpoints.len() as u64 + 1 + segment.len() as u64);
            peak_bytes = peak_bytes.max(
                checkpoints.len() as u64 * checkpoint_bytes
                    + (1 + segment.len() as u64) * state_bytes
                    + held.iter().map(Recorded::memory_bytes).sum::<u64>(),
            );
            for k in (from..to).rev() {
                let i = (k - from) as usize;
                let bars = (&mut x_bar[..], &mut v_bar[..]);
                let external = options.controls.and_then(|c| {
                    let (f, _) = c.at(k)?;
                    Some((c.frame(f), &mut controls_bar[f * n..][..n]))
                });
                match &mut transpose {
                    Transpose::Explicit(t) => {
                        t.step(model, &surfaces, &segment[i], external, bars, &mut grad)
                    }
                    Transpose::Implicit(t) => t.step(
                        model,
                        (&segment[i], &segment[i + 1]),
                        (&surfaces, &held[i]),
                        external,
                        bars,
                        &mut grad,
                    ),
                }
                if let Some(&f) = frame_at.get(&k) {
                    let bar = FrameBar {
                        x: &mut x_bar,
                        v: &mut v_bar,
                        mass: &mut grad.mass,
                    };
                    total += loss.frame(f, &segment[i], bar);
                }
            }
        }
        Ok(())
    })?;
    let backward_seconds = clock.elapsed().as_secs_f64();
    let peak_memory_bytes = peak_bytes
        + model.memory_bytes()
        + solver.memory_bytes()
        + transpose.memory_bytes()
        + grad.memory_bytes()
        + crate::vec_bytes(&controls_bar)
        + 2 * crate::vec_bytes(&x_bar);
    Ok(Backward {
        loss: total,
        x0: x_bar,
        v0: v_bar,
        gradient: grad,
        controls: controls_bar,
        steps,
        interval,
        peak_states,
        peak_memory_bytes,
        forward_seconds,
        backward_seconds,
        turned_steps,
    })
}

/// Steps between checkpoints, S, for a run of `steps` steps whose checkpoints take `checkpoint`
/// states' bytes and whose recomputed segment `per_step` states' bytes a step: the peak
/// c T/S + s S is least at S = √(c T/s), where it is 2√(c s T) (2√T states for the explicit
/// integrators, whose checkpoints are states; implicit Euler's hold its warm start too).
fn checkpoint_interval(steps: u64, checkpoint: f64, per_step: f64) -> u64 {
    ((checkpoint * steps as f64 / per_step).sqrt().ceil() as u64).clamp(1, steps.max(1))
}

/// The transpose of a step of the run's integrator.
enum Transpose {
    Explicit(Box<StepAdjoint>),
    Implicit(Box<ImplicitAdjoint>),
}

impl Transpose {
    fn memory_bytes(&self) -> u64 {
        match self {
            Transpose::Explicit(t) => t.memory_bytes(),
            Transpose::Implicit(t) => t.memory_bytes(),
        }
    }
}

/// Whether two states are the same bits.
fn same_bits(a: &State, b: &State) -> bool {
    let same = |p: &[DVec3], q: &[DVec3]| {
        p.len() == q.len()
            && p.iter()
                .zip(q)
                .all(|(p, q)| p.to_array().map(f64::to_bits) == q.to_array().map(f64::to_bits))
    };
    same(&a.x, &b.x) && same(&a.v, &b.v)
}
