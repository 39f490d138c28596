//! The GPU against its CPU twin: each stage on the same input, each explicit integrator's run
//! against the CPU's, the instability record, implicit Euler (its system and CG solve against
//! the CPU's `System` and `CgProblem::solve`, its runs against the CPU's), 2-D grids, a lost
//! device.
//! (What both backends must satisfy on their own — closed forms, contact laws, determinism, the
//! stiff cube, the scenes — is tested once for both in the top-level `tests/`.)
//!
//! softbody-testkit's harness: without an adapter every test reports itself ignored ("skipped:
//! no GPU adapter"), unless `SOFTBODY_REQUIRE_GPU=1`, which makes a missing adapter a failure.
//! The tests share one device. Each prints the agreement it measured (`--nocapture` shows it).
//!
//! # Tolerances
//!
//! The GPU computes in f32 (unit roundoff u = 2⁻²⁴ ≈ 6e-8), the CPU in f64. Stage tests give both
//! the same f32-representable input, so their difference is the f32 rounding of a few dozen
//! operations, bounded relative to the *scale* of each quantity (not its value, which may be a
//! near-cancellation): a spring force against k_s(|d| + r) + k_d|v_a − v_b|, an acceleration
//! against |g| + Σ|f_s|/m + drag|v|, a position against |x|. The bounds below are 1e-5 of those
//! scales (about 170 u), an order of magnitude above what is measured.
//!
//! Runs carry every step's rounding forward. Over 0.5 s of a 30 cm cube landing on a plane or a
//! slope without restitution, the particles stay on the surface, well inside the contact band,
//! and the runs agree to about 1e-6 m per particle (bound 1e-5 m). With restitution, contact
//! decisions at the band's edge flip on a rounding and the paths part (see [`BOUNCY`]). The
//! measured agreement is printed per integrator and terrain.

mod common;

use std::process::ExitCode;
use std::sync::Arc;

use common::{BOUNCY_PLANE, PLANE, SLOPE, inverse_block, product_scale, rhs_scale, step_error};
use glam::DVec3;
use softbody_cpu::{CpuSolver, collision_response, energy, forces, spring_forces};
use softbody_gpu::{Gpu, GpuOptions, GpuSolver};
use softbody_scene::{Integrator, Model, Scene, Solver, State, Statistics, StepError};
use softbody_terrain::Surface;
use softbody_testkit::{Failed, GpuTest, Rng, ensure};

fn main() -> ExitCode {
    let tests: &[(&str, GpuTest)] = &[
        ("stage_spring_forces", stage_spring_forces),
        ("stage_accelerations_with_contact_coulomb", |gpu| {
            stage_accelerations(gpu, "coulomb")
        }),
        ("stage_accelerations_with_contact_viscous", |gpu| {
            stage_accelerations(gpu, "viscous")
        }),
        ("stage_collision_response", stage_collision_response),
        ("stage_energies", stage_energies),
        ("one_step_explicit_euler", |gpu| {
            one_step(gpu, Integrator::ExplicitEuler)
        }),
        ("one_step_symplectic_euler", |gpu| {
            one_step(gpu, Integrator::SymplecticEuler)
        }),
        ("one_step_midpoint", |gpu| {
            one_step(gpu, Integrator::Midpoint)
        }),
        ("one_step_rk4", |gpu| one_step(gpu, Integrator::Rk4)),
        ("run_explicit_euler_plane", |gpu| {
            run_against_cpu(gpu, Integrator::ExplicitEuler, PLANE)
        }),
        ("run_explicit_euler_slope", |gpu| {
            run_against_cpu(gpu, Integrator::ExplicitEuler, SLOPE)
        }),
        ("run_explicit_euler_bouncy_plane", |gpu| {
            run_against_cpu(gpu, Integrator::ExplicitEuler, BOUNCY_PLANE)
        }),
        ("run_symplectic_euler_plane", |gpu| {
            run_against_cpu(gpu, Integrator::SymplecticEuler, PLANE)
        }),
        ("run_symplectic_euler_slope", |gpu| {
            run_against_cpu(gpu, Integrator::SymplecticEuler, SLOPE)
        }),
        ("run_symplectic_euler_bouncy_plane", |gpu| {
            run_against_cpu(gpu, Integrator::SymplecticEuler, BOUNCY_PLANE)
        }),
        ("run_midpoint_plane", |gpu| {
            run_against_cpu(gpu, Integrator::Midpoint, PLANE)
        }),
        ("run_midpoint_slope", |gpu| {
            run_against_cpu(gpu, Integrator::Midpoint, SLOPE)
        }),
        ("run_midpoint_bouncy_plane", |gpu| {
            run_against_cpu(gpu, Integrator::Midpoint, BOUNCY_PLANE)
        }),
        ("run_rk4_plane", |gpu| {
            run_against_cpu(gpu, Integrator::Rk4, PLANE)
        }),
        ("run_rk4_slope", |gpu| {
            run_against_cpu(gpu, Integrator::Rk4, SLOPE)
        }),
        ("run_rk4_bouncy_plane", |gpu| {
            run_against_cpu(gpu, Integrator::Rk4, BOUNCY_PLANE)
        }),
        (
            "instability_names_the_first_step_and_lowest_particle",
            instability_is_exact,
        ),
        (
            "instability_matches_the_cpu_on_a_nan",
            instability_matches_cpu,
        ),
        ("a_lost_device_is_reported_not_a_panic", lost_device),
        (
            "the_design_counts_its_dispatches_and_traffic",
            design_figures,
        ),
        (
            "two_dimensional_grids_give_the_same_bits",
            two_dimensional_grids,
        ),
        ("a_scene_without_bodies_runs", no_bodies),
        ("implicit_system_twin", implicit_system_twin),
        ("implicit_cg_twin", implicit_cg_twin),
        (
            "implicit_cg_iterations_take_three_dispatches",
            implicit_cg_dispatches,
        ),
        (
            "implicit_solves_stop_at_what_the_f32_state_resolves",
            implicit_bounces,
        ),
        ("run_implicit_euler_plane", |gpu| run_implicit(gpu, PLANE)),
        ("run_implicit_euler_slope", |gpu| run_implicit(gpu, SLOPE)),
        (
            "implicit_euler_two_dimensional_grids_give_the_same_bits",
            implicit_two_dimensional_grids,
        ),
    ];
    softbody_testkit::run_gpu("GPU twin tests", tests.iter().copied())
}

// ---------------------------------------------------------------------------------------------
// Scenes and inputs

