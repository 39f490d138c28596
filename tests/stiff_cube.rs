//! A stiff cube at a frame-sized step, on every backend: implicit Euler keeps it stable and
//! brings it to rest, explicit Euler is reported unstable.

use std::process::ExitCode;

use glam::DVec3;
use softbody::output::{Frame, FrameSink, Header};
use softbody::run::{self, RunError};
use softbody::scene::SpringParams;
use softbody::{Integrator, Model, Scene, StepError};
use softbody_testkit::scenes::*;
use softbody_testkit::{Backend, Failed, Law, all, ensure};

fn main() -> ExitCode {
    softbody_testkit::run(
        "stiff_cube",
        [
            Law::new(
                "implicit_euler_keeps_a_stiff_cube_stable_at_a_frame_step",
                implicit_euler_keeps_a_stiff_cube_stable_at_a_frame_step,
            ),
            Law::new(
                "explicit_euler_on_the_stiff_cube_is_reported_unstable",
                explicit_euler_on_the_stiff_cube_is_reported_unstable,
            ),
        ],
    )
}

/// A 6×6×6 cube, 0.5 m, 1 kg, k_s = 1e4 N/m and k_d = 5 N·s/m on all three families, dropped
/// from 0.1 m onto a plane with μ = 0.5, k_r = 0, h = 1/60 s, for 5 s (300 steps).
fn stiff_cube(integrator: Integrator) -> Scene {
    let mut sim = simulation(integrator, 1.0 / 60.0);
    sim.duration = 5.0;
    let params = SpringParams {
        stiffness: 1e4,
        damping: 5.0,
    };
    let cube = cuboid(
        DVec3::splat(0.5),
        [6, 6, 6],
        DVec3::new(0.0, 0.35, 0.0),
        1.0,
        params,
    );
    scene(
        sim,
        vec![cuboid_body(cube)],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.0, 0.5)],
    )
}

fn bounding_box(x: &[DVec3]) -> (DVec3, DVec3) {
    x.iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        })
}

/// Implicit Euler at h = 1/60 on the stiff cube (explicit methods need h < ~1e-4 here):
/// - every state is finite and the total energy (kinetic + gravitational + elastic) never rises
///   from one step to the next by more than 1e-9 J (1e-9 of the drop's energy scale M g·0.35 m ≈
///   3.4 J; backward Euler with damping and perfectly inelastic contact only dissipates) plus
///   8ε of that scale, what the backend resolves of it (3e-6 J in f32; measured on lavapipe: a
///   largest rise of 6e-8 J);
/// - it never sinks: min y ≥ −ε at every step;
/// - at the end (5 s) it is at rest (kinetic energy < 1e-8 J), every spring is within 10 % of its
///   rest length, and the bounding box is within 5 % of the original 0.5 m per axis, resting on
///   the plane (bottom within ε of y = 0).
fn implicit_euler_keeps_a_stiff_cube_stable_at_a_frame_step(
    backend: &Backend,
) -> Result<(), Failed> {
    let scene = stiff_cube(Integrator::ImplicitEuler);
    let (model, state) = Model::build(&scene);
    let stable = model.stable_dt().unwrap();
    ensure(scene.simulation.dt > 50.0 * stable, || {
        format!("stable dt {stable:e}")
    })?;
    let eps = scene.simulation.contact_distance;
    let noise = 1e-9 + 8.0 * backend.epsilon() * 1.0 * G * 0.35;
    let mut solver = backend.solver_from(model.clone(), state)?;
    let steps = scene.simulation.steps();
    let e = |solver: &mut dyn softbody::Solver| -> Result<_, Failed> {
        Ok(solver.energies().map_err(|e| e.to_string())?)
    };
    let mut e_prev = e(solver.as_mut())?.total();
    let e0 = e_prev;
    let (mut worst_rise, mut worst_step, mut lowest) = (f64::NEG_INFINITY, 0, f64::INFINITY);
    for k in 1..=steps {
        solver.advance(1).map_err(|e| e.to_string())?;
        let e = e(solver.as_mut())?.total();
        ensure(e.is_finite(), || format!("energy {e} at step {k}"))?;
        if e - e_prev > worst_rise {
            (worst_rise, worst_step) = (e - e_prev, k);
        }
        e_prev = e;
        let st = solver.state().map_err(|e| e.to_string())?;
        lowest = lowest.min(st.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min));
    }
    let energies = e(solver.as_mut())?;
    let stats = solver.statistics();
    let st = solver.state().map_err(|e| e.to_string())?;
    let sp = model.springs();
    let worst_strain = (0..sp.len())
        .map(|s| {
            let len = st.x[sp.a[s] as usize].distance(st.x[sp.b[s] as usize]);
            (len / sp.rest[s] - 1.0).abs()
        })
        .fold(0.0, f64::max);
    let (lo, hi) = bounding_box(&st.x);
    let size = hi - lo;
    println!(
        "implicit-euler: E {e0:.4} → {:.4} J, largest rise {worst_rise:.2e} J at step {worst_step}, \
         (bound {noise:.1e} J), final kinetic {:.2e} J, worst strain {worst_strain:.4}, box {size:.4}, lowest y {lowest:.2e}, \
         {} CG iterations in {} solves (max residual {:.1e})",
        energies.total(),
        energies.kinetic,
        stats.cg_iterations,
        stats.cg_solves,
        stats.cg_max_residual
    );
    let mut failures = Vec::new();
    if worst_rise > noise {
        failures.push(format!(
            "total energy rose by {worst_rise:e} J at step {worst_step}"
        ));
    }
    if lowest < -eps {
        failures.push(format!("sank to y = {lowest} m"));
    }
    if energies.kinetic > 1e-8 {
        failures.push(format!(
            "not at rest after 5 s: kinetic energy {} J",
            energies.kinetic
        ));
    }
    if worst_strain > 0.1 {
        failures.push(format!("a spring is strained by {worst_strain}"));
    }
    if (size - DVec3::splat(0.5)).abs().max_element() > 0.025 {
        failures.push(format!("bounding box {size} m, was 0.5 m"));
    }
    if lo.y.abs() > eps {
        failures.push(format!("bottom at y = {} m, not on the plane", lo.y));
    }
    all(failures)
}

