//! [`CpuSolver`]: the model, its terrain surfaces, the integrator with its scratch, the state,
//! and the rayon pool that steps them.

use std::sync::Arc;

use glam::DVec3;

use softbody_scene::{
    Controls, Energies, History, Instability, Model, Solver, State, Statistics, StepError, Timings,
    solver::check_state_len,
};

use crate::body_contact::BodyContact;
use crate::integrators::Stepper;
use crate::{energy, vec_bytes};
use softbody_terrain::Surface;

/// The CPU backend.
///
/// Its timings ([`Statistics::timings`]) have the stages "fused passes" (the explicit
/// integrators: spring forces, forces, update, collision response and the finiteness check in
/// one sweep per stage), or "assemble", "contacts", "cg", "update" and "finiteness" (implicit
/// Euler), then "body contact" (scenes whose bodies touch), and "energies".
pub struct CpuSolver {
    model: Model,
    /// One query object per terrain shape.
    surfaces: Vec<Surface>,
    stepper: Stepper,
    /// The contact between bodies and the state at the start of the step it needs, for a model
    /// whose bodies can touch.
    body_contact: Option<(BodyContact, State)>,
    state: State,
    /// The control forces, while some are set.
    controls: Option<Controls>,
    pool: Arc<rayon::ThreadPool>,
    steps: u64,
    timings: Timings,
}

impl CpuSolver {
    /// A solver for `model` starting from `state`, on `threads` threads (all cores if `None`).
    ///
    /// Stepping by hand, here a free-falling particle (no springs, no terrain), whose symplectic
    /// Euler recurrence gives y_k = y₀ − g·h²·k(k+1)/2 exactly:
    ///
    /// ```
    /// use softbody_cpu::CpuSolver;
    /// use softbody_scene::{Model, Scene, Solver};
    /// let scene = Scene::from_toml(r#"
    ///     [simulation]
    ///     integrator = "symplectic-euler"
    ///     dt = 0.01
    ///     duration = 1.0
    ///     gravity = [0.0, -10.0, 0.0]
    ///     [[body]]
    ///     kind = "particles"
    ///     positions = [[0.0, 5.0, 0.0]]
    ///     masses = [1.0]
    /// "#, "fall.toml".as_ref())?;
    /// let (model, state) = Model::build(&scene);
    /// let mut solver = CpuSolver::new(model, state, Some(1))?;
    /// solver.advance(10)?;
    /// let y = solver.state()?.x[0].y;
    /// assert!((y - (5.0 - 10.0 * 0.01 * 0.01 * 55.0)).abs() < 1e-12);
    /// let e = solver.energies()?;
    /// assert!((e.kinetic - 0.5 * (10.0 * 0.1f64).powi(2)).abs() < 1e-9);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn new(
        model: Model,
        state: State,
        threads: Option<usize>,
    ) -> Result<CpuSolver, rayon::ThreadPoolBuildError> {
        let threads =
            threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?;
        Ok(CpuSolver::in_pool(model, state, Arc::new(pool)))
    }

    /// A solver for `model` starting from `state` that steps in `pool`, which other solvers may
    /// share (one pool for a batch of runs instead of one per run). The result does not depend
    /// on the pool's size.
    pub fn in_pool(model: Model, state: State, pool: Arc<rayon::ThreadPool>) -> CpuSolver {
        // The passes split the particles by the pool's thread count.
        let stepper = pool.install(|| Stepper::new(&model));
        let body_contact = model
            .contact
            .enabled()
            .then(|| (BodyContact::new(), state.clone()));
        CpuSolver {
            surfaces: model.terrain.iter().map(Surface::new).collect(),
            model,
            stepper,
            body_contact,
            state,
            controls: None,
            pool,
            steps: 0,
            timings: Timings::default(),
        }
    }

    /// Advances `steps` steps with `external` forces on the particles.
    fn advance_with(&mut self, steps: u64, external: Option<&[DVec3]>) -> Result<(), StepError> {
        let (model, surfaces, stepper, state, timings) = (
            &self.model,
            &self.surfaces[..],
            &mut self.stepper,
            &mut self.state,
            &mut self.timings,
        );
        let body_contact = &mut self.body_contact;
        let dt = model.simulation.dt;
        let done = &mut self.steps;
        self.pool.install(|| {
            for _ in 0..steps {
                if let Some((contact, start)) = body_contact.as_mut() {
                    start.clone_from(state);
                    timings.time("body contact", || contact.prepare(model, state));
                }
                let pairs = body_contact.as_ref().map(|(contact, _)| contact.partners());
                let mut bad = stepper.step(model, surfaces, (pairs, external), state, timings);
                if let (Some((contact, start)), None) = (body_contact.as_mut(), bad) {
                    bad = timings
                        .time("body contact", || contact.respond(model, start, state))
                        .map(|i| (i, crate::non_finite_what(state, i)));
                }
                *done += 1;
                if let Some((i, what)) = bad {
                    return Err(StepError::Unstable(Instability {
                        step: *done,
                        time: *done as f64 * dt,
                        particle: i as u32,
                        what: what.to_owned(),
                    }));
                }
            }
            Ok(())
        })
    }

    /// Implicit Euler's contacts with the terrain in the last step as its final solve held
    /// them, and the step's Δv = v' − v before the response between bodies (nothing for the
    /// explicit integrators, whose contact is not constrained).
    pub(crate) fn implicit_step(
        &self,
    ) -> (&[crate::integrators::implicit_euler::Candidate], &[DVec3]) {
        self.stepper.implicit_step()
    }

    /// The pool the solver steps in.
    pub fn pool(&self) -> &Arc<rayon::ThreadPool> {
        &self.pool
    }
}