/// A 4×4×4 cube of 30 cm, all three spring families, 1 kg, tilted, 5 cm above the origin.
fn cube_scene(integrator: Integrator, dt: f64, duration: f64, terrain: &str) -> Scene {
    cube_scene_of(4, integrator, dt, duration, terrain)
}

/// The cube with `r` particles per edge.
fn cube_scene_of(r: u32, integrator: Integrator, dt: f64, duration: f64, terrain: &str) -> Scene {
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
resolution = [{r}, {r}, {r}]
center = [0.0, 0.25, 0.0]
rotation = [10.0, 0.0, 15.0]
velocity = [0.5, 0.0, 0.0]
mass = 1.0
structural = {{ stiffness = 400.0, damping = 1.0 }}
shear = {{ stiffness = 400.0, damping = 1.0 }}
bending = {{ stiffness = 200.0, damping = 0.5 }}
{terrain}
"#
    );
    Scene::from_toml(&text, "test.toml".as_ref()).expect("test scene is valid")
}

/// Rounds through f32, so that the CPU and GPU see the same input.
fn f32_exact(v: DVec3) -> DVec3 {
    v.as_vec3().as_dvec3()
}

/// The state perturbed: positions by up to `dx`, velocities up to `dv`, rounded to f32.
fn perturbed(state: &State, seed: u64, dx: f64, dv: f64) -> State {
    let mut rng = Rng::new(seed);
    State {
        x: state
            .x
            .iter()
            .map(|&x| f32_exact(x + rng.vec(dx)))
            .collect(),
        v: state
            .v
            .iter()
            .map(|&v| f32_exact(v + rng.vec(dv)))
            .collect(),
    }
}

fn open(gpu: &Arc<Gpu>, model: &Model, state: &State) -> Result<GpuSolver, Failed> {
    GpuSolver::on(gpu, model.clone(), state.clone()).map_err(|e| e.to_string().into())
}

/// The solver on the per-spring path, whose kernels the stage read-backs of the spring forces
/// and accelerations run (a cuboid's explicit run otherwise takes the stencil, which has no
/// spring list for them).
fn open_per_spring(gpu: &Arc<Gpu>, model: &Model, state: &State) -> Result<GpuSolver, Failed> {
    let options = GpuOptions {
        per_spring: true,
        ..GpuOptions::default()
    };
    GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
        .map_err(|e| e.to_string().into())
}

/// Largest |a − b| / scale over elements, and the largest |a − b|.
fn max_errors(
    gpu: impl Iterator<Item = DVec3>,
    cpu: impl Iterator<Item = DVec3>,
    scale: impl Iterator<Item = f64>,
) -> (f64, f64) {
    let (mut rel, mut abs) = (0.0f64, 0.0f64);
    for ((g, c), s) in gpu.zip(cpu).zip(scale) {
        let e = (g - c).length();
        abs = abs.max(e);
        rel = rel.max(if s > 0.0 { e / s } else { e });
    }
    (rel, abs)
}

fn check(what: &str, rel: f64, abs: f64, bound: f64) -> Result<(), Failed> {
    println!("{what}: max error {abs:.3e} absolute, {rel:.3e} of its scale (bound {bound:e})");
    if rel <= bound {
        Ok(())
    } else {
        Err(format!("{what}: error {rel:.3e} of its scale exceeds {bound:e}").into())
    }
}

const STAGE_BOUND: f64 = 1e-5;

// ---------------------------------------------------------------------------------------------
// Stages

fn stage_spring_forces(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, "");
    let (model, state) = Model::build(&scene);
    let state = perturbed(&state, 1, 0.02, 1.0);
    let mut g = open_per_spring(gpu, &model, &state)?;
    let got = g.debug_spring_forces().map_err(step_error)?;
    let mut want = vec![DVec3::ZERO; model.springs().len()];
    spring_forces::compute(model.springs(), &state.x, &state.v, &mut want);
    let s = model.springs();
    let scale = (0..s.len()).map(|k| {
        let (a, b) = (s.a[k] as usize, s.b[k] as usize);
        s.stiffness[k] * (state.x[a].distance(state.x[b]) + s.rest[k])
            + s.damping[k] * (state.v[a] - state.v[b]).length()
    });
    let (rel, abs) = max_errors(got.iter().map(|f| f.as_dvec3()), want.into_iter(), scale);
    check("spring forces", rel, abs, STAGE_BOUND)
}

/// The bottom of the cube pushed into (and just above) a plane, with random velocities: some
/// particles slip, some stick, some are out of reach.
fn stage_accelerations(gpu: &Arc<Gpu>, friction_model: &str) -> Result<(), Failed> {
    let terrain = format!("{PLANE}friction_model = \"{friction_model}\"\n");
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, &terrain);
    let (model, state) = Model::build(&scene);
    let mut state = perturbed(&state, 2, 0.01, 0.2);
    // Squash the cube flat onto the plane: heights from −2 mm to about 8 mm, so that the
    // particles are spread over inside, within and beyond the contact reach of 1 mm, and the
    // compressed springs push some into the plane and pull others away.
    let lowest = state.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
    for x in &mut state.x {
        x.y = f32_exact(DVec3::new(0.0, (x.y - lowest) * 0.02 - 0.002, 0.0)).y;
    }
    let mut g = open_per_spring(gpu, &model, &state)?;
    let got = g.debug_accelerations().map_err(step_error)?;
    let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
    let mut per_spring = vec![DVec3::ZERO; model.springs().len()];
    let mut want = vec![DVec3::ZERO; model.len()];
    forces::accelerations(
        &model,
        &surfaces,
        &state.x,
        &state.v,
        &mut per_spring,
        &mut want,
    );
    let in_reach: Vec<usize> = (0..model.len()).filter(|&i| state.x[i].y < 1e-3).collect();
    // Where the contact acts, a differs from the applied force alone.
    let touching = in_reach
        .iter()
        .filter(|&&i| {
            let f = forces::applied_force(&model, &per_spring, state.v[i], i);
            (want[i] - f / model.mass[i]).length() > 1e-9
        })
        .count();
    println!(
        "{} of {} particles within reach of the plane, {touching} pressing into it",
        in_reach.len(),
        model.len()
    );
    let sim = &model.simulation;
    let scale = (0..model.len()).map(|i| {
        let springs: f64 = model
            .adjacency()
            .of(i)
            .iter()
            .map(|&e| per_spring[(e >> 1) as usize].length())
            .sum();
        // Contact and friction are bounded by the applied force (and m|v|/h for friction).
        2.0 * (sim.gravity.length()
            + springs / model.mass[i]
            + sim.drag * state.v[i].length()
            + state.v[i].length() / sim.dt)
    });
    let (rel, abs) = max_errors(got.iter().map(|a| a.as_dvec3()), want.into_iter(), scale);
    check(
        &format!("accelerations with {friction_model} contact"),
        rel,
        abs,
        STAGE_BOUND,
    )
}

