//! The standard benchmark cube, as `../shared/peers/mass_spring_peer.py` defines it, so that
//! `softbody` and its peers (Warp, Taichi, NumPy) time the same problem.
//!
//! n³ particles on a unit grid (spacing 1/(n−1)) whose bottom face starts at y = 0.5, total
//! mass 1, structural, shear and bending springs with k_s = 2000 and k_d = 5, gravity, a ground
//! plane y = 0 with restitution 0.5 and no friction.
//!
//! [`measure`] times one size of it the way `softbody bench` reports it: build, warm up, then
//! the stepping alone.

use std::time::Instant;

use glam::DVec3;
use softbody_scene::{
    Body, BodyContact, BodyShape, Cuboid, FrictionModel, Integrator, Preconditioner, Scene,
    Simulation, Solver, SpringParams, StepError, Terrain, TerrainShape,
};

use crate::{Backend, OpenError};

/// Spring stiffness of the benchmark cube, N/m.
pub const STIFFNESS: f64 = 2000.0;
/// Spring damping of the benchmark cube, N·s/m.
pub const DAMPING: f64 = 5.0;
/// Bound on the largest eigenvalue of the lattice's unit spring operator (the peer script's
/// `MU_MAX`, measured there with an eigensolver).
const MU_MAX: f64 = 18.0;

/// Largest stable symplectic-Euler step of the linearised n³ cube (the peer's
/// `dt_max_symplectic`): the stiffest mode λ = k_s μ n³, c = 2 k_d μ n³ is stable iff
/// h²λ + hc ≤ 4.
pub fn dt_max_symplectic(n: u32) -> f64 {
    dt_max_symplectic_with(n, STIFFNESS)
}

/// [`dt_max_symplectic`] for springs of stiffness `stiffness` (and the cube's damping).
pub fn dt_max_symplectic_with(n: u32, stiffness: f64) -> f64 {
    let n3 = (n as f64).powi(3);
    let a = stiffness * MU_MAX * n3;
    let b = 2.0 * DAMPING * MU_MAX * n3;
    (-b + (b * b + 16.0 * a).sqrt()) / (2.0 * a)
}

/// The benchmark cube of n³ particles with `stiffness` on every spring, stepped by
/// `integrator` at `dt`.
pub fn cube(n: u32, stiffness: f64, integrator: Integrator, dt: f64) -> Scene {
    let springs = Some(SpringParams {
        stiffness,
        damping: DAMPING,
    });
    Scene {
        simulation: Simulation {
            integrator,
            dt,
            duration: 1.0,
            frame_rate: 1.0 / dt.max(1.0 / 30.0),
            gravity: DVec3::new(0.0, -9.81, 0.0),
            drag: 0.0,
            contact_distance: 0.0,
            body_contact: Default::default(),
            preconditioner: Default::default(),
            cg_tolerance: softbody_scene::implicit::CG_TOLERANCE,
        },
        bodies: vec![jelly(
            "cube".into(),
            (DVec3::ONE, n),
            (DVec3::new(0.5, 1.0, 0.5), DVec3::ZERO),
            1.0,
            springs,
        )],
        terrain: vec![Terrain {
            shape: TerrainShape::Plane {
                point: DVec3::ZERO,
                normal: DVec3::Y,
            },
            restitution: 0.5,
            friction: 0.0,
            friction_model: FrictionModel::Coulomb,
        }],
    }
}

/// A cuboid body at rest of n³ particles, `(size, n)`, placed at `(center, rotation)`, with
/// `springs` on all three families.
fn jelly(
    name: String,
    (size, n): (DVec3, u32),
    (center, rotation): (DVec3, DVec3),
    mass: f64,
    springs: Option<SpringParams>,
) -> Body {
    Body {
        name,
        shape: BodyShape::Cuboid(Cuboid {
            size,
            resolution: [n; 3],
            center,
            rotation,
            velocity: DVec3::ZERO,
            mass,
            structural: springs,
            shear: springs,
            bending: springs,
        }),
        pinned: Vec::new(),
        contact_radius: None,
        self_contact: false,
    }
}

