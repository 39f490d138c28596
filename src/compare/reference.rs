//! The reference of a study: RK4 on the CPU at a fine step, its positions recorded at every
//! frame time of every run (a whole reference step's state, or the cubic Hermite interpolant
//! between the two around the time).

use std::time::Instant;

use glam::DVec3;
use softbody_scene::{Instability, Scene, Solver, StepError};

use super::{PROGRESS_STEPS, StudyError};
use crate::Backend;
use crate::run::{self, ENERGY_GROWTH_BOUND};

/// A reference time within this fraction of a step of a whole step takes that step's state.
const WHOLE_STEP: f64 = 1e-9;
/// The frame times of a run of `scene`, computed exactly as [`run::run`] stamps its frames.
pub(super) fn frame_times(scene: &Scene) -> Vec<f64> {
    let sim = scene.simulation;
    (0..sim.frame_count())
        .map(|k| sim.frame_step(k) as f64 * sim.dt)
        .collect()
}

/// The reference's positions at the frame times (ascending, exact f64 keys).
pub(super) struct ReferenceStates {
    pub(super) times: Vec<f64>,
    pub(super) states: Vec<Vec<DVec3>>,
}

impl ReferenceStates {
    pub(super) fn at(&self, time: f64) -> Option<&[DVec3]> {
        self.times
            .binary_search_by(|t| t.total_cmp(&time))
            .ok()
            .map(|i| self.states[i].as_slice())
    }
}

/// Runs the reference scene and records its positions at each of `times` (ascending); returns
/// them with the steps taken and the wall time. `progress` hears the steps done.
pub(super) fn reference_states(
    scene: &Scene,
    threads: Option<usize>,
    times: &[f64],
    progress: &mut dyn FnMut(u64),
) -> Result<(Vec<Vec<DVec3>>, u64, f64), StudyError> {
    let started = Instant::now();
    let dt = scene.simulation.dt;
    let mut solver = crate::open(scene, Backend::Cpu, threads)?;
    let unstable = |instability| StudyError::ReferenceUnstable { dt, instability };
    let step_error = |e: StepError| match e {
        StepError::Unstable(i) => unstable(i),
        StepError::Device(d) | StepError::Invalid(d) => StudyError::Device(d),
    };
    let e0 = solver.energies().map_err(step_error)?;
    let scale = run::energy_scale(solver.as_mut(), &e0).map_err(step_error)?;

    // The states at the last two steps visited: an interpolation needs the steps on both sides
    // of a time, and the next time may need the upper one again as its lower one.
    type Snapshot = (u64, Vec<DVec3>, Vec<DVec3>);
    let mut recent: Vec<Snapshot> = Vec::with_capacity(2);
    let mut snapshot = |step: u64,
                        solver: &mut dyn Solver,
                        recent: &mut Vec<Snapshot>|
     -> Result<usize, StudyError> {
        if let Some(i) = recent.iter().position(|s| s.0 == step) {
            return Ok(i);
        }
        // Requests never go back further than the snapshots kept (the times ascend).
        while solver.steps_taken() < step {
            let n = (step - solver.steps_taken()).min(PROGRESS_STEPS);
            solver.advance(n).map_err(step_error)?;
            progress(solver.steps_taken());
        }
        // The energy guard of `run::run`, at the states the comparison uses.
        let e = solver.energies().map_err(step_error)?;
        if e.total() - e0.total() > ENERGY_GROWTH_BOUND * scale {
            // Named by its fastest particle, as `run::run` does.
            let (fastest, speed) = solver
                .state()
                .map_err(step_error)?
                .v
                .iter()
                .enumerate()
                .map(|(i, v)| (i, v.length()))
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or((0, 0.0));
            return Err(unstable(Instability {
                step,
                time: step as f64 * dt,
                particle: fastest as u32,
                what: format!(
                    "is the fastest ({speed:.3e} m/s) as the total energy reached {:.3e} J, more than \
                     {ENERGY_GROWTH_BOUND} energy scales ({scale:.3e} J each) above its initial {:.3e} J",
                    e.total(),
                    e0.total()
                ),
            }));
        }
        let state = solver.state().map_err(step_error)?;
        if recent.len() == 2 {
            recent.remove(0);
        }
        recent.push((step, state.x.clone(), state.v.clone()));
        Ok(recent.len() - 1)
    };

    let mut states = Vec::with_capacity(times.len());
    for &t in times {
        let s = t / dt;
        let whole = s.round();
        if (s - whole).abs() <= WHOLE_STEP * whole.max(1.0) {
            let i = snapshot(whole as u64, solver.as_mut(), &mut recent)?;
            states.push(recent[i].1.clone());
            continue;
        }
        let lower = s.floor() as u64;
        let theta = s - s.floor();
        // Two snapshot calls may shift `recent`: take the lower one's index after both.
        snapshot(lower, solver.as_mut(), &mut recent)?;
        let hi = snapshot(lower + 1, solver.as_mut(), &mut recent)?;
        // Always kept (the times ascend, so only these two are ever needed at once); an error
        // rather than a panic if that ever stopped being true.
        let lo = recent.iter().position(|r| r.0 == lower).ok_or_else(|| {
            StudyError::Device(format!("internal: reference step {lower} no longer kept"))
        })?;
        states.push(hermite(&recent[lo], &recent[hi], theta, dt));
    }
    Ok((
        states,
        solver.steps_taken(),
        started.elapsed().as_secs_f64(),
    ))
}

/// Cubic Hermite interpolation of positions between two consecutive steps `h` apart, at the
/// fraction `theta` of the step.
fn hermite(
    a: &(u64, Vec<DVec3>, Vec<DVec3>),
    b: &(u64, Vec<DVec3>, Vec<DVec3>),
    theta: f64,
    h: f64,
) -> Vec<DVec3> {
    let (t, t2, t3) = (theta, theta * theta, theta * theta * theta);
    let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
    let h10 = t3 - 2.0 * t2 + t;
    let h01 = -2.0 * t3 + 3.0 * t2;
    let h11 = t3 - t2;
    (0..a.1.len())
        .map(|i| h00 * a.1[i] + h10 * h * a.2[i] + h01 * b.1[i] + h11 * h * b.2[i])
        .collect()
}
