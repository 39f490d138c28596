//! The integrator study: one scene run with several integrators and time steps, each measured
//! against a converged reference.
//!
//! A [`Study`] names the scene, the integrators, the time steps (the scene's own by default), the
//! backend and the CPU threads; [`Study::run`] returns a [`Report`] with the [`Reference`] and one
//! [`RunReport`] per integrator × dt, each with its per-frame time series ([`Sample`]s) for plots.
//!
//! # The reference
//!
//! RK4 on the CPU (always f64, whatever the study's backend: an f32 reference would put every
//! error on a floor of f32 round-off) at `dt_ref = min(dts) / refinement` (16 by default). Its own
//! error is estimated by running RK4 once more at twice that step, `2·dt_ref`, and measuring that
//! run against the reference exactly as the study's runs are: the largest difference is
//! [`Reference::error_estimate`]. It bounds the reference's error from above (for a smooth
//! fourth-order problem the reference's error is about 1/15 of it; contacts make the motion
//! non-smooth, and the difference is then the honest figure).
//!
//! Whether the reference is converged, and so whether each run's error measures anything, is
//! judged in `convergence.rs`: a run is [`Standing::Comparable`] when stable, against a converged
//! reference, with an error of at least [`RESOLVED`] times the reference's bound.
//!
//! # Comparing at frame times
//!
//! Frame k of a run is taken at step round(k / (frame_rate·dt)), time step·dt, so frames fall at
//! the same times for every dt only when dt divides the frame interval. Each run is therefore
//! compared at its own frame times: the reference records its positions at every frame time of
//! every run. A time that is a whole number of reference steps (to 1e-9 of a step) takes that
//! step's state; any other is interpolated between the two reference steps around it with the
//! cubic Hermite interpolant of their positions and velocities, whose error
//! O(dt_ref⁴·|x⁗|) is of the order of RK4's own (across a contact's velocity jump it is
//! O(dt_ref·Δv) instead, still far below the errors of the runs being studied).
//!
//! # What a run reports
//!
//! - wall time and steps/s of the stepping (the per-frame comparison is timed apart and left
//!   out);
//! - whether it became unstable, and at which step and time: a non-finite state
//!   ([`StepError::Unstable`]) or the energy guard of [`run`](crate::run::run) (total energy more
//!   than [`ENERGY_GROWTH_BOUND`](run::ENERGY_GROWTH_BOUND) energy scales above the
//!   start). An unstable run is a result: its figures cover the frames before it;
//! - the largest position error, max over frames and particles of |x − x_ref|, and its time;
//! - the energy drift max |E − E₀| / E_s over the frames, with E_s the energy scale of the
//!   instability guard ([`energy_scale`](crate::run::energy_scale): K₀ + E_el,₀ + M|g|(D + 1 m)).
//!   E_s, not E₀, because the gravitational energy's zero is wherever the scene's origin is, so
//!   E₀ may be zero or negative; for a scene without gravity E_s = E₀. The drift measures an
//!   integrator's energy error only in undamped scenes: damping, drag, friction and inelastic
//!   contacts remove energy on purpose;
//! - the deepest penetration: the smallest signed distance φ of any particle to any terrain shape
//!   ([`Surface::query`](crate::terrain::Surface::query)) at the frames, negative inside the
//!   solid (None without terrain). The explicit integrators project particles back onto the
//!   surface after every step, so theirs is ≈ 0 unless a particle is pinned inside or pushed into
//!   a second shape; implicit Euler treats contacts as velocity constraints and may end slightly
//!   inside;
//! - whether the body came to rest: the largest particle speed at the last frame below
//!   [`Study::rest_speed`] (1 cm/s by default); the final speed and kinetic energy are reported
//!   too, for other thresholds.
//!
//! Memory: the reference's positions at every frame time of every dt are kept, frames × dts ×
//! particles × 24 bytes (91 frames, 2 dts and 216 particles: under 1 MB).
//!
//! ```
//! use softbody::compare::Study;
//! use softbody::{Integrator, Scene};
//! let scene = Scene::from_toml(r#"
//!     [simulation]
//!     integrator = "rk4"
//!     dt = 0.01
//!     duration = 0.5
//!     gravity = [0.0, 0.0, 0.0]
//!     [[body]]
//!     kind = "particles"
//!     positions = [[0.0, 0.0, 0.0], [1.1, 0.0, 0.0]]
//!     masses = [1.0, 1.0]
//!     springs = [{ a = 0, b = 1, stiffness = 50.0, damping = 0.0, rest = 1.0 }]
//! "#, "inline.toml".as_ref()).unwrap();
//! let mut study = Study::new(scene);
//! study.integrators = vec![Integrator::ExplicitEuler, Integrator::Rk4];
//! study.threads = Some(1);
//! let report = study.run(&mut |_, _| {}).unwrap();
//! assert_eq!(report.runs.len(), 2);
//! // RK4 is far closer to the reference than explicit Euler.
//! assert!(report.runs[1].max_error < 1e-3 * report.runs[0].max_error);
//! ```

