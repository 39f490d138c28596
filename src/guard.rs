//! The energy guard of a run (`run`, `grad`, `fit`): a run is unstable at the first frame whose
//! total energy exceeds its initial value, less the control forces' work, by more than
//! [`ENERGY_GROWTH_BOUND`] energy scales, or is not a finite number; the exact step is then
//! found by stepping again from the frame before.
//!
//! E − E₀ − W > B·E_s, with E_s = K₀ + E_el,₀ + M|g|(D + 1 m) (D: the diagonal of the initial
//! bounding box, M: the total mass) and W = Σ_f Σ_i u_{f,i}·(x_{f+1,i} − x_{f,i}) the work of
//! the controls u held over each frame (exact for a force held constant, whatever the path): no
//! scene of springs, dampers, drag and terrain can gain that much, so it can only be a diverging
//! integrator.

use glam::DVec3;
use softbody_scene::{Controls, Energies, History, Instability, Model, Solver, State, StepError};

use crate::run::RunError;

/// How many energy scales a run may gain before it is called unstable.
pub const ENERGY_GROWTH_BOUND: f64 = 10.0;

/// The energy scale E_s of the solver's current (initial) state.
pub fn energy_scale(solver: &mut dyn Solver, e0: &Energies) -> Result<f64, StepError> {
    let x = solver.state()?.x.clone();
    Ok(energy_scale_of(solver.model(), &x, e0))
}

/// The energy scale E_s of `model` at positions `x` with energies `e0`.
pub(crate) fn energy_scale_of(model: &Model, x: &[DVec3], e0: &Energies) -> f64 {
    let g = model.simulation.gravity.length();
    let mass: f64 = model.mass.iter().sum();
    let (lo, hi) = x
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    let diagonal = if x.is_empty() {
        0.0
    } else {
        (hi - lo).length()
    };
    e0.kinetic + e0.elastic + mass * g * (diagonal + 1.0)
}

/// The guard of one run, frame by frame.
#[derive(Debug, Clone)]
pub struct EnergyGuard {
    e0: Energies,
    scale: f64,
    controls: Option<Controls>,
    /// The controls' work up to the last frame.
    work: f64,
    /// The last frame's index, step, state and history: where an instability found at the
    /// next is looked for step by step.
    previous: Option<(u64, u64, State, History)>,
}

impl EnergyGuard {
    /// The guard of a run starting from the solver's current state (frame 0, not yet
    /// checked); [`RunError::Overflow`] if its energy is not finite.
    pub fn start(solver: &mut dyn Solver) -> Result<EnergyGuard, RunError> {
        let e0 = solver.energies()?;
        let scale = energy_scale(solver, &e0)?;
        EnergyGuard::resumed(solver, e0, scale)
    }

    /// The guard of a run whose initial energies were `e0` and energy scale `scale`.
    pub(crate) fn resumed(
        solver: &dyn Solver,
        e0: Energies,
        scale: f64,
    ) -> Result<EnergyGuard, RunError> {
        if !e0.total().is_finite() {
            return Err(RunError::Overflow(e0));
        }
        Ok(EnergyGuard {
            e0,
            scale,
            controls: solver.controls().cloned(),
            work: 0.0,
            previous: None,
        })
    }

    /// The initial energies.
    pub fn initial(&self) -> Energies {
        self.e0
    }

    /// The controls' work from the last frame to `x` at frame `k`, added to the work before.
    fn work_to(&self, k: u64, x: &[DVec3]) -> f64 {
        match (&self.controls, &self.previous) {
            (Some(c), Some((before, _, state, _))) if k == before + 1 => {
                self.work + c.work(*before as usize, &state.x, x)
            }
            _ => self.work,
        }
    }

    fn exceeds(&self, e: &Energies, work: f64) -> bool {
        !e.total().is_finite()
            || e.total() - self.e0.total() - work > ENERGY_GROWTH_BOUND * self.scale
    }

    /// A frame that was not stepped here (replayed from a journal): frame `k` at `step` in
    /// `state`, the solver's history then being `history`.
    pub(crate) fn passed(&mut self, k: u64, step: u64, state: State, history: History) {
        self.work = self.work_to(k, &state.x);
        self.previous = Some((k, step, state, history));
    }

    /// Checks the solver at frame `k`'s step: its energies, or the instability at the exact
    /// step it began (stepping again from the frame before).
    pub fn frame(&mut self, k: u64, solver: &mut dyn Solver) -> Result<Energies, RunError> {
        let energies = solver.energies()?;
        let state = solver.state()?.clone();
        if self.exceeds(&energies, self.work_to(k, &state.x)) {
            let mut energies = energies;
            if let Some((_, step, state, history)) = &self.previous {
                let target = solver.steps_taken();
                solver.restore(*step, state, history)?;
                loop {
                    solver.advance(1)?;
                    energies = solver.energies()?;
                    let x = &solver.state()?.x;
                    if self.exceeds(&energies, self.work_to(k, x)) || solver.steps_taken() >= target
                    {
                        break;
                    }
                }
            }
            return Err(RunError::Unstable(self.instability(solver, &energies)?));
        }
        let history = solver.history()?;
        self.passed(k, solver.steps_taken(), state, history);
        Ok(energies)
    }

    /// The state of the last frame checked.
    pub fn last_state(&self) -> Option<&State> {
        self.previous.as_ref().map(|(_, _, state, _)| state)
    }

    /// The instability of a solver whose energies exceed the guard (or overflowed) at its
    /// current step.
    fn instability(
        &self,
        solver: &mut dyn Solver,
        energies: &Energies,
    ) -> Result<Instability, StepError> {
        let step = solver.steps_taken();
        let time = step as f64 * solver.model().simulation.dt;
        let (fastest, speed) = solver
            .state()?
            .v
            .iter()
            .enumerate()
            .map(|(i, v)| (i, v.length()))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        let what = if energies.total().is_finite() {
            format!(
                "is the fastest ({speed:.3e} m/s) as the total energy reached {:.3e} J, more \
                 than {ENERGY_GROWTH_BOUND} energy scales ({:.3e} J each) above its initial \
                 {:.3e} J",
                energies.total(),
                self.scale,
                self.e0.total()
            )
        } else {
            format!(
                "is the fastest ({speed:.3e} m/s) as the energy overflowed (kinetic {} J, \
                 gravitational {} J, elastic {} J)",
                energies.kinetic, energies.gravitational, energies.elastic
            )
        };
        Ok(Instability {
            step,
            time,
            particle: fastest as u32,
            what,
        })
    }
}
