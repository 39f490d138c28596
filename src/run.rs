//! Driving a solver through a run: frames at their steps, energies, and the instability guard.
//!
//! Frame k is taken at step round(k / (frame_rate·dt)) and stamped with that step times dt;
//! frame 0 is the initial state. A run stops at the first step whose state is not finite (the
//! solver reports it), or at the first frame whose total energy, less the control forces' work,
//! exceeds its initial value by more than [`ENERGY_GROWTH_BOUND`] times the scene's energy
//! scale ([`EnergyGuard`]); and at the first frame whose energy is not a finite number (it
//! overflowed f64), so that no frame records a non-number. Either way every frame before it has
//! been written. A scene whose initial energy already overflows (velocities of 1e200 m/s,
//! gravity of 1e308 m/s²) is refused before anything is written: by validation, which names the
//! body, or, for a total within rounding of f64's largest value that the solver's order of
//! summation overflows, here ([`RunError::Overflow`]).

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use softbody_scene::{Energies, History, Instability, Model, Solver, StepError};

use crate::checkpoint::{CheckpointError, Checkpoints, JournalFrame};
use crate::guard::energy_scale_of;
pub use crate::guard::{ENERGY_GROWTH_BOUND, EnergyGuard, energy_scale};

use crate::output::{Frame, FrameSink, Header};

/// Steps advanced between progress reports (and looks at [`run_until`]'s stop flag) at most.
pub const PROGRESS_STEPS: u64 = 256;

/// Why a run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The simulation diverged; frames before it are written.
    #[error("{0}")]
    Unstable(Instability),
    /// The initial state's energy is not a finite number: the scene's values overflow. Nothing
    /// was written.
    #[error(
        "the initial energy is not a finite number (kinetic {} J, gravitational {} J, elastic \
         {} J): the scene's velocities, masses, gravity or positions are too large to simulate",
        softbody_scene::Num(.0.kinetic), softbody_scene::Num(.0.gravitational),
        softbody_scene::Num(.0.elastic)
    )]
    Overflow(Energies),
    /// The output's header does not fit in the memory left: its spring arrays, for a sink
    /// that reads them ([`FrameSink::wants_springs`]). Nothing was written.
    #[error("{0}")]
    TooLarge(String),
    /// The device failed.
    #[error("{0}")]
    Device(String),
    /// Stopped on request ([`run_until`]); the frames before it are written.
    #[error("stopped after {frames} frames ({steps} steps)")]
    Stopped {
        /// Frames written.
        frames: u64,
        /// Steps of the last frame written.
        steps: u64,
    },
    /// Writing frames failed.
    #[error("cannot write frames")]
    Io(#[from] std::io::Error),
    /// Writing or resuming the checkpoint failed.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
}

impl RunError {
    /// Whether the scene (with its output) cannot run as given, found before anything was
    /// written: [`RunError::Overflow`] and [`RunError::TooLarge`], bad input to the caller.
    pub fn is_bad_input(&self) -> bool {
        matches!(self, RunError::Overflow(_) | RunError::TooLarge(_))
    }
}

/// Bytes a run's header takes per spring for a sink that reads its spring arrays: the ends
/// (2 × 4), the rest length, the stiffness and the damping (3 × 8).
pub const HEADER_BYTES_PER_SPRING: u64 = 40;

/// Refuses a header whose spring arrays would not fit in the memory left
/// ([`softbody_scene::memory::available_memory`]), before they are allocated.
fn header_fits(model: &Model) -> Result<(), RunError> {
    let springs = model.spring_count() as u64;
    let need = springs * HEADER_BYTES_PER_SPRING;
    match softbody_scene::memory::available_memory() {
        Some((have, what)) if need > have => Err(RunError::TooLarge(format!(
            "the output takes every spring's ends, rest length and coefficients ({springs} springs, {:.2} GiB) and {:.2} GiB are {what}; JSON Lines and CSV do without them",
            need as f64 / (1u64 << 30) as f64,
            have as f64 / (1u64 << 30) as f64
        ))),
        _ => Ok(()),
    }
}

impl From<StepError> for RunError {
    fn from(e: StepError) -> Self {
        match e {
            StepError::Unstable(i) => RunError::Unstable(i),
            StepError::Device(d) | StepError::Invalid(d) => RunError::Device(d),
        }
    }
}

