//! The fused explicit step (`shaders/fused_step.wgsl`, `softbody_gpu::integrators::fused`): one
//! dispatch per integrator stage, each particle gathering its springs' forces from its
//! neighbours, with the update, the collision response and the finiteness check in the same
//! kernel.
//!
//! - Against the CPU, every explicit integrator, on a slope (contact and friction from the
//!   first step) with pinned particles: within the twin tests' bounds for smooth contact
//!   (`twins.rs`: 1e-5 m per particle, 5e-4 of the peak speed).
//! - Against the per-spring path on the GPU (`GpuOptions::per_spring`), with restitution and
//!   pinned particles, over submissions of odd and even step counts (the Euler methods'
//!   ping-pong and its copy back): the same bits, since each spring force is the same call on
//!   the same inputs, gathered in the same order.
//! - Run to run: the same bits.
//! - An adapter that cannot bind the fused kernels' buffers (WebGPU's minimum of 8 storage
//!   buffers per stage) takes the per-spring path.
//! - The design's figures: 1, 2 and 4 dispatches per step, less traffic than the per-spring
//!   path.

mod common;

use std::process::ExitCode;
use std::sync::Arc;

use common::{BOUNCY_PLANE, SLOPE, step_error};
use softbody_cpu::CpuSolver;
use softbody_gpu::{Gpu, GpuOptions, GpuSolver};
use softbody_scene::{Energies, Integrator, Model, Scene, Solver, State};
use softbody_testkit::{Failed, GpuTest, ensure};

const EXPLICIT: [Integrator; 4] = [
    Integrator::ExplicitEuler,
    Integrator::SymplecticEuler,
    Integrator::Midpoint,
    Integrator::Rk4,
];

fn main() -> ExitCode {
    let mut tests: Vec<(String, GpuTest)> = Vec::new();
    let cpu: [GpuTest; 4] = [
        |gpu| against_cpu(gpu, Integrator::ExplicitEuler),
        |gpu| against_cpu(gpu, Integrator::SymplecticEuler),
        |gpu| against_cpu(gpu, Integrator::Midpoint),
        |gpu| against_cpu(gpu, Integrator::Rk4),
    ];
    let per_spring: [GpuTest; 4] = [
        |gpu| against_per_spring(gpu, Integrator::ExplicitEuler),
        |gpu| against_per_spring(gpu, Integrator::SymplecticEuler),
        |gpu| against_per_spring(gpu, Integrator::Midpoint),
        |gpu| against_per_spring(gpu, Integrator::Rk4),
    ];
    for ((integrator, cpu), per_spring) in EXPLICIT.iter().zip(cpu).zip(per_spring) {
        let name = integrator.to_string().replace('-', "_");
        tests.push((format!("fused_{name}_matches_the_cpu"), cpu));
        tests.push((
            format!("fused_{name}_equals_the_per_spring_path"),
            per_spring,
        ));
    }
    tests.push(("fused_runs_repeat_bit_for_bit".into(), repeatable));
    tests.push((
        "an_adapter_at_webgpus_minimum_takes_the_per_spring_path".into(),
        minimum_adapter,
    ));
    tests.push(("fused_design_figures".into(), design_figures));
    softbody_testkit::run_gpu("GPU fused step tests", tests)
}

/// A 6×6×6 cube of 30 cm (216 particles, 2,556 springs), tilted, its lowest corner in `terrain`
/// (contacts from the first step), thrown down at 1 m/s, with three particles pinned (two on
/// the bottom face, one on the top): the springs to them pull on their neighbours while they
/// stay put.
fn cube(integrator: Integrator, dt: f64, duration: f64, terrain: &str) -> (Model, State) {
    let text = format!(
        r#"
[simulation]
integrator = "{integrator}"
dt = {dt:e}
duration = {duration}
frame_rate = 20.0
gravity = [0.0, -9.81, 0.0]
drag = 0.1

[[body]]
name = "cube"
kind = "cuboid"
size = [0.3, 0.3, 0.3]
resolution = [6, 6, 6]
center = [0.0, 0.18, 0.0]
rotation = [10.0, 0.0, 15.0]
velocity = [0.5, -1.0, 0.0]
mass = 1.0
pinned = [0, 5, 215]
structural = {{ stiffness = 400.0, damping = 1.0 }}
shear = {{ stiffness = 400.0, damping = 1.0 }}
bending = {{ stiffness = 200.0, damping = 0.5 }}
{terrain}
"#
    );
    let scene = Scene::from_toml(&text, "test.toml".as_ref()).expect("test scene is valid");
    Model::build(&scene)
}

