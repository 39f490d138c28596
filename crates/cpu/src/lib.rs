//! The CPU reference solver of `softbody`: f64 throughout, parallel with rayon, and the same bits
//! for any thread count.
//!
//! The pipeline of one step reads top to bottom:
//! [`spring_forces`] (one force per spring, gathered per particle) → [`forces`] (gravity, drag,
//! springs, then [`contact`] and friction against each terrain [`Surface`]) → an
//! [`integrators`] step → [`collision_response`] (explicit family) → a finiteness check.
//! Implicit Euler replaces the last four with a linearised backward-Euler solve that treats
//! contacts as velocity constraints.
//!
//! ```
//! use softbody_cpu::CpuSolver;
//! use softbody_scene::{Model, Scene, Solver};
//! let scene = Scene::from_toml(r#"
//!     [simulation]
//!     integrator = "rk4"
//!     dt = 0.001
//!     duration = 0.1
//!     [[body]]
//!     kind = "particles"
//!     positions = [[0.0, 1.0, 0.0]]
//!     masses = [1.0]
//! "#, "inline.toml".as_ref()).unwrap();
//! let (model, state) = Model::build(&scene);
//! let mut solver = CpuSolver::new(model, state, Some(1)).unwrap();
//! solver.advance(100).unwrap();
//! let y = solver.state().unwrap().x[0].y;
//! assert!((y - (1.0 - 0.5 * 9.81 * 0.1 * 0.1)).abs() < 1e-12); // RK4 is exact for free fall
//! ```
#![warn(missing_docs)]

pub mod collision_response;
pub mod contact;
pub mod energy;
pub mod forces;
pub mod integrators;
mod pipeline;
pub mod reduce;
pub mod spring_forces;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{
    Energies, Instability, Integrator, Model, Solver, State, Statistics, StepError,
};
use softbody_terrain::Surface;

pub use rayon::ThreadPoolBuildError;

/// The model, its terrain surfaces, and the scratch a step needs (allocated once).
pub struct Workspace {
    /// The model being stepped.
    pub model: Model,
    /// One query object per terrain shape.
    pub surfaces: Vec<Surface>,
    /// The spring pass, set up for the model.
    kernel: spring_forces::Kernel,
    /// How the fused passes split the particles among threads, and their scratch.
    plan: pipeline::Plan,
    /// The explicit integrators' second state buffer: a pass writes the next state there, and
    /// the buffers are swapped.
    next_x: Vec<DVec3>,
    next_v: Vec<DVec3>,
    /// Stage state of the multi-stage methods.
    stage_x: Vec<DVec3>,
    stage_v: Vec<DVec3>,
    /// RK4's running weighted sums.
    sum_x: Vec<DVec3>,
    sum_v: Vec<DVec3>,
    /// Implicit Euler's solver state.
    implicit: Option<integrators::implicit_euler::Implicit>,
}

impl Workspace {
    /// Builds the terrain surfaces and sizes the scratch for the model's integrator.
    pub fn new(model: Model) -> Workspace {
        let n = model.len();
        let surfaces = model.terrain.iter().map(Surface::new).collect();
        let zeros = |len: usize| vec![DVec3::ZERO; len];
        let integrator = model.simulation.integrator;
        let multi_stage = matches!(integrator, Integrator::Midpoint | Integrator::Rk4);
        let rk4 = integrator == Integrator::Rk4;
        let implicit = (integrator == Integrator::ImplicitEuler)
            .then(|| integrators::implicit_euler::Implicit::new(&model));
        let explicit = implicit.is_none();

        Workspace {
            next_x: zeros(if explicit { n } else { 0 }),
            next_v: zeros(if explicit { n } else { 0 }),
            // Implicit Euler has no use for the explicit passes' plan.
            plan: if explicit {
                pipeline::Plan::new(&model)
            } else {
                pipeline::Plan::empty()
            },
            stage_x: zeros(if multi_stage { n } else { 0 }),
            stage_v: zeros(if multi_stage { n } else { 0 }),
            sum_x: zeros(if rk4 { n } else { 0 }),
            sum_v: zeros(if rk4 { n } else { 0 }),
            implicit,
            surfaces,
            kernel: spring_forces::Kernel::new(&model.springs),
            model,
        }
    }