use std::time::{Duration, Instant};

use softbody_scene::{Instability, Integrator, Scene, Solver, StepError};
use softbody_terrain::Surface;

use crate::output::{Frame, FrameSink, Header};
use crate::run::{self, RunError};
use crate::{Backend, OpenError};

mod convergence;
mod reference;
mod report;

use convergence::{Evidence, standing, suggested_refinement, unconverged};
pub use convergence::{RESOLVED, SIZE_FRACTION, Standing};
use reference::{ReferenceStates, frame_times, reference_states};

/// The reference's default refinement: dt_ref = min(dts) / 16.
pub const REFINEMENT: u32 = 16;

/// The default rest threshold: the largest particle speed at the last frame, m/s.
pub const REST_SPEED: f64 = 0.01;

/// Steps advanced between progress reports at most, for the reference.
const PROGRESS_STEPS: u64 = 256;

/// What to compare.
#[derive(Debug, Clone)]
pub struct Study {
    /// The scene; its integrator and dt are replaced by each run's.
    pub scene: Scene,
    /// The integrators, in report order.
    pub integrators: Vec<Integrator>,
    /// Time steps, seconds, each > 0; empty: the scene's dt.
    pub dts: Vec<f64>,
    /// Backend of the study's runs (the reference always runs on the CPU).
    pub backend: Backend,
    /// CPU threads (all cores when `None`).
    pub threads: Option<usize>,
    /// dt_ref = min(dts) / refinement, at least 2.
    pub refinement: u32,
    /// A run whose fastest particle at the last frame is slower than this (m/s) is at rest.
    pub rest_speed: f64,
}

/// Why a study could not be carried out. An unstable run is not an error: it is reported in its
/// [`RunReport`].
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// Bad parameters: no integrator, a dt that is not a positive number, a scene that is
    /// invalid with one of the dts.
    #[error("{0}")]
    Invalid(String),
    /// A solver could not be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// The reference itself diverged: no error can be measured.
    #[error("the reference (rk4 at dt = {dt:e} s) became unstable: {instability}")]
    ReferenceUnstable {
        /// The reference's dt, seconds.
        dt: f64,
        /// What happened.
        instability: Instability,
    },
    /// The device failed.
    #[error("device failure: {0}")]
    Device(String),
}