impl Solver for CpuSolver {
    fn backend(&self) -> &'static str {
        "cpu"
    }

    fn device(&self) -> String {
        let threads = self.pool.current_num_threads();
        format!(
            "CPU, {threads} thread{}",
            if threads == 1 { "" } else { "s" }
        )
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn advance(&mut self, steps: u64) -> Result<(), StepError> {
        let end = self.steps + steps;
        let controls = self.controls.clone();
        while self.steps < end {
            // The steps up to the next frame's take one frame's forces.
            let (forces, until) = match controls.as_ref().and_then(|c| c.at(self.steps)) {
                Some((f, next)) => (controls.as_ref().map(|c| c.frame(f)), next.min(end)),
                None => (None, end),
            };
            self.advance_with(until - self.steps, forces)?;
        }
        Ok(())
    }

    fn sync(&mut self) -> Result<(), StepError> {
        Ok(())
    }

    fn steps_taken(&self) -> u64 {
        self.steps
    }

    fn state(&mut self) -> Result<&State, StepError> {
        Ok(&self.state)
    }

    fn set_state(&mut self, state: &State) -> Result<(), StepError> {
        check_state_len(&self.model, state)?;
        self.state.clone_from(state);
        Ok(())
    }

    fn set_controls(&mut self, controls: Option<Controls>) -> Result<(), StepError> {
        if let Some(c) = &controls {
            c.check(&self.model)?;
        }
        self.controls = controls;
        Ok(())
    }

    fn controls(&self) -> Option<&Controls> {
        self.controls.as_ref()
    }

    fn history(&mut self) -> Result<History, StepError> {
        Ok(self.stepper.history())
    }

    fn restore(&mut self, steps: u64, state: &State, history: &History) -> Result<(), StepError> {
        self.set_state(state)?;
        let (model, stepper) = (&self.model, &mut self.stepper);
        self.pool.install(|| stepper.restore(model, history))?;
        self.steps = steps;
        Ok(())
    }

    fn energies(&mut self) -> Result<Energies, StepError> {
        let (model, state, pool) = (&self.model, &self.state, &self.pool);
        Ok(self.timings.time("energies", || {
            pool.install(|| energy::energies(model, state))
        }))
    }

    fn statistics(&self) -> Statistics {
        Statistics {
            steps: self.steps,
            timings: self.timings.clone(),
            ..self.stepper.statistics()
        }
    }

    /// The state, the model's arrays ([`Model::memory_bytes`]: springs and adjacency only
    /// where something built them) and the integrator's scratch (terrain query structures
    /// and names excluded).
    fn memory_bytes(&self) -> u64 {
        let model = self.model.memory_bytes();
        let contact = self.body_contact.as_ref().map_or(0, |(c, start)| {
            c.memory_bytes() + vec_bytes(&start.x) + vec_bytes(&start.v)
        });
        vec_bytes(&self.state.x)
            + vec_bytes(&self.state.v)
            + model
            + self.stepper.memory_bytes()
            + contact
    }
}