/// The multi-body benchmark: 27 jelly cubes of n³ particles (20 cm, 8 kg, k_s = 2000 N/m) in
/// a 3×3×3 block with 2 cm gaps, the lowest layer 2 cm above a bowl of radius 1 m, touching
/// each other (body restitution 0.2, friction 0.4), stepped by symplectic Euler at half the
/// stable estimate of `softbody check`. The bench times its steps once the cubes have landed on
/// each other.
pub fn pile(n: u32) -> Scene {
    let springs = Some(SpringParams {
        stiffness: STIFFNESS,
        damping: DAMPING,
    });
    let mut bodies = Vec::new();
    for k in 0..27 {
        let (i, j, l) = (k % 3, k / 3 % 3, k / 9);
        let at = |c: u32| 0.22 * (f64::from(c) - 1.0);
        bodies.push(jelly(
            format!("cube{k}"),
            (DVec3::splat(0.2), n),
            (
                DVec3::new(at(i), 0.22 + 0.22 * f64::from(l), at(j)),
                DVec3::new(5.0 * f64::from(i), 7.0 * f64::from(j), 3.0 * f64::from(l)),
            ),
            8.0,
            springs,
        ));
    }
    let mut scene = Scene {
        simulation: Simulation {
            integrator: Integrator::SymplecticEuler,
            dt: 1e-4,
            duration: 1.0,
            frame_rate: 30.0,
            gravity: DVec3::new(0.0, -9.81, 0.0),
            drag: 0.0,
            contact_distance: 1e-3,
            body_contact: BodyContact {
                restitution: 0.2,
                friction: 0.4,
                friction_model: FrictionModel::Coulomb,
            },
            preconditioner: Default::default(),
            cg_tolerance: softbody_scene::implicit::CG_TOLERANCE,
        },
        bodies,
        terrain: vec![Terrain {
            shape: TerrainShape::Bowl {
                center: DVec3::new(0.0, 1.0, 0.0),
                radius: 1.0,
            },
            restitution: 0.2,
            friction: 0.4,
            friction_model: FrictionModel::Coulomb,
        }],
    };
    let (model, _) = softbody_scene::Model::build(&scene);
    if let Some(limit) = model.stable_dt() {
        scene.simulation.dt = 0.5 * limit;
        scene.simulation.frame_rate = 30.0f64.min(1.0 / scene.simulation.dt);
    }
    scene
}

/// How [`measure`] runs one size.
#[derive(Debug, Clone)]
pub struct Options {
    /// Which solver.
    pub backend: Backend,
    /// The integrator stepping the cube.
    pub integrator: Integrator,
    /// CPU threads (all cores when `None`); the GPU ignores it.
    pub threads: Option<usize>,
    /// Timed steps; `None` picks about [`TARGET_PARTICLE_STEPS`] particle-steps, or
    /// [`MIN_SECONDS`] of stepping where that is more, capped at [`MAX_SECONDS`].
    pub steps: Option<u64>,
    /// Steps before timing; `None` warms up by time (one step, then pilots of about a quarter
    /// of a second until two agree). A fixed count, with a fixed `steps`, times the same
    /// stretch of the cube's motion in every run: implicit Euler's cost per step depends on
    /// it (a falling cube's solves take more iterations than a resting one's), so runs that
    /// are compared need the same stretch. `Some(0)` times from the first step; then, with
    /// `steps` `None`, there is no time per step to bound the count by, and the timed steps
    /// are about [`TARGET_PARTICLE_STEPS`] particle-steps (at least [`MIN_STEPS`]).
    pub warmup_steps: Option<u64>,
    /// Spring stiffness k_s, N/m.
    pub stiffness: f64,
    /// Time step; `None` is half [`dt_max_symplectic_with`] for the size and stiffness.
    pub dt: Option<f64>,
    /// Whether the cube touches itself (`self_contact`, its default contact radius): what
    /// contact between particles costs when nothing is in contact but everything is checked.
    pub self_contact: bool,
    /// Implicit Euler's CG preconditioner (the CPU's; the GPU always runs block Jacobi).
    pub preconditioner: Preconditioner,
    /// How the GPU finds each particle's springs (the GPU's only).
    pub gpu_route: GpuRoute,
}