/// The response on the bouncy plane, from step starts some of which lie in the contact band
/// (no restitution: v_n ← 0) and some above it (a fresh impact: v_n ← −k_r v_n).
fn stage_collision_response(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, BOUNCY_PLANE);
    let (model, state) = Model::build(&scene);
    let mut state = perturbed(&state, 3, 0.01, 1.0);
    let lowest = state.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
    for x in &mut state.x {
        x.y = f32_exact(*x - DVec3::new(0.0, lowest + 0.05, 0.0)).y;
    }
    // Band edge ε = 1 mm: starts 0.25 mm or 4 mm above the end position, alternately (clear
    // of the f32 rounding of the band test).
    let x_start: Vec<DVec3> = (0..model.len())
        .map(|i| {
            let up = if i % 2 == 0 { 2.5e-4 } else { 4e-3 };
            f32_exact(state.x[i].max(DVec3::new(f64::MIN, 0.0, f64::MIN)) + DVec3::Y * up)
        })
        .collect();
    let mut g = open(gpu, &model, &state)?;
    g.debug_collision_response(&x_start).map_err(step_error)?;
    let got = g.state().map_err(step_error)?.clone();
    let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
    let mut want = state.clone();
    let start = State {
        x: x_start.clone(),
        v: state.v.clone(),
    };
    collision_response::respond(&model, &surfaces, &start, &mut want.x, &mut want.v);
    let moved = (0..model.len())
        .filter(|&i| want.x[i] != state.x[i])
        .count();
    let eps = model.simulation.contact_distance;
    let responded = |fresh: bool| {
        (0..model.len())
            .filter(|&i| want.v[i] != state.v[i] && (x_start[i].y >= eps) == fresh)
            .count()
    };
    println!(
        "{moved} of {} particles moved back onto the plane; {} fresh impacts, {} in the band",
        model.len(),
        responded(true),
        responded(false)
    );
    if responded(true) == 0 || responded(false) == 0 {
        return Err("the case does not exercise both fresh and resting contacts".into());
    }
    let (rx, ax) = max_errors(
        got.x.iter().copied(),
        want.x.iter().copied(),
        state.x.iter().map(|x| x.length().max(0.05)),
    );
    let (rv, av) = max_errors(
        got.v.iter().copied(),
        want.v.iter().copied(),
        state.v.iter().map(|v| v.length()),
    );
    check("collision response: positions", rx, ax, STAGE_BOUND)?;
    check("collision response: velocities", rv, av, STAGE_BOUND)
}

fn stage_energies(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, "");
    let (model, state) = Model::build(&scene);
    let state = perturbed(&state, 4, 0.02, 1.0);
    let mut g = open(gpu, &model, &state)?;
    let got = g.energies().map_err(step_error)?;
    let want = energy::energies(&model, &state);
    let g_len = model.simulation.gravity.length();
    // Scales: sums of the terms' magnitudes.
    let kinetic_scale = want.kinetic;
    let grav_scale: f64 = (0..model.len())
        .map(|i| model.mass[i] * g_len * state.x[i].length())
        .sum();
    let s = model.springs();
    let elastic_scale: f64 = (0..s.len())
        .map(|k| {
            let d = state.x[s.a[k] as usize].distance(state.x[s.b[k] as usize]);
            0.5 * s.stiffness[k] * (d + s.rest[k]) * (d + s.rest[k])
        })
        .sum();
    for (what, got, want, scale) in [
        ("kinetic energy", got.kinetic, want.kinetic, kinetic_scale),
        (
            "gravitational energy",
            got.gravitational,
            want.gravitational,
            grav_scale,
        ),
        ("elastic energy", got.elastic, want.elastic, elastic_scale),
    ] {
        let abs = (got - want).abs();
        check(what, abs / scale, abs, STAGE_BOUND)?;
    }
    Ok(())
}

/// One step of each integrator from the same state, no terrain: forces and update.
fn one_step(gpu: &Arc<Gpu>, integrator: Integrator) -> Result<(), Failed> {
    let scene = cube_scene(integrator, 1e-3, 0.1, "");
    let (model, state) = Model::build(&scene);
    let state = perturbed(&state, 5, 0.02, 1.0);
    let mut g = open(gpu, &model, &state)?;
    g.advance(1).map_err(step_error)?;
    let got = g.state().map_err(step_error)?.clone();
    let mut cpu =
        CpuSolver::new(model.clone(), state.clone(), Some(1)).map_err(|e| e.to_string())?;
    cpu.advance(1).map_err(step_error)?;
    let want = cpu.state().map_err(step_error)?.clone();
    let h = model.simulation.dt;
    // Position error: the f32 rounding of x itself plus h times the velocity error.
    let x_scale = state.x.iter().map(|x| x.length() + h * 10.0);
    let (rx, ax) = max_errors(got.x.iter().copied(), want.x.iter().copied(), x_scale);
    // Velocity error: rounding of v plus h times the acceleration error (scale of a: Σ|f|/m).
    let v_scale = (0..model.len()).map(|i| {
        let k: f64 = model
            .adjacency()
            .of(i)
            .iter()
            .map(|&e| {
                let s = (e >> 1) as usize;
                let sp = model.springs();
                sp.stiffness[s] * (sp.rest[s] + 0.05) + sp.damping[s] * 2.0
            })
            .sum();
        state.v[i].length() + h * (9.81 + k / model.mass[i])
    });
    let (rv, av) = max_errors(got.v.iter().copied(), want.v.iter().copied(), v_scale);
    check(
        &format!("one {integrator} step: positions"),
        rx,
        ax,
        STAGE_BOUND,
    )?;
    check(
        &format!("one {integrator} step: velocities"),
        rv,
        av,
        STAGE_BOUND,
    )
}

// ---------------------------------------------------------------------------------------------
// Runs

/// Bounds of a run: particle position (m), particle velocity (of the peak speed), centre of
/// mass (m), total energy (of the energy scale M|g|(D + 1 m), as the run driver's guard).
struct RunBounds {
    position: f64,
    velocity: f64,
    center: f64,
    energy: f64,
}

/// Without restitution, particles stay on the surface (φ ≈ 0), well inside the contact band
/// [0, ε): contact decisions have margin, and the runs stay within a few f32 roundings of x per
/// particle (measured on llvmpipe, Vulkan and GL: at most 1.2e-6 m and 1.6e-5 of the peak speed).
const SMOOTH: RunBounds = RunBounds {
    position: 1e-5,
    velocity: 5e-4,
    center: 1e-5,
    energy: 1e-5,
};