/// The converged solution the runs are measured against.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Always RK4.
    pub integrator: Integrator,
    /// dt_ref, seconds.
    pub dt: f64,
    /// Steps taken (to the last frame time needed).
    pub steps: u64,
    /// Wall time, seconds.
    pub seconds: f64,
    /// The dt of the check run, 2·dt_ref.
    pub check_dt: f64,
    /// Max over frames and particles of |x_check − x_ref|, metres: an upper estimate of the
    /// reference's own error.
    pub error_estimate: f64,
    /// The explicit integrators' stable step estimate of the scene (`softbody check`'s),
    /// seconds; None without springs.
    pub stable_dt: Option<f64>,
    /// The bodies' size: the diagonal of their initial bounding box, metres.
    pub size: f64,
    /// Why the reference is not converged (the criteria of the module doc); empty when it is.
    pub unconverged: Vec<String>,
    /// A refinement to try when it is not: its check step below the stable estimate, and at
    /// least twice the study's.
    pub suggested_refinement: u32,
}

impl Reference {
    /// Whether the runs can be measured against it.
    pub fn converged(&self) -> bool {
        self.unconverged.is_empty()
    }
}

/// One frame of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Frame time, seconds.
    pub time: f64,
    /// Max over particles of |x − x_ref|, metres.
    pub error: f64,
    /// Total energy, joules.
    pub energy: f64,
    /// (E − E₀) / E_s.
    pub drift: f64,
}

/// One integrator at one dt.
#[derive(Debug, Clone, PartialEq)]
pub struct RunReport {
    /// The integrator.
    pub integrator: Integrator,
    /// Time step, seconds.
    pub dt: f64,
    /// Steps taken (fewer than planned when unstable).
    pub steps: u64,
    /// Steps the complete run takes.
    pub planned_steps: u64,
    /// Wall time of the stepping, seconds.
    pub seconds: f64,
    /// Where it diverged, if it did.
    pub instability: Option<Instability>,
    /// Max over frames and particles of |x − x_ref|, metres.
    pub max_error: f64,
    /// Time of the frame where `max_error` was reached, seconds.
    pub max_error_time: f64,
    /// max |E − E₀| / E_s over the frames.
    pub energy_drift: f64,
    /// Smallest signed distance of any particle to any terrain shape at the frames, metres
    /// (negative: inside); None without terrain.
    pub deepest_penetration: Option<f64>,
    /// Fastest particle's speed at the last frame, m/s.
    pub final_max_speed: f64,
    /// Kinetic energy at the last frame, joules.
    pub final_kinetic: f64,
    /// Whether the run completed with `final_max_speed` below the study's rest speed; None when
    /// unstable.
    pub at_rest: Option<bool>,
    /// Whether its error measures its integrator at its step, and if not, why.
    pub standing: Standing,
    /// One sample per frame written.
    pub samples: Vec<Sample>,
}

impl RunReport {
    /// Steps per second of wall time.
    pub fn steps_per_second(&self) -> f64 {
        self.steps as f64 / self.seconds.max(1e-9)
    }
}

/// The study's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    /// Particles in the scene.
    pub particles: usize,
    /// Simulated time, seconds.
    pub duration: f64,
    /// Frames per second.
    pub frame_rate: f64,
    /// The backend of the runs.
    pub backend: Backend,
    /// What ran them (e.g. "CPU, 2 threads").
    pub device: String,
    /// E_s of the initial state, joules: the unit of the energy drift.
    pub energy_scale: f64,
    /// The study's rest speed, m/s.
    pub rest_speed: f64,
    /// The reference.
    pub reference: Reference,
    /// One per integrator × dt, integrators outer, dts inner.
    pub runs: Vec<RunReport>,
}

impl Study {
    /// Every integrator at the scene's dt on the CPU, all cores, refinement [`REFINEMENT`], rest
    /// speed [`REST_SPEED`].
    pub fn new(scene: Scene) -> Study {
        Study {
            scene,
            integrators: Integrator::ALL.to_vec(),
            dts: Vec::new(),
            backend: Backend::Cpu,
            threads: None,
            refinement: REFINEMENT,
            rest_speed: REST_SPEED,
        }
    }

    /// The time steps of the runs: [`Study::dts`], or the scene's dt when empty.
    pub fn dts(&self) -> Vec<f64> {
        if self.dts.is_empty() {
            vec![self.scene.simulation.dt]
        } else {
            self.dts.clone()
        }
    }