/// How the GPU solver finds each particle's springs, so that its designs can be timed side by
/// side on one adapter (the figure reports which one ran: [`Measurement::kernel`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GpuRoute {
    /// What the solver takes by itself: for the explicit integrators the fused stencil on
    /// lattice bodies (the benchmark cube), for implicit Euler the fused product through the
    /// spring list.
    #[default]
    Auto,
    /// The fused step through the spring list and the adjacency, as for bodies that are not
    /// lattices (implicit Euler takes the spring list under [`GpuRoute::Auto`] too).
    Gather,
    /// The explicit integrators' forces per spring into a buffer, then gathered per particle
    /// (five dispatches a symplectic step instead of one); implicit Euler's product in two
    /// passes.
    PerSpring,
}

impl GpuRoute {
    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            GpuRoute::Auto => "auto",
            GpuRoute::Gather => "gather",
            GpuRoute::PerSpring => "per-spring",
        }
    }
}

impl std::str::FromStr for GpuRoute {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [GpuRoute::Auto, GpuRoute::Gather, GpuRoute::PerSpring]
            .into_iter()
            .find(|r| r.name() == s)
            .ok_or_else(|| format!("unknown GPU route `{s}`; expected auto, gather or per-spring"))
    }
}

impl Default for Options {
    fn default() -> Self {
        Options {
            backend: Backend::Cpu,
            integrator: Integrator::SymplecticEuler,
            threads: None,
            steps: None,
            warmup_steps: None,
            stiffness: STIFFNESS,
            dt: None,
            self_contact: false,
            preconditioner: Preconditioner::default(),
            gpu_route: GpuRoute::Auto,
        }
    }
}

/// Particle-steps a size is timed for by default (as the peer script's step counts).
pub const TARGET_PARTICLE_STEPS: f64 = 1e7;
/// Shortest the timed stepping of one size runs by default, seconds: a fast GPU does the
/// target's particle-steps of a large cube in a few milliseconds, too short to time against
/// the launch and the final synchronisation.
pub const MIN_SECONDS: f64 = 1.0;
/// Longest the timed stepping of one size runs by default, seconds.
pub const MAX_SECONDS: f64 = 20.0;
/// Fewest timed steps by default.
pub const MIN_STEPS: u64 = 3;
/// The warm-up after the first step runs for about this long, seconds (at least one step).
const PILOT_SECONDS: f64 = 0.25;
/// The longest pilot run, steps.
const MAX_PILOT: u64 = 100_000;
/// Pilot runs at most.
const MAX_PILOT_RUNS: u32 = 8;
/// Two pilots agree when their times per step differ by at most this fraction.
const PILOT_AGREEMENT: f64 = 0.1;
/// Shortest batch of timed steps between two progress reports, seconds.
const PROGRESS_SECONDS: f64 = 0.1;