/// With restitution, particles bounce up to the band's edge φ = ε and chatter there: in reach,
/// the contact force cancels gravity; out of reach, it does not. The force is discontinuous at
/// φ = ε, so where f32 and f64 put a particle on opposite sides, that particle's velocity
/// differs by up to g·h plus a friction impulse, and from then on the two runs follow different
/// (equally valid) paths: no per-particle bound holds, only the body's motion agrees. Measured
/// on llvmpipe (Vulkan, GL): up to 1.5 cm and 0.5 m/s for single particles, 9 mm for the centre
/// of mass, 8e-4 of the energy scale (RK4 via GL; the others agree better).
const BOUNCY: RunBounds = RunBounds {
    position: 0.05,
    velocity: 1.0,
    center: 0.02,
    energy: 0.01,
};

/// 0.5 s of the cube falling onto a plane or a slope: the GPU's frames against the CPU's.
fn run_against_cpu(gpu: &Arc<Gpu>, integrator: Integrator, terrain: &str) -> Result<(), Failed> {
    let (terrain_name, bounds) = match terrain {
        PLANE => ("plane", SMOOTH),
        SLOPE => ("slope", SMOOTH),
        _ => ("bouncy plane", BOUNCY),
    };
    let scene = cube_scene(integrator, 2.5e-4, 0.5, terrain);
    let run = side_by_side(gpu, &scene)?;
    let name = format!("{integrator} on the {terrain_name}");
    println!("{name}: {run}");
    bounds.check(&name, &run)
}

/// A scene run on the GPU and on the CPU (one thread), compared at every frame.
struct SideBySide {
    steps: u64,
    /// Seconds each took, energies included.
    seconds: (f64, f64),
    /// The largest particle position and velocity differences, m and m/s.
    dx: f64,
    dv: f64,
    /// The CPU's peak particle speed, m/s.
    peak: f64,
    /// The largest centre-of-mass difference, m.
    dc: f64,
    /// The largest total-energy difference, J, and the run driver's energy scale.
    de: f64,
    scale: f64,
    /// The solvers' counters at the end.
    statistics: (Statistics, Statistics),
}

fn side_by_side(gpu: &Arc<Gpu>, scene: &Scene) -> Result<SideBySide, Failed> {
    let (model, state) = Model::build(scene);
    let sim = model.simulation;
    let total_mass: f64 = model.mass.iter().sum();
    let mut g = open(gpu, &model, &state)?;
    let mut cpu = CpuSolver::new(model.clone(), state, Some(1)).map_err(|e| e.to_string())?;
    let e0 = cpu.energies().map_err(step_error)?;
    let scale = softbody_scale(&mut cpu, &e0)?;
    let (mut dx, mut dv, mut dc, mut peak, mut de) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let (mut gpu_time, mut cpu_time) = (0.0, 0.0);
    for k in 0..sim.frame_count() {
        let n = sim.frame_step(k) - g.steps_taken();
        let t = std::time::Instant::now();
        g.advance(n).map_err(step_error)?;
        let eg = g.energies().map_err(step_error)?;
        gpu_time += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        cpu.advance(n).map_err(step_error)?;
        let ec = cpu.energies().map_err(step_error)?;
        cpu_time += t.elapsed().as_secs_f64();
        de = de.max((eg.total() - ec.total()).abs());
        let gs = g.state().map_err(step_error)?;
        let cs = cpu.state().map_err(step_error)?;
        let (mut cg, mut cc) = (DVec3::ZERO, DVec3::ZERO);
        for i in 0..model.len() {
            dx = dx.max(gs.x[i].distance(cs.x[i]));
            dv = dv.max(gs.v[i].distance(cs.v[i]));
            peak = peak.max(cs.v[i].length());
            cg += model.mass[i] * gs.x[i];
            cc += model.mass[i] * cs.x[i];
        }
        dc = dc.max(cg.distance(cc) / total_mass);
    }
    Ok(SideBySide {
        steps: sim.steps(),
        seconds: (gpu_time, cpu_time),
        dx,
        dv,
        peak,
        dc,
        de,
        scale,
        statistics: (g.statistics(), cpu.statistics()),
    })
}

impl std::fmt::Display for SideBySide {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (gst, cst) = &self.statistics;
        write!(
            f,
            "{} steps (GPU {:.2} s, CPU {:.2} s): max |Δx| {:.2e} m, max |Δv| {:.2e} m/s ({:.2e} \
             of the peak speed {:.2} m/s), centre of mass {:.2e} m, total energy {:.2e} J \
             ({:.2e} of the scale {:.2} J)",
            self.steps,
            self.seconds.0,
            self.seconds.1,
            self.dx,
            self.dv,
            self.dv / self.peak,
            self.peak,
            self.dc,
            self.de,
            self.de / self.scale,
            self.scale
        )?;
        if gst.cg_solves > 0 {
            write!(
                f,
                "; CG: GPU {} iterations in {} solves (max residual {:.1e}), CPU {} in {} (max \
                 residual {:.1e})",
                gst.cg_iterations,
                gst.cg_solves,
                gst.cg_max_residual,
                cst.cg_iterations,
                cst.cg_solves,
                cst.cg_max_residual
            )?;
        }
        Ok(())
    }
}

impl RunBounds {
    /// Ok if `run` is within the bounds.
    fn check(&self, name: &str, run: &SideBySide) -> Result<(), Failed> {
        if run.dx > self.position
            || run.dv > self.velocity * run.peak
            || run.dc > self.center
            || run.de > self.energy * run.scale
        {
            return Err(format!(
                "{name}: the GPU run is further from the CPU's than the bounds ({} m per \
                 particle, {} of the peak speed, {} m centre of mass, {} of the energy scale)",
                self.position, self.velocity, self.center, self.energy
            )
            .into());
        }
        Ok(())
    }
}

/// M|g|(D + 1 m) + K₀ + E_el,₀: the run driver's energy scale.
fn softbody_scale(cpu: &mut CpuSolver, e0: &softbody_scene::Energies) -> Result<f64, Failed> {
    let g = cpu.model().simulation.gravity.length();
    let mass: f64 = cpu.model().mass.iter().sum();
    let x = &cpu.state().map_err(step_error)?.x;
    let (lo, hi) = x
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    Ok(e0.kinetic + e0.elastic + mass * g * ((hi - lo).length() + 1.0))
}

// ---------------------------------------------------------------------------------------------
// Instability