fn open(
    gpu: &Arc<Gpu>,
    model: &Model,
    state: &State,
    per_spring: bool,
) -> Result<GpuSolver, Failed> {
    let options = GpuOptions {
        per_spring,
        ..GpuOptions::default()
    };
    let g = GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
        .map_err(|e| e.to_string())?;
    let want = if per_spring {
        "per-spring + gather"
    } else {
        "fused gather"
    };
    let kernel = g.statistics().kernel;
    ensure(kernel == want, || format!("kernel {kernel}, want {want}"))?;
    Ok(g)
}

/// The particles' largest |Δx| (m) and |Δv| (m/s) between `a` and `b`.
fn differences(a: &State, b: &State) -> (f64, f64) {
    let max = |p: &[glam::DVec3], q: &[glam::DVec3]| {
        p.iter()
            .zip(q)
            .map(|(p, q)| p.distance(*q))
            .fold(0.0, f64::max)
    };
    (max(&a.x, &b.x), max(&a.v, &b.v))
}

/// 0.25 s (1,000 steps) on the slope against the CPU (one thread), compared at every frame.
fn against_cpu(gpu: &Arc<Gpu>, integrator: Integrator) -> Result<(), Failed> {
    let (model, state) = cube(integrator, 2.5e-4, 0.25, SLOPE);
    let mut g = open(gpu, &model, &state, false)?;
    let mut cpu =
        CpuSolver::new(model.clone(), state.clone(), Some(1)).map_err(|e| e.to_string())?;
    let pinned: Vec<usize> = (0..model.len())
        .filter(|&i| model.inv_mass[i] == 0.0)
        .collect();
    let (mut dx, mut dv, mut peak, mut moved) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let sim = model.simulation;
    for k in 0..sim.frame_count() {
        let n = sim.frame_step(k) - g.steps_taken();
        g.advance(n).map_err(step_error)?;
        cpu.advance(n).map_err(step_error)?;
        let (gs, cs) = (
            g.state().map_err(step_error)?,
            cpu.state().map_err(step_error)?,
        );
        let (x, v) = differences(gs, cs);
        dx = dx.max(x);
        dv = dv.max(v);
        peak = cs.v.iter().map(|v| v.length()).fold(peak, f64::max);
        moved =
            cs.x.iter()
                .zip(&state.x)
                .map(|(a, b)| a.distance(*b))
                .fold(moved, f64::max);
        for &i in &pinned {
            ensure(
                gs.x[i] == state.x[i].as_vec3().as_dvec3() && gs.v[i] == state.v[i],
                || format!("pinned particle {i} moved on the GPU: {:?}", gs.x[i]),
            )?;
        }
    }
    println!(
        "{integrator}: {} steps, {} pinned; max |Δx| {dx:.2e} m, max |Δv| {dv:.2e} m/s ({:.2e} \
         of the peak speed {peak:.2} m/s); particles moved up to {moved:.3} m",
        sim.steps(),
        pinned.len(),
        dv / peak
    );
    ensure(moved > 0.05 && pinned.len() == 3, || {
        "the cube did not move".into()
    })?;
    ensure(dx <= 1e-5 && dv <= 5e-4 * peak, || {
        format!(
            "{integrator}: the fused GPU run is further from the CPU's than 1e-5 m, 5e-4 of the peak speed"
        )
    })
}

/// The run as submitted in batches of `batches` steps: the state and energies after each.
fn batches(g: &mut GpuSolver, batches: &[u64]) -> Result<Vec<(State, Energies)>, Failed> {
    batches
        .iter()
        .map(|&n| {
            g.advance(n).map_err(step_error)?;
            let e = g.energies().map_err(step_error)?;
            Ok((g.state().map_err(step_error)?.clone(), e))
        })
        .collect()
}