/// What one size measured.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// Particles per edge.
    pub n: u32,
    /// Particles, n³.
    pub particles: u64,
    /// Springs.
    pub springs: u64,
    /// Time step, seconds.
    pub dt: f64,
    /// Steps taken before timing (first step and pilot).
    pub warmup_steps: u64,
    /// Timed steps.
    pub steps: u64,
    /// Wall-clock seconds of the timed steps (GPU: until the queue is done).
    pub seconds: f64,
    /// What the solver holds per particle ([`Solver::memory_bytes`]: state, masses, springs,
    /// adjacency, integrator scratch; device buffers on the GPU).
    pub bytes_per_particle: f64,
    /// Implicit Euler: conjugate-gradient iterations per timed step.
    pub cg_iterations_per_step: Option<f64>,
    /// Implicit Euler: CG solves per timed step (more than one when contacts change).
    pub cg_solves_per_step: Option<f64>,
    /// Implicit Euler: the preconditioner that ran (block Jacobi where the backend reports
    /// none: the GPU).
    pub preconditioner: Option<Preconditioner>,
    /// The GPU design's figures over the timed steps (`None` on the CPU).
    pub design: Option<Design>,
    /// What ran it (thread count, adapter).
    pub device: String,
    /// The spring kernel that ran ([`softbody_scene::Statistics::kernel`]).
    pub kernel: &'static str,
}

/// What a GPU solver's design costs per step, counted as it encodes (so the same on any
/// adapter): [`softbody_scene::Statistics::dispatches`] and
/// [`device_bytes`](softbody_scene::Statistics::device_bytes) over the timed steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Design {
    /// Compute dispatches per step.
    pub dispatches_per_step: f64,
    /// Bytes of device memory traffic per particle and step, by the design's count.
    pub bytes_per_particle_step: f64,
}

impl Measurement {
    /// Particle-steps per second.
    pub fn particle_steps_per_s(&self) -> f64 {
        self.particles as f64 * self.steps as f64 / self.seconds
    }

    /// Spring-steps per second.
    pub fn spring_steps_per_s(&self) -> f64 {
        self.springs as f64 * self.steps as f64 / self.seconds
    }

    /// Nanoseconds per particle-step.
    pub fn ns_per_particle_step(&self) -> f64 {
        1e9 / self.particle_steps_per_s()
    }

    /// One JSON object: `particles`, `springs`, `steps`, `seconds`, `particle_steps_per_s`,
    /// `spring_steps_per_s`, `bytes_per_particle`, `kernel`, and
    /// `cg_iterations_per_step`, `cg_solves_per_step` and `preconditioner` for implicit Euler,
    /// `gpu_route` on the GPU, plus what was run (`n`, `backend`,
    /// `device`, `integrator`, `dt`, `stiffness`, `warmup_steps`).
    pub fn to_json(&self, options: &Options) -> serde_json::Value {
        let mut v = serde_json::json!({
            "n": self.n,
            "backend": options.backend.name(),
            "device": self.device,
            "integrator": options.integrator.name(),
            "stiffness": options.stiffness,
            "self_contact": options.self_contact,
            "dt": self.dt,
            "particles": self.particles,
            "springs": self.springs,
            "warmup_steps": self.warmup_steps,
            "steps": self.steps,
            "seconds": self.seconds,
            "particle_steps_per_s": self.particle_steps_per_s(),
            "spring_steps_per_s": self.spring_steps_per_s(),
            "bytes_per_particle": self.bytes_per_particle,
            "kernel": self.kernel,
        });
        if options.backend == Backend::Gpu {
            v["gpu_route"] = options.gpu_route.name().into();
        }
        if let Some(design) = &self.design {
            v["dispatches_per_step"] = design.dispatches_per_step.into();
            v["bytes_per_particle_step"] = design.bytes_per_particle_step.into();
        }
        if let Some(cg) = self.cg_iterations_per_step {
            v["cg_iterations_per_step"] = cg.into();
            v["cg_solves_per_step"] = self.cg_solves_per_step.into();
            v["preconditioner"] = self.preconditioner.map(Preconditioner::name).into();
        }
        v
    }
}

/// Why a size could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The cube is not a valid scene (a size below 2, a stiffness or step that is not positive).
    #[error("{n}³ cube: {key}: {message}")]
    Invalid {
        /// Particles per edge.
        n: u32,
        /// The scene key at fault.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// The solver could not be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// A step failed: non-finite values, or a GPU device failure.
    #[error("{n}³ cube: {source}")]
    Step {
        /// Particles per edge.
        n: u32,
        /// What happened.
        source: StepError,
    },
    /// The final state holds a value that is not finite (checked after the timed steps).
    #[error("{n}³ cube: the final state is not finite")]
    NotFinite {
        /// Particles per edge.
        n: u32,
    },
}