/// Five free particles (no gravity) flying up with exactly representable f32 numbers: particles
/// 3 and 4 overflow their position at step 300 (x = 2¹¹⁷(1748 + k), f32 max just below 2¹²⁸ =
/// 2¹¹⁷·2048), particle 1 at step 400, particles 0 and 2 never. The report must be step 300,
/// particle 3, position, found in a later submission than the first of those in flight (the
/// first is one step, the next up to 256), read back by `sync`: `advance` does not wait.
fn instability_is_exact(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = Scene::from_toml(
        "[simulation]\nintegrator = \"explicit-euler\"\ndt = 0.5\nduration = 1000.0\n\
         frame_rate = 1.0\ngravity = [0.0, 0.0, 0.0]\ndrag = 0.0\n\
         [[body]]\nkind = \"particles\"\nmasses = [1.0, 1.0, 1.0, 1.0, 1.0]\n\
         positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0], \
         [4.0, 0.0, 0.0]]\n",
        "t.toml".as_ref(),
    )
    .expect("valid");
    let (model, mut state) = Model::build(&scene);
    let p117 = 2f64.powi(117);
    let v = 2f64.powi(118); // h·v = 2¹¹⁷ with h = 0.5
    state.x[1].y = p117 * 1648.0;
    state.x[3].y = p117 * 1748.0;
    state.x[4].y = p117 * 1748.0;
    for i in [1, 3, 4] {
        state.v[i].y = v;
    }
    let mut g = open(gpu, &model, &state)?;
    match g.advance(1000).and_then(|()| g.sync()) {
        Err(StepError::Unstable(i)) => {
            println!("reported: {i}");
            if (i.step, i.particle, i.what.as_str(), i.time)
                != (300, 3, "has a non-finite position", 150.0)
                || g.steps_taken() != 300
            {
                return Err(format!(
                    "want step 300 (t = 150 s), particle 3, position; got {i:?}, steps_taken {}",
                    g.steps_taken()
                )
                .into());
            }
            Ok(())
        }
        other => Err(format!("want an instability at step 300, got {other:?}").into()),
    }
}

/// A NaN velocity in the initial state: the GPU reports the step and particle the CPU reports.
fn instability_matches_cpu(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene(Integrator::Midpoint, 1e-3, 0.1, PLANE);
    let (model, mut state) = Model::build(&scene);
    state.v[37] = DVec3::new(0.0, f64::NAN, 0.0);
    let mut g = open(gpu, &model, &state)?;
    let mut cpu = CpuSolver::new(model, state, Some(1)).map_err(|e| e.to_string())?;
    let (got, want) = (g.advance(10).and_then(|()| g.sync()), cpu.advance(10));
    println!("GPU: {got:?}\nCPU: {want:?}");
    match (got, want) {
        (Err(StepError::Unstable(a)), Err(StepError::Unstable(b))) if a == b => Ok(()),
        (got, want) => Err(format!("GPU {got:?} differs from CPU {want:?}").into()),
    }
}

/// The dispatches and the traffic a solver counts are the same for every step, whatever
/// the submissions were (10 steps, then 30 in other batches, after the first), and grow with the integrator's
/// stages: midpoint runs the force stages twice, RK4 four times. Symplectic Euler moves at
/// least its state (x and v read and written: 4 × 16 bytes per particle) each step.
fn design_figures(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let mut per_step = Vec::new();
    for integrator in [
        Integrator::SymplecticEuler,
        Integrator::Midpoint,
        Integrator::Rk4,
    ] {
        let scene = cube_scene(integrator, 1e-3, 0.1, PLANE);
        let (model, state) = Model::build(&scene);
        let mut g = open(gpu, &model, &state)?;
        let counts = |g: &mut GpuSolver, steps: u64| -> Result<(u64, u64), Failed> {
            let before = g.statistics();
            g.advance(steps)
                .and_then(|()| g.sync())
                .map_err(step_error)?;
            let after = g.statistics();
            Ok((
                after.dispatches - before.dispatches,
                after.device_bytes - before.device_bytes,
            ))
        };
        // The first step also computes the collision response's band masks once.
        counts(&mut g, 1)?;
        let (d10, b10) = counts(&mut g, 10)?;
        let (d30, b30) = counts(&mut g, 30)?;
        ensure(d10 > 0 && 3 * d10 == d30 && 3 * b10 == b30, || {
            format!("{integrator}: {d10} dispatches and {b10} B in 10 steps, {d30} and {b30} in 30")
        })?;
        let bytes = b10 as f64 / 10.0 / model.len() as f64;
        println!(
            "{integrator}: {} dispatches, {bytes:.0} B per particle-step",
            d10 / 10
        );
        per_step.push((d10 / 10, bytes));
    }
    let [(symplectic, bytes), (midpoint, _), (rk4, _)] = per_step[..] else {
        unreachable!("three integrators")
    };
    ensure(
        symplectic < midpoint && midpoint < rk4 && bytes >= 64.0,
        || format!("dispatches per step: {per_step:?}"),
    )
}

/// After the device is gone, every call reports StepError::Device; nothing panics.
fn lost_device(_shared: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, PLANE);
    let (model, state) = Model::build(&scene);
    // A device of its own: destroying the binary's shared one would fail the other tests.
    let own = Gpu::open().map_err(|e| e.to_string())?;
    let mut g = open(&own, &model, &state)?;
    g.advance(10).map_err(step_error)?;
    g.debug_destroy_device();
    let results = [
        g.advance(10).and_then(|()| g.sync()).err(),
        g.energies().err(),
        g.state().err(),
        g.advance(1).err(),
    ];
    for (call, result) in ["advance and sync", "energies", "state", "advance again"]
        .iter()
        .zip(results)
    {
        match result {
            Some(StepError::Device(message)) => println!("{call}: {message}"),
            other => return Err(format!("{call} after losing the device: {other:?}").into()),
        }
    }
    Ok(())
}

/// Scenes of more than 65,535 workgroups run on 2-D grids. Forcing grids one or two workgroups
/// wide makes a small scene take that path (512 particles: 2 groups, as 1 × 2 or 2 × 1; 6,220
/// springs: 25 groups, as 1 × 25 or 2 × 13 with one idle group): the same steps and energies as
/// the 1-D grids, bit for bit.
fn two_dimensional_grids(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene_of(8, Integrator::Rk4, 2.5e-4, 0.1, BOUNCY_PLANE);
    same_bits_on_every_grid_width(gpu, &scene, 200)
}