    /// Bytes held on the heap: the model's particle, spring and adjacency arrays, and every
    /// scratch buffer (terrain query structures and names excluded).
    pub fn memory_bytes(&self) -> u64 {
        let m = &self.model;
        let s = &m.springs;
        let model = vec_bytes(&m.mass)
            + vec_bytes(&m.inv_mass)
            + vec_bytes(&s.a)
            + vec_bytes(&s.b)
            + vec_bytes(&s.rest)
            + vec_bytes(&s.stiffness)
            + vec_bytes(&s.damping)
            + vec_bytes(&m.adjacency.offsets)
            + vec_bytes(&m.adjacency.entries);
        let scratch = [
            &self.next_x,
            &self.next_v,
            &self.stage_x,
            &self.stage_v,
            &self.sum_x,
            &self.sum_v,
        ]
        .into_iter()
        .map(vec_bytes)
        .sum::<u64>();
        model
            + scratch
            + self.plan.memory_bytes()
            + self.implicit.as_ref().map_or(0, |i| i.memory_bytes())
    }

    /// Advances `state` by one step of the model's integrator.
    pub fn step(&mut self, state: &mut State) {
        self.step_checked(state);
    }

    /// Advances `state` by one step and returns the first particle with a non-finite position
    /// or velocity afterwards ([`first_non_finite`]), found within the step's last pass.
    pub fn step_checked(&mut self, state: &mut State) -> Option<(usize, &'static str)> {
        if self.implicit.is_none() && !self.plan.fits() {
            // Stepped from another thread pool than the one the workspace was made in.
            self.plan = pipeline::Plan::new(&self.model);
        }
        let bad = match self.model.simulation.integrator {
            Integrator::ExplicitEuler => integrators::explicit_euler::step(self, state),
            Integrator::SymplecticEuler => integrators::symplectic_euler::step(self, state),
            Integrator::Midpoint => integrators::midpoint::step(self, state),
            Integrator::Rk4 => integrators::rk4::step(self, state),
            Integrator::ImplicitEuler => {
                let mut implicit = self
                    .implicit
                    .take()
                    .expect("sized for implicit-euler in Workspace::new");
                implicit.step(&self.model, &self.surfaces, state);
                self.implicit = Some(implicit);
                return first_non_finite(state);
            }
        };
        bad.map(|i| (i, non_finite_what(state, i)))
    }
}

/// Bytes a vector holds on the heap.
pub(crate) fn vec_bytes<T>(v: &Vec<T>) -> u64 {
    (v.capacity() * std::mem::size_of::<T>()) as u64
}

/// The first particle with a non-finite position or velocity, and which it is.
pub fn first_non_finite(state: &State) -> Option<(usize, &'static str)> {
    let i = state
        .x
        .par_iter()
        .zip(state.v.par_iter())
        .with_min_len(forces::PARTICLE_CHUNK)
        .position_first(|(x, v)| !x.is_finite() || !v.is_finite())?;
    Some((i, non_finite_what(state, i)))
}

fn non_finite_what(state: &State, i: usize) -> &'static str {
    if state.x[i].is_finite() {
        "has a non-finite velocity"
    } else {
        "has a non-finite position"
    }
}

/// The CPU backend: a [`Workspace`], the state, and a rayon pool of a fixed size.
pub struct CpuSolver {
    ws: Workspace,
    state: State,
    pool: rayon::ThreadPool,
    threads: usize,
    steps: u64,
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
        let ws = pool.install(|| Workspace::new(model));
        Ok(CpuSolver {
            ws,
            state,
            pool,
            threads,
            steps: 0,
        })
    }

    /// Bytes the solver holds on the heap: the state, the model's particle, spring and
    /// adjacency arrays, and the integrator's scratch (terrain query structures excluded).
    pub fn memory_bytes(&self) -> u64 {
        vec_bytes(&self.state.x) + vec_bytes(&self.state.v) + self.ws.memory_bytes()
    }
}

impl Solver for CpuSolver {
    fn backend(&self) -> &'static str {
        "cpu"
    }

    fn device(&self) -> String {
        format!(
            "CPU, {} thread{}",
            self.threads,
            if self.threads == 1 { "" } else { "s" }
        )
    }

    fn model(&self) -> &Model {
        &self.ws.model
    }

    fn advance(&mut self, steps: u64) -> Result<(), StepError> {
        let (ws, state) = (&mut self.ws, &mut self.state);
        let dt = ws.model.simulation.dt;
        let done = &mut self.steps;
        self.pool.install(|| {
            for _ in 0..steps {
                let bad = ws.step_checked(state);
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

    fn steps_taken(&self) -> u64 {
        self.steps
    }

    fn state(&mut self) -> Result<&State, StepError> {
        Ok(&self.state)
    }

    fn energies(&mut self) -> Result<Energies, StepError> {
        let (model, state) = (&self.ws.model, &self.state);
        Ok(self.pool.install(|| energy::energies(model, state)))
    }

    fn statistics(&self) -> Statistics {
        let mut s = self
            .ws
            .implicit
            .as_ref()
            .map(|i| i.statistics)
            .unwrap_or_default();
        s.steps = self.steps;
        s
    }
}