/// Builds the n³ benchmark cube for `options`, warms the solver up (one step, then runs of
/// about a quarter of a second until two agree on the time per step; or
/// [`Options::warmup_steps`] steps), times
/// `options.steps` steps (by default about [`TARGET_PARTICLE_STEPS`] particle-steps and at
/// least [`MIN_SECONDS`], at most [`MAX_SECONDS`]) with nothing else in the loop, and checks
/// that the final state is finite.
/// Timings end when the solver has computed every step ([`Solver::sync`]: on the GPU, when
/// the queue is done).
/// `progress` hears (timed steps done, timed steps in all) about a hundred times.
pub fn measure(
    n: u32,
    options: &Options,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Measurement, BenchError> {
    let dt = options
        .dt
        .unwrap_or_else(|| 0.5 * dt_max_symplectic_with(n, options.stiffness));
    let mut scene = cube(n, options.stiffness, options.integrator, dt);
    scene.bodies[0].self_contact = options.self_contact;
    scene.simulation.preconditioner = options.preconditioner;
    scene.validate().map_err(|e| BenchError::Invalid {
        n,
        key: e.key.to_string(),
        message: e.message.to_string(),
    })?;
    let mut solver = match (options.backend, options.gpu_route) {
        (Backend::Gpu, route @ (GpuRoute::Gather | GpuRoute::PerSpring)) => {
            use softbody_gpu::{Gpu, GpuOptions, GpuSolver};
            let (model, state) = softbody_scene::Model::build(&scene);
            let gpu_options = GpuOptions {
                gather: route == GpuRoute::Gather,
                per_spring: route == GpuRoute::PerSpring,
                ..GpuOptions::default()
            };
            let gpu = Gpu::open().map_err(OpenError::from)?;
            let solver = GpuSolver::with_options(&gpu, model, state, gpu_options);
            Box::new(solver.map_err(OpenError::from)?)
        }
        _ => crate::open(&scene, options.backend, options.threads)?,
    };
    time(solver.as_mut(), n, dt, options, progress)
}

/// The warm-up by time: the first step pays for what happens once (pipelines, first touches
/// of memory); then pilots of about PILOT_SECONDS run until one that lasts at least half of
/// that agrees with the one before on the time per step: neither the first steps nor a GPU's
/// clocks, still rising from idle after a long setup, set the step count (on an H200, a 300³
/// cube's first pilots ran at a third of its rate). Returns the steps taken and the last
/// pilot's seconds per step.
fn warm_up(
    solver: &mut dyn Solver,
    run: &dyn Fn(&mut dyn Solver, u64) -> Result<f64, BenchError>,
) -> Result<(u64, Option<f64>), BenchError> {
    let mut pilot = ((PILOT_SECONDS / run(solver, 1)?.max(1e-9)) as u64).clamp(1, MAX_PILOT);
    let mut warmup_steps = 1;
    let mut previous: Option<f64> = None;
    let mut runs = 0;
    loop {
        let seconds = run(solver, pilot)?;
        warmup_steps += pilot;
        runs += 1;
        let per_step = seconds / pilot as f64;
        let long = seconds >= 0.5 * PILOT_SECONDS || pilot == MAX_PILOT;
        let agrees = previous.is_some_and(|p| (per_step - p).abs() <= PILOT_AGREEMENT * p);
        if (long && agrees) || runs == MAX_PILOT_RUNS {
            return Ok((warmup_steps, Some(per_step)));
        }
        previous = Some(per_step);
        pilot = ((PILOT_SECONDS / per_step.max(1e-12)) as u64).clamp(1, MAX_PILOT);
    }
}

/// The warm-up of exactly `steps` steps: the first alone (it pays for what happens once),
/// then the rest, whose seconds per step are the estimate (the first's where it is the only
/// one; none for no steps).
fn warm_up_for(
    solver: &mut dyn Solver,
    steps: u64,
    run: &dyn Fn(&mut dyn Solver, u64) -> Result<f64, BenchError>,
) -> Result<(u64, Option<f64>), BenchError> {
    if steps == 0 {
        return Ok((0, None));
    }
    let first = run(solver, 1)?;
    if steps == 1 {
        return Ok((1, Some(first)));
    }
    let rest = run(solver, steps - 1)?;
    Ok((steps, Some(rest / (steps - 1) as f64)))
}

/// The warm-up and the timed steps of [`measure`].
fn time(
    solver: &mut dyn Solver,
    n: u32,
    dt: f64,
    options: &Options,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Measurement, BenchError> {
    let model = solver.model();
    let (particles, springs) = (model.len() as u64, model.spring_count() as u64);
    let step_error = |source| BenchError::Step { n, source };
    let run = |solver: &mut dyn Solver, steps: u64| -> Result<f64, BenchError> {
        let started = Instant::now();
        solver.advance(steps).map_err(step_error)?;
        solver.sync().map_err(step_error)?;
        Ok(started.elapsed().as_secs_f64())
    };
    let (warmup_steps, per_step) = match options.warmup_steps {
        Some(w) => warm_up_for(solver, w, &run)?,
        None => warm_up(solver, &run)?,
    };
    let steps = options.steps.unwrap_or_else(|| {
        let target = (TARGET_PARTICLE_STEPS / particles as f64).ceil() as u64;
        let Some(per_step) = per_step else {
            return target.max(MIN_STEPS);
        };
        let per_step = per_step.max(1e-12);
        let target = target.max((MIN_SECONDS / per_step).ceil() as u64);
        let cap = (MAX_SECONDS / per_step) as u64;
        target.min(cap).max(MIN_STEPS)
    });
    let before = solver.statistics();
    // In about a hundred batches at most, for the progress report, and of PROGRESS_SECONDS at
    // least where the warm-up timed a step: each `advance` ends the GPU's submission, which
    // must not be a few steps long.
    let least = per_step.map_or(0, |t| (PROGRESS_SECONDS / t.max(1e-12)) as u64);
    let batch = steps.div_ceil(100).max(least);
    let started = Instant::now();
    let mut done = 0;
    while done < steps {
        let k = batch.min(steps - done);
        solver.advance(k).map_err(step_error)?;
        done += k;
        progress(done, steps);
    }
    solver.sync().map_err(step_error)?;
    let seconds = started.elapsed().as_secs_f64();
    let after = solver.statistics();
    let state = solver.state().map_err(step_error)?;
    if !state.x.iter().chain(&state.v).all(|p| p.is_finite()) {
        return Err(BenchError::NotFinite { n });
    }
    let implicit = options.integrator == Integrator::ImplicitEuler;
    let per_step = |count: u64| (count as f64) / (steps as f64);
    Ok(Measurement {
        n,
        particles,
        springs,
        dt,
        warmup_steps,
        steps,
        seconds,
        bytes_per_particle: solver.memory_bytes() as f64 / particles as f64,
        cg_iterations_per_step: implicit
            .then(|| per_step(after.cg_iterations - before.cg_iterations)),
        cg_solves_per_step: implicit.then(|| per_step(after.cg_solves - before.cg_solves)),
        preconditioner: implicit
            .then(|| after.preconditioner.unwrap_or(Preconditioner::BlockJacobi)),
        design: (after.dispatches > before.dispatches).then(|| Design {
            dispatches_per_step: per_step(after.dispatches - before.dispatches),
            bytes_per_particle_step: per_step(after.device_bytes - before.device_bytes)
                / particles as f64,
        }),
        device: solver.device(),
        kernel: after.kernel,
    })
}