/// `steps` steps of `scene` on 1-D grids and on grids one and two workgroups wide: the same
/// states, energies and CG counts, bit for bit.
fn same_bits_on_every_grid_width(gpu: &Arc<Gpu>, scene: &Scene, steps: u64) -> Result<(), Failed> {
    let (model, state) = Model::build(scene);
    let mut runs = Vec::new();
    for width in [None, Some(1), Some(2)] {
        let mut g = GpuSolver::with_options(
            gpu,
            model.clone(),
            state.clone(),
            softbody_gpu::GpuOptions {
                grid_width: width,
                ..Default::default()
            },
        )
        .map_err(|e| e.to_string())?;
        g.advance(steps).map_err(step_error)?;
        let e = g.energies().map_err(step_error)?;
        let stats = g.statistics();
        runs.push((
            g.state().map_err(step_error)?.clone(),
            e,
            stats.cg_iterations,
            stats.cg_solves,
        ));
    }
    println!(
        "{} particles, {} springs; energies {:?}; {} CG iterations in {} solves",
        model.len(),
        model.springs().len(),
        runs[0].1,
        runs[0].2,
        runs[0].3
    );
    if runs[1] != runs[0] || runs[2] != runs[0] {
        return Err("2-D grids give different results from 1-D grids".into());
    }
    Ok(())
}

/// Terrain only: nothing to dispatch, nothing to read, and no error.
fn no_bodies(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    // A scene file must have a body; a model built in code need not.
    let mut scene = cube_scene(Integrator::SymplecticEuler, 0.001, 0.01, PLANE);
    scene.bodies.clear();
    let (model, state) = Model::build(&scene);
    let mut g = open(gpu, &model, &state)?;
    g.advance(10).map_err(step_error)?;
    let e = g.energies().map_err(step_error)?;
    let s = g.state().map_err(step_error)?.clone();
    if !s.x.is_empty() || e.total() != 0.0 || g.steps_taken() != 10 {
        return Err(format!("{s:?} {e:?}").into());
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Implicit Euler

/// A 3×3×3 cube (the CPU's `perturbed_cube` of tests/implicit.rs): uneven masses and
/// stiffnesses, positions perturbed by up to 3 cm (some springs compressed, some stretched),
/// random velocities, drag 0.3, h = 10 ms; every input rounded to f32 so that both solvers see
/// the same numbers.
fn implicit_cube() -> (Model, State) {
    let scene = Scene::from_toml(
        r#"
[simulation]
integrator = "implicit-euler"
dt = 0.01
duration = 0.1
drag = 0.3
[[body]]
kind = "cuboid"
size = [0.4, 0.4, 0.4]
resolution = [3, 3, 3]
center = [0.0, 1.0, 0.0]
mass = 2.0
structural = { stiffness = 400.0, damping = 0.8 }
shear = { stiffness = 400.0, damping = 0.8 }
bending = { stiffness = 400.0, damping = 0.8 }
"#,
        "t.toml".as_ref(),
    )
    .expect("valid");
    let (mut model, state) = Model::build(&scene);
    let mut rng = Rng::new(42);
    let f32r = |x: f64| x as f32 as f64;
    for i in 0..model.len() {
        model.mass[i] = f32r(0.05 + 0.05 * (rng.signed() + 1.0));
        model.inv_mass[i] = 1.0 / model.mass[i];
    }
    let springs = model.springs_mut();
    for s in 0..springs.len() {
        springs.stiffness[s] = f32r(springs.stiffness[s] * (1.0 + 0.5 * rng.signed()));
        springs.damping[s] = f32r(springs.damping[s] * (1.0 + 0.5 * rng.signed()));
        springs.rest[s] = f32r(springs.rest[s]);
    }
    let state = perturbed(&state, 42, 0.03, 1.0);
    (model, state)
}

/// The GPU's assembly (b, block-Jacobi inverse) and product A p against the CPU's `System` on
/// the same input. Errors are relative to the scale of each quantity: b against
/// h(m|g| + drag·m|v| + Σ|g_s|), A p against m(1 + h·drag)|p_i| + Σ(β + γ)(|p_a| + |p_b|), and
/// each inverse block against its largest entry.
fn implicit_system_twin(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    use softbody_cpu::integrators::implicit_euler::system::System;
    let (model, state) = implicit_cube();
    let n = model.len();
    let mut rng = Rng::new(7);
    let p: Vec<DVec3> = (0..n).map(|_| f32_exact(rng.vec(1.0))).collect();
    let mut g = open(gpu, &model, &state)?;
    let (gb, gdiag, gap) = g.debug_implicit_system(&p).map_err(step_error)?;
    let mut sys = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    sys.assemble(&model, (None, None), &state.x, &state.v, &mut b);
    let mut ap = vec![DVec3::ZERO; n];
    sys.apply(&model, &p, &mut ap);
    let compressed = (0..model.springs().len())
        .filter(|&s| sys.gamma[s] == 0.0)
        .count();
    println!(
        "{n} particles, {} springs ({compressed} compressed: γ = 0)",
        model.springs().len()
    );
    let b_scale = rhs_scale(&model, &state.x, &state.v);
    let (rb, ab) = max_errors(
        gb.iter().map(|v| v.as_dvec3()),
        b.iter().copied(),
        b_scale.into_iter(),
    );
    let ap_scale = product_scale(&model, &p);
    let (rap, aap) = max_errors(
        gap.iter().map(|v| v.as_dvec3()),
        ap.iter().copied(),
        ap_scale.into_iter(),
    );
    let (mut rinv, mut ainv, mut rmd) = (0.0f64, 0.0f64, 0.0f64);
    for (i, d) in gdiag.iter().enumerate() {
        let gm = inverse_block(*d);
        let cm = sys.inv_diag[i];
        let largest = cm
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, x| a.max(x.abs()));
        let err = (gm - cm)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, x| a.max(x.abs()));
        ainv = ainv.max(err);
        rinv = rinv.max(err / largest);
        rmd = rmd.max((f64::from(d[3]) - sys.mass_diag[i]).abs() / sys.mass_diag[i]);
    }
    // What the f32 state resolves of b_i, ρ_i² = Σ_s (h k_s ε_s)² with ε_s half a ulp of the
    // largest coordinate of the spring's ends in f32 (the CG's floor; docs/physics.md).
    let half_ulp = |a: f32| f64::from(f32::from_bits(a.to_bits() + 1) - a) / 2.0;
    let largest = |p: DVec3| p.as_vec3().abs().max_element();
    let sp = model.springs();
    let mut rho2 = vec![0.0f64; n];
    for s in 0..sp.len() {
        let (a, b) = (sp.a[s] as usize, sp.b[s] as usize);
        let eps = half_ulp(largest(state.x[a]).max(largest(state.x[b])));
        let term = (model.simulation.dt * sp.stiffness[s] * eps).powi(2);
        rho2[a] += term;
        rho2[b] += term;
    }
    let rres = (gdiag.iter().zip(&rho2))
        .map(|(d, r)| (f64::from(d[7]) - r).abs() / r)
        .fold(0.0f64, f64::max);
    check("implicit system: b", rb, ab, STAGE_BOUND)?;
    check("implicit system: A p", rap, aap, STAGE_BOUND)?;
    check("implicit system: resolution of b", rres, rres, STAGE_BOUND)?;
    check("implicit system: m(1 + h·drag)", rmd, rmd, STAGE_BOUND)?;
    check(
        "implicit system: block-Jacobi inverse",
        rinv,
        ainv,
        STAGE_BOUND,
    )
}