/// The scene file a run's frames name in their header, and the text of the scene that ran
/// (the file's, with any settings written in: [`crate::scene_text`]).
#[derive(Debug, Clone, Copy)]
pub struct SceneFile<'a> {
    /// The file.
    pub path: &'a Path,
    /// The scene's text.
    pub text: &'a str,
}

/// What a finished (or stopped) run did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Frames written.
    pub frames: u64,
    /// Steps taken.
    pub steps: u64,
    /// Energies of the last frame written.
    pub last_energies: Energies,
}

/// Runs the solver to the end of its scene, writing each frame to `sink`; `progress` hears
/// (steps done, steps in all) as the run goes. `scene` names the file the scene came from, and
/// its text, in the frames' header.
///
/// Frames into memory as JSON Lines, first the header, then one line per frame:
///
/// ```
/// use softbody::{Backend, Scene, output::{self, Format}};
/// let mut scene = Scene::from_file("scenes/jelly-on-ground.toml")?;
/// scene.simulation.duration = 0.1; // 3 frames after the first at 30 frames/s
/// let mut solver = softbody::open(&scene, Backend::Cpu, Some(1))?;
/// let mut bytes = Vec::new();
/// {
///     let mut sink = output::sink(Format::Jsonl, Box::new(&mut bytes))?;
///     let summary = softbody::run::run(solver.as_mut(), None, sink.as_mut(), &mut |_, _| {})?;
///     assert_eq!(summary.frames, 4);
///     sink.finish()?;
/// }
/// let text = String::from_utf8(bytes)?;
/// assert_eq!(text.lines().count(), 1 + 4);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn run(
    solver: &mut dyn Solver,
    scene: Option<SceneFile<'_>>,
    sink: &mut dyn FrameSink,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Summary, RunError> {
    run_until(solver, scene, sink, progress, &AtomicBool::new(false), None)
}

/// [`run`], stopping early once `stop` is set (by a signal handler, another thread): it is
/// looked at every [`PROGRESS_STEPS`] steps at most, and the run ends with
/// [`RunError::Stopped`] after the frames written so far, each complete.
///
/// With `checkpoints`, every frame is journaled and the run checkpointed as they say; a
/// resumed run's [`Checkpoints`] first give the frames computed before, then the solver (freshly
/// opened) is restored to the last of them and the run goes on from there.
pub fn run_until(
    solver: &mut dyn Solver,
    scene: Option<SceneFile<'_>>,
    sink: &mut dyn FrameSink,
    progress: &mut dyn FnMut(u64, u64),
    stop: &AtomicBool,
    mut checkpoints: Option<&mut Checkpoints>,
) -> Result<Summary, RunError> {
    let stopped = |summary: &Summary| {
        stop.load(Ordering::Relaxed).then_some(RunError::Stopped {
            frames: summary.frames,
            steps: summary.steps,
        })
    };
    let sim = solver.model().simulation;
    let total = sim.steps();
    let frames = sim.frame_count();
    // A resumed run's frames stream from its journal, one record at a time: holding them
    // would take the journal's size in memory.
    let (mut replay, history) = match checkpoints.as_deref_mut() {
        Some(c) if c.resumed_frames() > 0 => {
            let (replay, history) = c.replay()?;
            (Some(replay), history)
        }
        _ => (None, History::default()),
    };
    let mut replayed = JournalFrame::default();
    let replaying = match &mut replay {
        Some(replay) => replay.next(&mut replayed)?,
        None => false,
    };
    // Frame 0 is the initial state, whose energies are E₀.
    let mut guard = if replaying {
        let e0 = replayed.energies;
        let scale = energy_scale_of(solver.model(), &replayed.state.x, &e0);
        EnergyGuard::resumed(solver, e0, scale)?
    } else {
        EnergyGuard::start(solver)?
    };
    let e0 = guard.initial();
    // Handed over: its spring arrays are as large as the state, so a sink that keeps them
    // moves them, and the run keeps none.
    let springs = sink.wants_springs();
    if springs {
        header_fits(solver.model())?;
    }
    sink.take_header(Header::new(solver, frames, scene, springs))?;

    let mut summary = Summary {
        frames: 0,
        steps: 0,
        last_energies: e0,
    };
    if replaying && let Some(mut replay) = replay {
        loop {
            let f = &replayed;
            sink.frame(&Frame {
                index: f.index,
                step: f.step,
                time: f.time,
                positions: &f.state.x,
                velocities: &f.state.v,
                energies: f.energies,
            })?;
            guard.passed(f.index, f.step, f.state.clone(), History::default());
            summary.frames += 1;
            summary.steps = f.step;
            summary.last_energies = f.energies;
            if !replay.next(&mut replayed)? {
                break;
            }
        }
        // The last frame again, with the history the run goes on from.
        let f = &replayed;
        guard.passed(f.index, f.step, f.state.clone(), history.clone());
        // A history the solver refuses (a part missing or of another size) is a checkpoint
        // that this version cannot read: bad input, not a failure of the solver.
        let refused = |e| match (e, checkpoints.as_deref()) {
            (StepError::Invalid(why), Some(c)) => CheckpointError::Corrupt(c.file(), why).into(),
            (e, _) => RunError::from(e),
        };
        solver
            .restore(f.step, &f.state, &history)
            .map_err(refused)?;
    }
    for k in summary.frames..frames {
        let target = sim.frame_step(k);
        while solver.steps_taken() < target {
            if let Some(e) = stopped(&summary) {
                return Err(e);
            }
            let n = (target - solver.steps_taken()).min(PROGRESS_STEPS);
            solver.advance(n)?;
            progress(solver.steps_taken(), total);
        }
        let energies = guard.frame(k, solver)?;
        let state = guard.last_state().expect("the frame just checked");
        let step = solver.steps_taken();
        let frame = Frame {
            index: k,
            step,
            time: step as f64 * sim.dt,
            positions: &state.x,
            velocities: &state.v,
            energies,
        };
        sink.frame(&frame)?;
        if let Some(c) = checkpoints.as_deref_mut() {
            c.frame(&frame, solver)?;
        }
        summary.frames += 1;
        summary.steps = step;
        summary.last_energies = energies;
    }
    Ok(summary)
}