/// Odd and even submissions: 1 step (the timed first), 2, 7, then 300 (however the solver
/// splits them).
const BATCHES: [u64; 4] = [1, 2, 7, 300];

/// The fused path against the per-spring path: the same bits after every batch.
fn against_per_spring(gpu: &Arc<Gpu>, integrator: Integrator) -> Result<(), Failed> {
    let (model, state) = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
    let fused = batches(&mut open(gpu, &model, &state, false)?, &BATCHES)?;
    let per_spring = batches(&mut open(gpu, &model, &state, true)?, &BATCHES)?;
    let (last, _) = fused.last().expect("batches");
    let (dx, _) = differences(last, &state);
    println!(
        "{integrator}: {} steps, particles moved up to {dx:.3} m",
        BATCHES.iter().sum::<u64>()
    );
    for (k, (f, p)) in fused.iter().zip(&per_spring).enumerate() {
        let (x, v) = differences(&f.0, &p.0);
        ensure(f == p, || {
            format!(
                "{integrator}: after batch {k} the fused run differs from the per-spring run \
                 (|Δx| {x:e}, |Δv| {v:e}; energies {:?} and {:?})",
                f.1, p.1
            )
        })?;
    }
    ensure(dx > 0.01, || "the cube did not move".into())
}

/// Each explicit integrator twice: the same bits.
fn repeatable(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    for integrator in EXPLICIT {
        let (model, state) = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
        let a = batches(&mut open(gpu, &model, &state, false)?, &BATCHES)?;
        let b = batches(&mut open(gpu, &model, &state, false)?, &BATCHES)?;
        ensure(a == b, || format!("{integrator}: two fused runs differ"))?;
    }
    Ok(())
}

/// With 8 storage buffers per stage (the fused kernels bind 11 to 13), every explicit
/// integrator takes the per-spring path, with the fused path's bits.
fn minimum_adapter(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    for integrator in EXPLICIT {
        let (model, state) = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
        let options = GpuOptions {
            max_storage_buffers: Some(8),
            ..GpuOptions::default()
        };
        let mut g = GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
            .map_err(|e| e.to_string())?;
        let kernel = g.statistics().kernel;
        ensure(kernel == "per-spring + gather", || {
            format!("{integrator} at 8 storage buffers: kernel {kernel}")
        })?;
        let fused = batches(&mut open(gpu, &model, &state, false)?, &BATCHES[..3])?;
        ensure(batches(&mut g, &BATCHES[..3])? == fused, || {
            format!("{integrator}: the fallback differs from the fused run")
        })?;
    }
    Ok(())
}

/// Dispatches and bytes per step of each explicit integrator, fused and per-spring, over 20
/// steps after the first (which also computes the response's band masks once).
fn design_figures(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    for (integrator, stages) in EXPLICIT.into_iter().zip([1, 1, 2, 4]) {
        let (model, state) = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
        let mut figures = Vec::new();
        for per_spring in [false, true] {
            let mut g = open(gpu, &model, &state, per_spring)?;
            g.advance(1).and_then(|()| g.sync()).map_err(step_error)?;
            let before = g.statistics();
            g.advance(20).and_then(|()| g.sync()).map_err(step_error)?;
            let after = g.statistics();
            let dispatches = (after.dispatches - before.dispatches) as f64 / 20.0;
            let bytes =
                (after.device_bytes - before.device_bytes) as f64 / 20.0 / model.len() as f64;
            figures.push((dispatches, bytes));
        }
        let [(fused, fused_bytes), (per_spring, per_spring_bytes)] = figures[..] else {
            unreachable!("two paths")
        };
        println!(
            "{integrator}: fused {fused} dispatches, {fused_bytes:.0} B per particle-step; \
             per-spring {per_spring} dispatches, {per_spring_bytes:.0} B"
        );
        ensure(
            fused == f64::from(stages) && per_spring > fused && per_spring_bytes > fused_bytes,
            || format!("{integrator}: {figures:?}"),
        )?;
    }
    Ok(())
}