/// The CPU's filtered PCG residual of `dv`, in f64: sqrt(rᵀP⁻¹r / scale) with r = S(b − A dv).
fn true_residual(
    sys: &mut softbody_cpu::integrators::implicit_euler::system::System,
    model: &Model,
    constraints: &[softbody_cpu::integrators::implicit_euler::cg::Constraint],
    b: &[DVec3],
    dv: &[DVec3],
    scale: f64,
) -> f64 {
    let mut a_dv = vec![DVec3::ZERO; dv.len()];
    sys.apply(model, dv, &mut a_dv);
    let delta: f64 = (0..dv.len())
        .map(|i| {
            let r = constraints[i].filter(b[i] - a_dv[i]);
            r.dot(sys.inv_diag[i] * r)
        })
        .sum();
    (delta / scale).sqrt()
}

/// One filtered PCG solve on the GPU against the CPU's `CgProblem::solve` on the same system
/// (the cube of `implicit_system_twin`, h = 10 ms): about a third of the particles free, a third
/// with a normal constraint (random unit normal, prescribed normal Δv) and a third fixed
/// (prescribed Δv), a warm start in the free directions. Checks: the prescribed components are
/// exact; the GPU's recursive residual is below CG_TOLERANCE_F32 (it stops there); the true
/// residual of its Δv, in f64, is below 2·CG_TOLERANCE_F32 (the f32 recursion drifts from it);
/// its Δv matches the CPU's 1e-8 solution to 5e-5 of max|Δv|. Measured on llvmpipe (Vulkan,
/// GL): 10 iterations (the CPU: 10 at 1e-5, 15 at 1e-8), residual 5.3e-6 (true 5.3e-6), Δv
/// within 7.8e-6 of max|Δv|, prescribed parts exact. Prints the iterations of both (the CPU also at the GPU's
/// tolerance).
/// A CG iteration on a model without contact between bodies is three dispatches: the fused
/// product (each particle computing its springs' terms as it gathers them, then filtering
/// q = S A c and summing cᵀq's partials), cg_advance (which computes α itself) and
/// cg_direction (which computes β itself and writes the next grids). It took seven while cᵀq,
/// α and β had kernels of their own and the product two passes (`fused.rs` checks that the two
/// passes take one dispatch more per chunk).
fn implicit_cg_dispatches(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = implicit_cube();
    let mut g = open(gpu, &model, &state)?;
    let one = g.debug_cg_iteration_dispatches(1).map_err(step_error)?;
    let ten = g.debug_cg_iteration_dispatches(10).map_err(step_error)?;
    ensure(one == 3 && ten == 30, || {
        format!("{one} dispatches for one CG iteration, {ten} for ten")
    })
}

fn implicit_cg_twin(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    use softbody_cpu::integrators::implicit_euler::CG_TOLERANCE;
    use softbody_cpu::integrators::implicit_euler::cg::{self, Constraint, Scratch};
    use softbody_cpu::integrators::implicit_euler::system::System;
    use softbody_gpu::CG_TOLERANCE_F32;
    let (model, state) = implicit_cube();
    let n = model.len();
    let mut sys = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    sys.assemble(&model, (None, None), &state.x, &state.v, &mut b);
    let b: Vec<DVec3> = b.into_iter().map(f32_exact).collect();
    let mut rng = Rng::new(11);
    let (mut constraints, mut z, mut warm) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..n {
        let (c, zi) = match i % 3 {
            0 => (Constraint::Free, DVec3::ZERO),
            1 => {
                // A random axis: unit in f32 and f64 alike, so both filter with the same
                // projector (an f32-rounded oblique normal is not unit in f64).
                let axis = (rng.signed().abs() * 3.0) as usize % 3;
                let mut nrm = DVec3::ZERO;
                nrm[axis] = if rng.signed() < 0.0 { -1.0 } else { 1.0 };
                (Constraint::Normal(nrm), f32_exact(nrm * 0.3 * rng.signed()))
            }
            _ => (Constraint::Fixed, f32_exact(rng.vec(0.2))),
        };
        constraints.push(c);
        z.push(zi);
        warm.push(f32_exact(c.filter(rng.vec(0.05))));
    }
    let mut g = open(gpu, &model, &state)?;
    let (gdv, scalars) = g
        .debug_implicit_solve(&constraints, &b, &z, &warm)
        .map_err(step_error)?;
    let solve = |tol: f64| {
        let mut sys = System::new(&model);
        let mut bb = vec![DVec3::ZERO; n];
        sys.assemble(&model, (None, None), &state.x, &state.v, &mut bb);
        let mut dv = warm.clone();
        let mut scratch = Scratch::new(n);
        let out = cg::CgProblem {
            tolerance: tol,
            ..cg::CgProblem::new(&mut sys, &model, &constraints, &b, &z)
        }
        .solve(&mut dv, &mut scratch);
        (dv, out)
    };
    let (cdv, cpu_out) = solve(CG_TOLERANCE);
    let (_, cpu_loose) = solve(f64::from(CG_TOLERANCE_F32));
    // The scale the CPU measures its residual against: max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀).
    let mut start: Vec<DVec3> = (0..n)
        .map(|i| constraints[i].filter(warm[i]) + z[i])
        .collect();
    let delta0: f64 = (0..n)
        .map(|i| {
            let sb = constraints[i].filter(b[i]);
            sb.dot(constraints[i].filter(sys.inv_diag[i] * sb))
        })
        .sum();
    let r0 = true_residual(&mut sys, &model, &constraints, &b, &start, 1.0);
    let scale = delta0.max(r0 * r0);
    start.clear();
    let gpu_true = true_residual(&mut sys, &model, &constraints, &b, &gdv, scale);
    let cpu_true = true_residual(&mut sys, &model, &constraints, &b, &cdv, scale);
    let mut prescribed = 0.0f64;
    for i in 0..n {
        let fixed_part = gdv[i] - constraints[i].filter(gdv[i]);
        prescribed = prescribed.max((fixed_part - z[i]).length());
    }
    let largest = cdv.iter().fold(0.0f64, |a, v| a.max(v.length()));
    let (_, adv) = max_errors(
        gdv.iter().copied(),
        cdv.iter().copied(),
        std::iter::repeat(largest),
    );
    println!(
        "CG: GPU {} iterations to a relative residual of {:.2e} (its own, f32; tolerance {:e}), \
         true residual in f64 {gpu_true:.2e}; CPU {} iterations to {:.2e} (tolerance {:e}), \
         {} iterations at the GPU's tolerance; |Δv_gpu − Δv_cpu| ≤ {adv:.2e} m/s \
         ({:.2e} of max |Δv| = {largest:.3} m/s); CPU true residual {cpu_true:.2e}; \
         prescribed components off by {prescribed:.2e}",
        scalars.iterations,
        scalars.relative_residual(),
        CG_TOLERANCE_F32,
        cpu_out.iterations,
        cpu_out.relative_residual,
        CG_TOLERANCE,
        cpu_loose.iterations,
        adv / largest,
    );
    let mut failures = Vec::new();
    if scalars.relative_residual() > f64::from(CG_TOLERANCE_F32) {
        failures.push(format!(
            "GPU residual {:e} above the tolerance",
            scalars.relative_residual()
        ));
    }
    if gpu_true > 2.0 * f64::from(CG_TOLERANCE_F32) {
        failures.push(format!("true residual of the GPU's Δv {gpu_true:e}"));
    }
    if adv > 5e-5 * largest {
        failures.push(format!("Δv differs by {adv:e}"));
    }
    // Prescribed parts: z exactly, up to the rounding of S p + z in f32.
    if prescribed > 1e-6 {
        failures.push(format!("prescribed components off by {prescribed:e}"));
    }
    if failures.is_empty() {
        Ok(())
    } else {
        Err(failures.join("; ").into())
    }
}