    /// The reference's dt: min(dts) / refinement.
    pub fn reference_dt(&self) -> f64 {
        self.dts().into_iter().fold(f64::INFINITY, f64::min) / f64::from(self.refinement.max(2))
    }

    /// The scene with `integrator` and `dt` in place of its own.
    fn scene_with(&self, integrator: Integrator, dt: f64) -> Scene {
        let mut scene = self.scene.clone();
        scene.simulation.integrator = integrator;
        scene.simulation.dt = dt;
        scene
    }

    /// Checks the parameters: at least one integrator, every dt a positive finite number, the
    /// scene valid at each (and at the reference's), refinement ≥ 2, a rest speed ≥ 0.
    pub fn validate(&self) -> Result<(), StudyError> {
        let invalid = |m: String| Err(StudyError::Invalid(m));
        if self.integrators.is_empty() {
            return invalid("no integrator to compare".into());
        }
        if self.refinement < 2 {
            return invalid(format!(
                "the reference refinement must be at least 2, not {}",
                self.refinement
            ));
        }
        if !(self.rest_speed >= 0.0 && self.rest_speed.is_finite()) {
            return invalid(format!(
                "the rest speed must be a finite number ≥ 0, not {}",
                self.rest_speed
            ));
        }
        for dt in self.dts() {
            if !(dt > 0.0 && dt.is_finite()) {
                return invalid(format!(
                    "dt must be a finite number greater than zero, not {dt}"
                ));
            }
        }
        let dt_ref = self.reference_dt();
        for dt in self.dts().into_iter().chain([dt_ref, 2.0 * dt_ref]) {
            if let Err(e) = self.scene_with(Integrator::Rk4, dt).validate() {
                return invalid(format!("with dt = {dt:e} s: {}: {}", e.key, e.message));
            }
        }
        Ok(())
    }

    /// Steps of the whole study: the reference, its check run and every run, complete.
    pub fn total_steps(&self) -> u64 {
        let dts = self.dts();
        let runs: u64 = dts
            .iter()
            .map(|&dt| self.scene_with(Integrator::Rk4, dt).simulation.steps())
            .sum::<u64>()
            * self.integrators.len() as u64;
        let dt_ref = self.reference_dt();
        let reference = self.scene_with(Integrator::Rk4, dt_ref).simulation.steps() + 1;
        let check = self
            .scene_with(Integrator::Rk4, 2.0 * dt_ref)
            .simulation
            .steps();
        runs + reference + check
    }