/// The same scene with explicit Euler at h = 1/60 (≈ 100× its stable step) must be reported
/// unstable: `advance` (with `sync`, since a GPU runs ahead) stops with `StepError::Unstable` naming a step ≥ 1 within the run and a
/// particle of the model that is not finite, and `run::run` stops with `RunError::Unstable` (the
/// energy guard or the non-finite check), having written only frames before the instability,
/// frame 0 included. On the CPU the state is that of the failing step, and the particle named is
/// its first non-finite one; the GPU finishes its submission of steps, so later steps may have
/// spread the non-finite values (its exact step and particle are tested against the CPU in
/// `crates/gpu/tests`).
fn explicit_euler_on_the_stiff_cube_is_reported_unstable(backend: &Backend) -> Result<(), Failed> {
    let scene = stiff_cube(Integrator::ExplicitEuler);
    let steps = scene.simulation.steps();
    let (model, state) = Model::build(&scene);
    let n = model.len() as u32;
    let mut solver = backend.solver_from(model.clone(), state.clone())?;
    match solver.advance(steps).and_then(|()| solver.sync()) {
        Err(StepError::Unstable(i)) => {
            println!("advance: {i}");
            ensure(i.step >= 1 && i.step <= steps && i.particle < n, || {
                format!("{i:?}")
            })?;
            ensure(solver.steps_taken() == i.step, || {
                format!(
                    "{} steps taken, unstable at {}",
                    solver.steps_taken(),
                    i.step
                )
            })?;
            ensure(
                (i.time - i.step as f64 * scene.simulation.dt).abs() < 1e-12,
                || format!("{i:?}"),
            )?;
            let st = solver.state().map_err(|e| e.to_string())?;
            let p = i.particle as usize;
            ensure(!(st.x[p].is_finite() && st.v[p].is_finite()), || {
                format!("{i:?}")
            })?;
            if !backend.is_gpu() {
                ensure(
                    st.x[..p]
                        .iter()
                        .zip(&st.v[..p])
                        .all(|(x, v)| x.is_finite() && v.is_finite()),
                    || format!("{i:?} is not the first non-finite particle"),
                )?;
            }
        }
        other => {
            return Err(format!("explicit Euler at h = 1/60 on k = 1e4: {other:?}").into());
        }
    }

    let mut solver = backend.solver_from(model, state)?;
    let mut sink = Frames::default();
    match run::run(solver.as_mut(), None, &mut sink, &mut |_, _| {}) {
        Err(RunError::Unstable(i)) => {
            println!("run: {i}; {} frames written", sink.steps.len());
            ensure(i.step >= 1 && i.step <= steps && i.particle < n, || {
                format!("{i:?}")
            })?;
            ensure(sink.header, || "no header written".into())?;
            ensure(!sink.steps.is_empty() && sink.steps[0] == 0, || {
                "frame 0 is not written".into()
            })?;
            ensure(sink.steps.iter().all(|&s| s < i.step), || {
                format!(
                    "frames {:?} after the instability at step {}",
                    sink.steps, i.step
                )
            })?;
            ensure(sink.energies.iter().all(|e| e.is_finite()), || {
                "a frame has a non-finite energy".into()
            })
        }
        other => Err(format!("run of explicit Euler at h = 1/60: {other:?}").into()),
    }
}

/// A sink that keeps each frame's step and total energy.
#[derive(Default)]
struct Frames {
    header: bool,
    steps: Vec<u64>,
    energies: Vec<f64>,
}

impl FrameSink for Frames {
    fn header(&mut self, _: &Header) -> std::io::Result<()> {
        self.header = true;
        Ok(())
    }
    fn frame(&mut self, frame: &Frame<'_>) -> std::io::Result<()> {
        self.steps.push(frame.step);
        self.energies.push(frame.energies.total());
        Ok(())
    }
    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}