/// The stiff 10³ cube of the CPU's `the_projected_warm_start_keeps_the_bounces_solves_short`
/// (k_s = 1e4 N/m, h = 1/60 s, dropped 0.5 m onto a plane with k_r = 0.5): over its 120 steps
/// (the fall, the bounces, the rest) CG stops at what the f32 state resolves of b and starts
/// from the warm start projected on the last three steps' Δv: at most 9 iterations a step
/// (6.0 measured on lavapipe; 15.1 from the last Δv alone, 40.0 without the floor as well,
/// where the rounding of x took 25–33 a step in free fall from an exact warm start), and the
/// cube comes to rest on the plane (with the floor at 1 instead of 1e-3 it took 77 a step and
/// did not).
fn implicit_bounces(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    use softbody_scene::SpringParams;
    use softbody_testkit::scenes::{cuboid, cuboid_body, plane, scene, simulation};
    let mut sim = simulation(Integrator::ImplicitEuler, 1.0 / 60.0);
    sim.contact_distance = 0.0;
    let params = SpringParams {
        stiffness: 1e4,
        damping: 5.0,
    };
    let cube = cuboid(DVec3::ONE, [10; 3], DVec3::new(0.5, 1.0, 0.5), 1.0, params);
    let (model, state) = Model::build(&scene(
        sim,
        vec![cuboid_body(cube)],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.5, 0.0)],
    ));
    let mut g = open(gpu, &model, &state)?;
    g.advance(120).map_err(step_error)?;
    let per_step = g.statistics().cg_iterations as f64 / 120.0;
    let st = g.state().map_err(step_error)?;
    let speed = st.v.iter().fold(0.0f64, |m, v| m.max(v.length()));
    let lowest = st.x.iter().fold(f64::INFINITY, |m, x| m.min(x.y));
    println!(
        "{per_step:.2} CG iterations a step; at 2 s |v| ≤ {speed:.2e} m/s, lowest y {lowest:.2e} m"
    );
    ensure(per_step <= 9.0, || {
        format!("{per_step} CG iterations a step")
    })?;
    ensure(speed < 1e-4 && lowest.abs() < 1e-4, || {
        format!("not at rest on the plane: |v| ≤ {speed} m/s, lowest y {lowest} m")
    })
}

/// 0.5 s of the 4×4×4 cube landing on a plane or a slope under implicit Euler at h = 2 ms, GPU
/// frames against CPU frames. The CPU solves to 1e-8, the GPU to CG_TOLERANCE_F32 = 1e-5
/// (relative), so the runs differ by the solve's tolerance each step as well as by f32
/// rounding; contacts are decided by thresholds (activation, release, stick/slip), see the
/// bounds. Prints the CG counts of both (the GPU takes fewer iterations at its looser
/// tolerance, in the same number of solves: the same active-set rounds).
fn run_implicit(gpu: &Arc<Gpu>, terrain: &str) -> Result<(), Failed> {
    let terrain_name = if terrain == PLANE { "plane" } else { "slope" };
    let scene = cube_scene(Integrator::ImplicitEuler, 2e-3, 0.5, terrain);
    let run = side_by_side(gpu, &scene)?;
    let name = format!("implicit-euler on the {terrain_name}");
    println!("{name}: {run}");
    IMPLICIT_RUN.check(&name, &run)
}

/// Bounds of the implicit runs against the CPU (see `run_implicit`): about ten times what was
/// measured on llvmpipe via Vulkan and GL (at most 2.0e-6 m per particle, 6.2e-6 of the peak
/// speed, 1.3e-6 m for the centre of mass, 2.5e-7 of the energy scale, on the slope; the plane
/// agrees better). The particles rest on the surface inside the contact band, so activation
/// and release keep their margins, and the stick/slip decisions agree.
const IMPLICIT_RUN: RunBounds = RunBounds {
    position: 2e-5,
    velocity: 1e-4,
    center: 2e-5,
    energy: 5e-6,
};

/// Implicit Euler on 2-D grids (grids forced one or two workgroups wide, as in
/// `two_dimensional_grids`), 20 steps of the 8×8×8 cube falling towards the slope: the
/// indirect CG dispatches and the partial sums of idle workgroups give the same steps, energies
/// and CG counts, bit for bit. The active-set kernels run, with no contact yet (contacts on
/// lavapipe cost ~30 s here; the runs above cover them on 1-D grids, and every kernel indexes
/// particles through the same `thread_of`).
fn implicit_two_dimensional_grids(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let scene = cube_scene_of(8, Integrator::ImplicitEuler, 2e-3, 0.1, SLOPE);
    same_bits_on_every_grid_width(gpu, &scene, 20)
}