    /// Runs the study: the reference, its check, then each integrator at each dt. `progress`
    /// hears (steps done, [`Study::total_steps`]) as it goes.
    pub fn run(&self, progress: &mut dyn FnMut(u64, u64)) -> Result<Report, StudyError> {
        self.validate()?;
        let total = self.total_steps();
        let mut done = 0u64;
        let dts = self.dts();
        let dt_ref = self.reference_dt();
        let check_dt = 2.0 * dt_ref;

        // Every frame time at which some run will be compared, ascending.
        let mut times: Vec<f64> = dts
            .iter()
            .chain([&check_dt])
            .flat_map(|&dt| frame_times(&self.scene_with(Integrator::Rk4, dt)))
            .collect();
        times.sort_by(f64::total_cmp);
        times.dedup();

        let reference_scene = self.scene_with(Integrator::Rk4, dt_ref);
        let (states, reference_steps, reference_seconds) =
            reference_states(&reference_scene, self.threads, &times, &mut |n| {
                progress(done + n, total)
            })?;
        done += reference_steps;
        let lookup = ReferenceStates { times, states };

        let rest_speed = self.rest_speed;
        let mut measure = |scene: &Scene, backend: Backend, done: &mut u64| {
            let mut solver = crate::open(scene, backend, self.threads)?;
            let start = *done;
            let report = measure_run(solver.as_mut(), &lookup, rest_speed, &mut |n| {
                progress(start + n, total)
            })?;
            *done += report.planned_steps;
            progress(*done, total);
            Ok::<_, StudyError>((report, solver.device()))
        };

        // The check run: on the CPU like the reference, whatever the study's backend.
        let (check, _) = measure(
            &self.scene_with(Integrator::Rk4, check_dt),
            Backend::Cpu,
            &mut done,
        )?;
        if let Some(i) = check.instability {
            return Err(StudyError::ReferenceUnstable {
                dt: check_dt,
                instability: i,
            });
        }

        let mut runs = Vec::new();
        let mut device = String::new();
        let mut energy_scale = f64::NAN;
        for &integrator in &self.integrators {
            for &dt in &dts {
                let scene = self.scene_with(integrator, dt);
                let (report, d) = measure(&scene, self.backend, &mut done)?;
                device = d;
                runs.push(report);
            }
        }
        // E_s from the reference scene on the CPU (the same initial state as every run).
        if let Ok(mut s) = crate::open(&reference_scene, Backend::Cpu, Some(1))
            && let Ok(e0) = s.energies()
        {
            energy_scale = run::energy_scale(s.as_mut(), &e0).unwrap_or(f64::NAN);
        }
        let (model, start) = softbody_scene::Model::build(&reference_scene);
        let stable_dt = softbody_cpu::stable_step::stable_dt_estimate(&model, &start.x);
        let (lo, hi) = start.x.iter().fold(
            (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY),
            |(lo, hi), x| (lo.min(*x), hi.max(*x)),
        );
        let size = if start.x.is_empty() {
            0.0
        } else {
            (hi - lo).length()
        };
        let errors: Vec<Option<f64>> = runs
            .iter()
            .map(|r| r.instability.is_none().then_some(r.max_error))
            .collect();
        let bound = check.max_error;
        let reasons = unconverged(Evidence {
            check_dt,
            stable_dt,
            bound,
            size,
            errors: &errors,
        });
        for (run, error) in runs.iter_mut().zip(errors) {
            run.standing = standing(error, bound, reasons.is_empty());
        }
        let min_dt = dts.iter().copied().fold(f64::INFINITY, f64::min);

        Ok(Report {
            particles: lookup.states.first().map_or(0, Vec::len),
            duration: self.scene.simulation.duration,
            frame_rate: self.scene.simulation.frame_rate,
            backend: self.backend,
            device,
            energy_scale,
            rest_speed,
            reference: Reference {
                integrator: Integrator::Rk4,
                dt: dt_ref,
                steps: reference_steps,
                seconds: reference_seconds,
                check_dt,
                error_estimate: bound,
                stable_dt,
                size,
                unconverged: reasons,
                suggested_refinement: suggested_refinement(self.refinement, min_dt, stable_dt),
            },
            runs,
        })
    }
}

