//! The gradient of a loss over a whole run, in memory that grows as √T.
//!
//! The forward pass steps the [`CpuSolver`] and keeps its state every S = ⌈√T⌉ steps (⌈T/S⌉
//! checkpoints). The backward pass takes the segments from the last to the first: it restores
//! the segment's checkpoint, recomputes its S states with the same solver (the same bits: the
//! segment's last state must equal the next checkpoint, or the run is refused as
//! [`AdjointError::Recompute`]), and sweeps the segment's steps back with
//! [`StepAdjoint::step`], adding each frame's loss cotangent as it passes the frame. At most
//! ⌈T/S⌉ + S + 1 ≤ 2√T + 2 states are held at once, besides the model and O(N) scratch.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::DVec3;
use softbody_scene::{Integrator, Model, Solver, State, StepError, TerrainShape};
use softbody_terrain::Surface;

use super::Gradient;
use super::integrators::StepAdjoint;
use crate::CpuSolver;

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
    /// The scene holds something without an adjoint yet.
    #[error("{0}")]
    Unsupported(String),
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
}

/// Refuses a model whose run has no adjoint yet, saying what it holds.
pub fn check_differentiable(model: &Model) -> Result<(), AdjointError> {
    if model.simulation.integrator == Integrator::ImplicitEuler {
        return Err(AdjointError::Unsupported(
            "gradients of implicit-euler runs are not built yet; the explicit integrators \
             (explicit-euler, symplectic-euler, midpoint, rk4) have them"
                .into(),
        ));
    }
    if model.contact.enabled() {
        return Err(AdjointError::Unsupported(
            "gradients through contact between bodies are not built yet; this scene's bodies \
             can touch (several bodies with contact radii, or self_contact)"
                .into(),
        ));
    }
    if let Some((k, t)) = model
        .terrain
        .iter()
        .enumerate()
        .find(|(_, t)| !Surface::new(t).is_differentiable())
    {
        let kind = match t.shape {
            TerrainShape::Box { .. } => "box",
            TerrainShape::Heightfield(_) => "heightfield",
            _ => "mesh",
        };
        return Err(AdjointError::Unsupported(format!(
            "terrain[{k}] is a {kind}: gradients through its contact are not built yet (plane, \
             sphere and bowl have them)"
        )));
    }
    Ok(())
}

/// The loss of the run of `model` from `start` over `model.simulation.steps()` steps and its
/// gradient, on `threads` threads (all cores if `None`; the result's bits do not depend on it).
/// `stop`, when set, ends it at the next segment ([`AdjointError::Stopped`]).
pub fn gradient(
    model: &Model,
    start: &State,
    threads: Option<usize>,
    loss: &mut (dyn Loss + Send),
    stop: Option<&AtomicBool>,
) -> Result<Backward, AdjointError> {
    let stopped = || stop.is_some_and(|s| s.load(Ordering::Relaxed));
    check_differentiable(model)?;
    let sim = &model.simulation;
    let steps = sim.steps();
    let interval = ((steps as f64).sqrt().ceil() as u64).max(1);
    let frames = sim.frame_count();
    let mut frame_at = std::collections::BTreeMap::new();
    for f in 0..frames {
        frame_at.insert(sim.frame_step(f), f);
    }
    let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
    let mut solver = CpuSolver::new(model.clone(), start.clone(), threads)?;
    let state_bytes = 2 * crate::vec_bytes(&start.x);

    let clock = Instant::now();
    let mut checkpoints = vec![start.clone()];
    let mut done = 0;
    while done < steps {
        if stopped() {
            return Err(AdjointError::Stopped);
        }
        let n = interval.min(steps - done);
        solver.advance(n)?;
        done += n;
        if done < steps {
            checkpoints.push(solver.state()?.clone());
        }
    }
    let last = solver.state()?.clone();
    let forward_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let n = model.len();
    let mut grad = Gradient::zeros(model);
    let mut adjoint = StepAdjoint::new(model);
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
    let mut peak_states = 0;
    // In the solver's pool throughout: its steps and the transposes run there without a
    // hand-over between threads at every step.
    let pool = solver.pool().clone();
    pool.install(|| -> Result<(), AdjointError> {
        for (j, checkpoint) in checkpoints.iter().enumerate().rev() {
            if stopped() {
                return Err(AdjointError::Stopped);
            }
            let from = j as u64 * interval;
            let to = (from + interval).min(steps);
            solver.set_state(checkpoint)?;
            segment.truncate(0);
            segment.push(checkpoint.clone());
            for _ in from..to {
                solver.advance(1)?;
                segment.push(solver.state()?.clone());
            }
            let expected = checkpoints.get(j + 1).unwrap_or(&last);
            if !same_bits(segment.last().expect("the segment's start"), expected) {
                return Err(AdjointError::Recompute { from, to });
            }
            // Checkpoints (the last state among them) and the segment.
            peak_states = peak_states.max(checkpoints.len() as u64 + 1 + segment.len() as u64);
            for k in (from..to).rev() {
                let state = &segment[(k - from) as usize];
                adjoint.step(model, &surfaces, state, (&mut x_bar, &mut v_bar), &mut grad);
                if let Some(&f) = frame_at.get(&k) {
                    let bar = FrameBar {
                        x: &mut x_bar,
                        v: &mut v_bar,
                        mass: &mut grad.mass,
                    };
                    total += loss.frame(f, state, bar);
                }
            }
        }
        Ok(())
    })?;
    let backward_seconds = clock.elapsed().as_secs_f64();
    let peak_memory_bytes = peak_states * state_bytes
        + model.memory_bytes()
        + solver.memory_bytes()
        + adjoint.memory_bytes()
        + grad.memory_bytes()
        + 2 * crate::vec_bytes(&x_bar);
    Ok(Backward {
        loss: total,
        x0: x_bar,
        v0: v_bar,
        gradient: grad,
        steps,
        interval,
        peak_states,
        peak_memory_bytes,
        forward_seconds,
        backward_seconds,
    })
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