#[cfg(test)]
pub(crate) mod tests {
    use glam::DVec3;

    use super::*;
    use crate::output::{self, Format};

    /// A stop requested after frame 2 ends the run there: its frames are the first three of
    /// the uninterrupted run's, byte for byte.
    #[test]
    fn a_stopped_run_keeps_the_frames_before_the_stop() {
        let mut scene = softbody_scene::Scene::from_file(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenes/jelly-on-ground.toml"
        ))
        .unwrap();
        scene.simulation.duration = 0.2;
        let frames = |stop_after: Option<u64>| {
            let mut solver = crate::open(&scene, crate::Backend::Cpu, Some(1)).unwrap();
            let mut bytes = Vec::new();
            let stop = AtomicBool::new(false);
            let result = {
                let mut sink = output::sink(Format::Jsonl, Box::new(&mut bytes)).unwrap();
                let frame_steps = [0, 1, 2].map(|k| scene.simulation.frame_step(k));
                let result = run_until(
                    solver.as_mut(),
                    None,
                    sink.as_mut(),
                    &mut |done, _| {
                        if stop_after.is_some_and(|k| done >= frame_steps[k as usize]) {
                            stop.store(true, Ordering::Relaxed);
                        }
                    },
                    &stop,
                    None,
                );
                sink.finish().unwrap();
                result
            };
            (result, String::from_utf8(bytes).unwrap())
        };
        let (all, text) = frames(None);
        assert!(all.unwrap().frames > 3);
        let (stopped, partial) = frames(Some(2));
        let Err(RunError::Stopped { frames, steps }) = stopped else {
            panic!("{stopped:?}");
        };
        assert_eq!((frames, steps), (3, scene.simulation.frame_step(2)));
        let expected: Vec<&str> = text.lines().take(1 + 3).collect();
        assert_eq!(partial.lines().collect::<Vec<_>>(), expected);
    }

    /// Control forces through the run service: a body pushed with u_i = m_i a in frame 0, left
    /// alone in frame 1 and pushed with m_i b in frame 2 moves as a rigid body (its springs
    /// stay at rest) with v = a t₀ after frame 1, the same after frame 2, and a t₀ + b t₀ after
    /// frame 3 (t₀ a frame's time; symplectic Euler adds h a exactly each step, to rounding).
    /// Without gravity the energy scale is 0, so the kinetic energy the pushes give would be
    /// called an instability but for the controls' work, which the guard subtracts. A
    /// checkpointed run resumes them (the guard's work counted over the replayed frames).
    #[test]
    fn control_forces_push_over_their_frames_and_their_work_is_not_an_instability() {
        use crate::service::{self, Hooks, RunFailure, RunRequest, SceneSource};
        struct Velocities(Vec<Vec<DVec3>>);
        impl FrameSink for Velocities {
            fn header(&mut self, _: &Header) -> std::io::Result<()> {
                Ok(())
            }
            fn frame(&mut self, f: &Frame<'_>) -> std::io::Result<()> {
                self.0.push(f.velocities.to_vec());
                Ok(())
            }
            fn finish(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let text = "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 0.01\nduration = 0.3\n\
            frame_rate = 10.0\ngravity = [0.0, 0.0, 0.0]\n[[body]]\nkind = \"cuboid\"\n\
            size = [0.2, 0.2, 0.2]\nresolution = [3, 3, 3]\nmass = 2.7\n\
            structural = { stiffness = 500.0, damping = 0.0 }\n";
        let origin = std::path::PathBuf::from("pushed.toml");
        let scene = crate::scene_from_toml(text, &origin, &[]).unwrap();
        let (model, _) = Model::build(&scene);
        let (frames, n) = (model.simulation.frame_count() as usize, model.len());
        assert_eq!(frames, 4);
        let (a, b) = (DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, -2.0, 0.5));
        let push = [a, DVec3::ZERO, b, DVec3::new(1e3, 1e3, 1e3)];
        let controls: Vec<DVec3> = (0..frames * n)
            .map(|k| model.mass[k % n] * push[k / n])
            .collect();
        let request = |backend, checkpoint| RunRequest {
            scene: SceneSource::Text {
                text: text.to_owned(),
                origin: origin.clone(),
            },
            backend,
            threads: Some(1),
            checkpoint,
            controls: Some(controls.clone().into()),
            ..RunRequest::file(&origin)
        };
        let mut seen = Velocities(Vec::new());
        let hooks = Hooks {
            observer: Some(&mut seen),
            ..Hooks::default()
        };
        let outcome = service::execute(&request(crate::Backend::Cpu, None), hooks);
        assert!(outcome.result.is_ok(), "{:?}", outcome.result.err());
        let t0 = 0.1;
        let expected = [DVec3::ZERO, a * t0, a * t0, (a + b) * t0];
        for (f, (v, e)) in seen.0.iter().zip(expected).enumerate() {
            for (i, v) in v.iter().enumerate() {
                assert!(
                    (*v - e).length() < 1e-12,
                    "frame {f}, particle {i}: {v} ≠ {e}"
                );
            }
        }
        // The GPU refuses them as bad input, before its device opens.
        match service::execute(&request(crate::Backend::Gpu, None), Hooks::default()).result {
            Err(RunFailure::Request(why)) => assert!(why.contains("control forces"), "{why}"),
            other => panic!("the GPU: {other:?}"),
        }
        // Checkpointed, stopped after frame 1 and resumed, the run is the uninterrupted one,
        // byte for byte; other forces are another run, whose resume is refused.
        let dir = tempfile::tempdir().unwrap();
        let to = |name: &str, checkpoint| RunRequest {
            destination: service::Destination::File {
                format: Format::Jsonl,
                path: dir.path().join(name),
            },
            ..request(crate::Backend::Cpu, checkpoint)
        };
        let plan = |resume| service::CheckpointPlan {
            every: Some(1),
            resume,
        };
        let whole = service::execute(&to("whole.jsonl", None), Hooks::default());
        assert_eq!(whole.result.unwrap().frames, 4);
        let stop = std::sync::atomic::AtomicBool::new(false);
        let stopped = service::execute(
            &to("resumed.jsonl", Some(plan(false))),
            Hooks {
                progress: Some(&mut |done, _| {
                    stop.store(done >= 10, std::sync::atomic::Ordering::Relaxed)
                }),
                stop: Some(&stop),
                ..Hooks::default()
            },
        );
        assert_eq!(stopped.frames, 2, "{:?}", stopped.result);
        let mut other = to("resumed.jsonl", Some(plan(true)));
        let mut pushed = controls.clone();
        pushed[0].x += 1.0;
        other.controls = Some(pushed.into());
        match service::execute(&other, Hooks::default()).result {
            Err(e) => assert!(e.to_string().contains("another run"), "{e}"),
            Ok(s) => panic!("resumed with other forces: {s:?}"),
        }
        let resumed = service::execute(&to("resumed.jsonl", Some(plan(true))), Hooks::default());
        assert_eq!(resumed.result.unwrap().frames, 4);
        let read = |name: &str| std::fs::read(dir.path().join(name)).unwrap();
        assert!(read("resumed.jsonl") == read("whole.jsonl"));
    }

    /// The header's spring arrays are built for a sink that reads them and left empty for one
    /// that does not: every spring in the model's order, or none.
    #[test]
    fn the_header_carries_the_springs_only_to_a_sink_that_wants_them() {
        struct Springs {
            wants: bool,
            got: Option<(usize, usize, usize, usize)>,
        }
        impl FrameSink for Springs {
            fn header(&mut self, h: &Header) -> std::io::Result<()> {
                self.got = Some((
                    h.springs.len(),
                    h.rest.len(),
                    h.stiffness.len(),
                    h.damping.len(),
                ));
                Ok(())
            }
            fn frame(&mut self, _: &Frame<'_>) -> std::io::Result<()> {
                Ok(())
            }
            fn finish(&mut self) -> std::io::Result<()> {
                Ok(())
            }
            fn wants_springs(&self) -> bool {
                self.wants
            }
        }
        let mut scene = softbody_scene::Scene::from_file(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenes/jelly-on-ground.toml"
        ))
        .unwrap();
        scene.simulation.duration = 0.01;
        for wants in [true, false] {
            let mut solver = crate::open(&scene, crate::Backend::Cpu, Some(1)).unwrap();
            let n = solver.model().spring_count();
            assert!(n > 0);
            let mut sink = Springs { wants, got: None };
            run(solver.as_mut(), None, &mut sink, &mut |_, _| {}).unwrap();
            let expected = if wants { n } else { 0 };
            assert_eq!(
                sink.got,
                Some((expected, expected, expected, expected)),
                "{wants}"
            );
        }
        // The formats that write no springs say so.
        for format in [Format::Jsonl, Format::Csv] {
            let sink = output::sink(format, Box::new(std::io::sink())).unwrap();
            assert!(!sink.wants_springs(), "{format:?}");
        }
        let npz = output::sink(Format::Npz, Box::new(std::io::sink())).unwrap();
        assert!(npz.wants_springs());
    }

    /// Explicit Euler at 400 Hz on a stiff undamped 3³ cube: beyond the energy guard within
    /// 2 s, between two frames (20 steps per frame).
    pub(crate) const UNSTABLE_CUBE: &str = r#"
        [simulation]
        integrator = "explicit-euler"
        dt = 0.0025
        duration = 2.0
        frame_rate = 20.0
        [[body]]
        kind = "cuboid"
        size = [0.3, 0.3, 0.3]
        resolution = [3, 3, 3]
        center = [0.0, 1.0, 0.0]
        mass = 1.0
        structural = { stiffness = 600.0, damping = 0.0 }
        shear = { stiffness = 600.0, damping = 0.0 }
    "#;

    /// An energy-guard instability is reported at the first step whose energy exceeds the
    /// guard, not at the frame that saw it: a solver stepped one step at a time from the start
    /// is within the guard one step before the reported step and beyond it at that step, which
    /// lies between two frames here (20 steps per frame).
    #[test]
    fn the_energy_guard_reports_the_exact_step() {
        let scene = softbody_scene::Scene::from_toml(UNSTABLE_CUBE, "guard.toml".as_ref()).unwrap();
        let open = || crate::open(&scene, crate::Backend::Cpu, Some(1)).unwrap();
        let mut solver = open();
        let mut sink = output::sink(Format::Csv, Box::new(std::io::sink())).unwrap();
        let Err(RunError::Unstable(i)) = run(solver.as_mut(), None, sink.as_mut(), &mut |_, _| {})
        else {
            panic!("explicit Euler at 400 Hz holds the cube");
        };
        assert!(i.what.contains("total energy reached"), "{i}");
        assert!(i.step % 20 != 0, "step {} is a frame's", i.step);
        assert_eq!(i.time, i.step as f64 * scene.simulation.dt);

        let mut solver = open();
        let e0 = solver.energies().unwrap();
        let bound = ENERGY_GROWTH_BOUND * energy_scale(solver.as_mut(), &e0).unwrap();
        let growth = |solver: &mut dyn Solver| solver.energies().unwrap().total() - e0.total();
        solver.advance(i.step - 1).unwrap();
        assert!(
            growth(solver.as_mut()) <= bound,
            "beyond the guard before step {}",
            i.step
        );
        solver.advance(1).unwrap();
        assert!(
            growth(solver.as_mut()) > bound,
            "within the guard at step {}",
            i.step
        );
    }
}