/// Runs `solver` to the end of its scene with [`run::run`] (its frame schedule and energy guard)
/// and measures each frame against the reference.
fn measure_run(
    solver: &mut dyn Solver,
    reference: &ReferenceStates,
    rest_speed: f64,
    progress: &mut dyn FnMut(u64),
) -> Result<RunReport, StudyError> {
    let sim = solver.model().simulation;
    let step_error = |e: StepError| match e {
        StepError::Unstable(i) => StudyError::Device(format!("unstable initial state: {i}")),
        StepError::Device(d) | StepError::Invalid(d) => StudyError::Device(d),
    };
    let e0 = solver.energies().map_err(step_error)?;
    let scale = run::energy_scale(solver, &e0).map_err(step_error)?;
    let mut sink = CompareSink {
        reference,
        surfaces: solver.model().terrain.iter().map(Surface::new).collect(),
        e0: e0.total(),
        scale,
        samples: Vec::new(),
        deepest: None,
        final_max_speed: 0.0,
        final_kinetic: e0.kinetic,
        busy: Duration::ZERO,
    };
    let started = Instant::now();
    let result = run::run(solver, None, &mut sink, &mut |done, _| progress(done));
    let seconds = (started.elapsed() - sink.busy).as_secs_f64();
    let instability = match result {
        Ok(_) => None,
        Err(RunError::Unstable(i)) => Some(i),
        Err(RunError::Device(d)) => return Err(StudyError::Device(d)),
        Err(e @ (RunError::Overflow(_) | RunError::TooLarge(_))) => {
            return Err(StudyError::Invalid(e.to_string()));
        }
        // The sink writes nothing; its only error is a frame time without a reference state.
        // `run` is never stopped, nor checkpointed.
        Err(e @ (RunError::Io(_) | RunError::Stopped { .. } | RunError::Checkpoint(_))) => {
            return Err(StudyError::Device(e.to_string()));
        }
    };
    let (max_error, max_error_time) = sink.samples.iter().fold((0.0f64, 0.0), |(e, t), s| {
        if s.error > e {
            (s.error, s.time)
        } else {
            (e, t)
        }
    });
    let energy_drift = sink
        .samples
        .iter()
        .map(|s| s.drift.abs())
        .fold(0.0, f64::max);
    let steps = instability
        .as_ref()
        .map_or(solver.steps_taken(), |i| i.step);
    Ok(RunReport {
        integrator: sim.integrator,
        dt: sim.dt,
        steps,
        planned_steps: sim.steps(),
        seconds,
        at_rest: instability
            .is_none()
            .then_some(sink.final_max_speed < rest_speed),
        // Judged once the reference's bound is known ([`Study::run`]).
        standing: Standing::Comparable,
        instability,
        max_error,
        max_error_time,
        energy_drift,
        deepest_penetration: sink.deepest,
        final_max_speed: sink.final_max_speed,
        final_kinetic: sink.final_kinetic,
        samples: sink.samples,
    })
}

/// Measures each frame as [`run::run`] hands it over.
struct CompareSink<'r> {
    reference: &'r ReferenceStates,
    surfaces: Vec<Surface>,
    e0: f64,
    scale: f64,
    samples: Vec<Sample>,
    deepest: Option<f64>,
    final_max_speed: f64,
    final_kinetic: f64,
    /// Time spent here, left out of the run's wall time.
    busy: Duration,
}

impl FrameSink for CompareSink<'_> {
    fn header(&mut self, _: &Header) -> std::io::Result<()> {
        Ok(())
    }

    fn frame(&mut self, frame: &Frame<'_>) -> std::io::Result<()> {
        let started = Instant::now();
        let reference = self.reference.at(frame.time).ok_or_else(|| {
            std::io::Error::other(format!("no reference state at t = {} s", frame.time))
        })?;
        let error = frame
            .positions
            .iter()
            .zip(reference)
            .map(|(x, r)| (*x - *r).length())
            .fold(0.0, f64::max);
        for s in &self.surfaces {
            // An infinite reach answers for every finite point; None: a shape that touches
            // nothing.
            let deepest = frame
                .positions
                .iter()
                .filter_map(|&x| s.query(x, f64::INFINITY))
                .map(|c| c.phi)
                .fold(f64::INFINITY, f64::min);
            if deepest.is_finite() {
                self.deepest = Some(self.deepest.map_or(deepest, |d| d.min(deepest)));
            }
        }
        let energy = frame.energies.total();
        self.samples.push(Sample {
            time: frame.time,
            error,
            energy,
            drift: (energy - self.e0) / self.scale,
        });
        self.final_max_speed = frame
            .velocities
            .iter()
            .map(|v| v.length())
            .fold(0.0, f64::max);
        self.final_kinetic = frame.energies.kinetic;
        self.busy += started.elapsed();
        Ok(())
    }

    fn wants_springs(&self) -> bool {
        false
    }

    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}
