//! GPU tests that need an adapter: each stage against its CPU twin on the same input, each
//! explicit integrator's run against the CPU's, and the instability record.
//!
//! A custom harness (libtest-mimic): without an adapter every test reports itself ignored
//! ("skipped: no GPU adapter"), unless `SOFTBODY_REQUIRE_GPU=1`, which makes a missing adapter a
//! failure. Each test prints the agreement it measured (`--nocapture` shows it).
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

use std::process::ExitCode;

use glam::DVec3;
use libtest_mimic::{Arguments, Completion, Failed, Trial};
use softbody_cpu::terrain::Surface;
use softbody_cpu::{CpuSolver, collision_response, energy, forces, spring_forces};
use softbody_gpu::GpuSolver;
use softbody_scene::{Integrator, Model, Scene, Solver, State, StepError};

type Test = fn() -> Result<(), Failed>;

fn main() -> ExitCode {
    let args = Arguments::from_args();
    let tests: Vec<(&str, Test)> = vec![
        ("stage_spring_forces", stage_spring_forces),
        ("stage_accelerations_with_contact_coulomb", || {
            stage_accelerations("coulomb")
        }),
        ("stage_accelerations_with_contact_viscous", || {
            stage_accelerations("viscous")
        }),
        ("stage_collision_response", stage_collision_response),
        ("stage_energies", stage_energies),
        ("one_step_explicit_euler", || {
            one_step(Integrator::ExplicitEuler)
        }),
        ("one_step_symplectic_euler", || {
            one_step(Integrator::SymplecticEuler)
        }),
        ("one_step_midpoint", || one_step(Integrator::Midpoint)),
        ("one_step_rk4", || one_step(Integrator::Rk4)),
        ("run_explicit_euler_plane", || {
            run_against_cpu(Integrator::ExplicitEuler, PLANE)
        }),
        ("run_explicit_euler_slope", || {
            run_against_cpu(Integrator::ExplicitEuler, SLOPE)
        }),
        ("run_explicit_euler_bouncy_plane", || {
            run_against_cpu(Integrator::ExplicitEuler, BOUNCY_PLANE)
        }),
        ("run_symplectic_euler_plane", || {
            run_against_cpu(Integrator::SymplecticEuler, PLANE)
        }),
        ("run_symplectic_euler_slope", || {
            run_against_cpu(Integrator::SymplecticEuler, SLOPE)
        }),
        ("run_symplectic_euler_bouncy_plane", || {
            run_against_cpu(Integrator::SymplecticEuler, BOUNCY_PLANE)
        }),
        ("run_midpoint_plane", || {
            run_against_cpu(Integrator::Midpoint, PLANE)
        }),
        ("run_midpoint_slope", || {
            run_against_cpu(Integrator::Midpoint, SLOPE)
        }),
        ("run_midpoint_bouncy_plane", || {
            run_against_cpu(Integrator::Midpoint, BOUNCY_PLANE)
        }),
        ("run_rk4_plane", || run_against_cpu(Integrator::Rk4, PLANE)),
        ("run_rk4_slope", || run_against_cpu(Integrator::Rk4, SLOPE)),
        ("run_rk4_bouncy_plane", || {
            run_against_cpu(Integrator::Rk4, BOUNCY_PLANE)
        }),
        (
            "instability_names_the_first_step_and_lowest_particle",
            instability_is_exact,
        ),
        (
            "instability_matches_the_cpu_on_a_nan",
            instability_matches_cpu,
        ),
        ("free_fall_is_exact_enough", free_fall),
        ("a_lost_device_is_reported_not_a_panic", lost_device),
        (
            "two_dimensional_grids_give_the_same_bits",
            two_dimensional_grids,
        ),
        ("a_scene_without_bodies_runs", no_bodies),
        ("readback_is_repeatable", repeatable),
    ];

    let adapter = softbody_gpu::device::Gpu::open().map(|gpu| gpu.name());
    let require = std::env::var("SOFTBODY_REQUIRE_GPU").is_ok_and(|v| v == "1");
    match &adapter {
        Ok(name) => eprintln!("GPU tests on {name}"),
        Err(e) => eprintln!("GPU tests: {e}"),
    }
    let trials = tests
        .into_iter()
        .map(|(name, test)| match &adapter {
            Ok(_) => Trial::test(name, test),
            Err(e) if require => {
                let message = format!("SOFTBODY_REQUIRE_GPU=1 but {e}");
                Trial::test(name, move || Err(message.into()))
            }
            Err(_) => Trial::ignorable_test(name, || {
                Ok(Completion::ignored_with("skipped: no GPU adapter"))
            }),
        })
        .collect();
    libtest_mimic::run(&args, trials).exit_code()
}

// ---------------------------------------------------------------------------------------------
// Scenes and inputs

const PLANE: &str = r#"
[[terrain]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
friction = 0.5
restitution = 0.0
"#;

/// The plane with restitution: landing particles bounce up to the edge of the contact band.
const BOUNCY_PLANE: &str = r#"
[[terrain]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
friction = 0.5
restitution = 0.2
"#;

const SLOPE: &str = r#"
[[terrain]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.4, 1.0, 0.0]
friction = 0.3
restitution = 0.0
"#;

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

/// A deterministic generator (64-bit LCG), uniform in [−1, 1).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
    fn vec(&mut self, scale: f64) -> DVec3 {
        DVec3::new(self.next(), self.next(), self.next()) * scale
    }
}

/// Rounds through f32, so that the CPU and GPU see the same input.
fn f32_exact(v: DVec3) -> DVec3 {
    v.as_vec3().as_dvec3()
}

/// The state perturbed: positions by up to `dx`, velocities up to `dv`, rounded to f32.
fn perturbed(state: &State, seed: u64, dx: f64, dv: f64) -> State {
    let mut rng = Lcg(seed);
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

fn gpu(model: &Model, state: &State) -> Result<GpuSolver, Failed> {
    GpuSolver::new(model.clone(), state.clone()).map_err(|e| e.to_string().into())
}

fn step_error(e: StepError) -> Failed {
    e.to_string().into()
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

fn stage_spring_forces() -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, "");
    let (model, state) = Model::build(&scene);
    let state = perturbed(&state, 1, 0.02, 1.0);
    let mut g = gpu(&model, &state)?;
    let got = g.debug_spring_forces().map_err(step_error)?;
    let mut want = vec![DVec3::ZERO; model.springs.len()];
    spring_forces::compute(&model.springs, &state.x, &state.v, &mut want);
    let s = &model.springs;
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
fn stage_accelerations(friction_model: &str) -> Result<(), Failed> {
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
    let mut g = gpu(&model, &state)?;
    let got = g.debug_accelerations().map_err(step_error)?;
    let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
    let mut per_spring = vec![DVec3::ZERO; model.springs.len()];
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
            .adjacency
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

fn stage_collision_response() -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, PLANE);
    let (model, state) = Model::build(&scene);
    let mut state = perturbed(&state, 3, 0.01, 1.0);
    let lowest = state.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
    for x in &mut state.x {
        x.y = f32_exact(*x - DVec3::new(0.0, lowest + 0.05, 0.0)).y;
    }
    let mut g = gpu(&model, &state)?;
    g.debug_collision_response().map_err(step_error)?;
    let got = g.state().map_err(step_error)?.clone();
    let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
    let mut want = state.clone();
    collision_response::respond(&model, &surfaces, &mut want.x, &mut want.v);
    let moved = (0..model.len())
        .filter(|&i| want.x[i] != state.x[i])
        .count();
    println!(
        "{moved} of {} particles moved back onto the plane",
        model.len()
    );
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

fn stage_energies() -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, "");
    let (model, state) = Model::build(&scene);
    let state = perturbed(&state, 4, 0.02, 1.0);
    let mut g = gpu(&model, &state)?;
    let got = g.energies().map_err(step_error)?;
    let want = energy::energies(&model, &state);
    let g_len = model.simulation.gravity.length();
    // Scales: sums of the terms' magnitudes.
    let kinetic_scale = want.kinetic;
    let grav_scale: f64 = (0..model.len())
        .map(|i| model.mass[i] * g_len * state.x[i].length())
        .sum();
    let s = &model.springs;
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
fn one_step(integrator: Integrator) -> Result<(), Failed> {
    let scene = cube_scene(integrator, 1e-3, 0.1, "");
    let (model, state) = Model::build(&scene);
    let state = perturbed(&state, 5, 0.02, 1.0);
    let mut g = gpu(&model, &state)?;
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
            .adjacency
            .of(i)
            .iter()
            .map(|&e| {
                let s = (e >> 1) as usize;
                let sp = &model.springs;
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
fn run_against_cpu(integrator: Integrator, terrain: &str) -> Result<(), Failed> {
    let (terrain_name, bounds) = match terrain {
        PLANE => ("plane", SMOOTH),
        SLOPE => ("slope", SMOOTH),
        _ => ("bouncy plane", BOUNCY),
    };
    let scene = cube_scene(integrator, 2.5e-4, 0.5, terrain);
    let (model, state) = Model::build(&scene);
    let sim = model.simulation;
    let total_mass: f64 = model.mass.iter().sum();
    let mut g = gpu(&model, &state)?;
    let mut cpu = CpuSolver::new(model.clone(), state, Some(1)).map_err(|e| e.to_string())?;
    let e0 = cpu.energies().map_err(step_error)?;
    let scale = softbody_scale(&mut cpu, &e0)?;
    let (mut dx, mut dv, mut dc, mut peak, mut de) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let started = std::time::Instant::now();
    for k in 0..sim.frame_count() {
        let target = sim.frame_step(k);
        let n = target - g.steps_taken();
        g.advance(n).map_err(step_error)?;
        cpu.advance(n).map_err(step_error)?;
        let (eg, ec) = (
            g.energies().map_err(step_error)?,
            cpu.energies().map_err(step_error)?,
        );
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
    let name = format!("{integrator} on the {terrain_name}");
    println!(
        "{name}: {} steps ({:.2} s for both): max |Δx| {dx:.2e} m, max |Δv| {dv:.2e} m/s \
         ({:.2e} of the peak speed {peak:.2} m/s), centre of mass {dc:.2e} m, \
         total energy {de:.2e} J ({:.2e} of the scale {scale:.2} J)",
        sim.steps(),
        started.elapsed().as_secs_f64(),
        dv / peak,
        de / scale,
    );
    if dx > bounds.position
        || dv > bounds.velocity * peak
        || dc > bounds.center
        || de > bounds.energy * scale
    {
        return Err(format!(
            "{name}: the GPU run is further from the CPU's than the bounds ({} m per particle, \
             {} of the peak speed, {} m centre of mass, {} of the energy scale)",
            bounds.position, bounds.velocity, bounds.center, bounds.energy
        )
        .into());
    }
    Ok(())
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

/// Free fall under RK4 (exact for constant acceleration): the f32 run stays within f32 rounding.
fn free_fall() -> Result<(), Failed> {
    let scene = Scene::from_toml(
        "[simulation]\nintegrator = \"rk4\"\ndt = 0.001\nduration = 1.0\n[[body]]\n\
         kind = \"particles\"\npositions = [[0.0, 10.0, 0.0]]\nmasses = [1.0]\n",
        "t.toml".as_ref(),
    )
    .expect("valid");
    let (model, state) = Model::build(&scene);
    let mut g = gpu(&model, &state)?;
    g.advance(1000).map_err(step_error)?;
    let y = g.state().map_err(step_error)?.x[0].y;
    let want = 10.0 - 0.5 * 9.81;
    println!(
        "free fall: y = {y}, exact {want}, error {:.3e}",
        (y - want).abs()
    );
    if (y - want).abs() > 1e-4 {
        return Err(format!("free fall: y = {y}, want {want}").into());
    }
    Ok(())
}

/// The same run twice gives the same bits (gathers in a fixed order, no float atomics).
fn repeatable() -> Result<(), Failed> {
    let scene = cube_scene(Integrator::Rk4, 2.5e-4, 0.1, PLANE);
    let (model, state) = Model::build(&scene);
    let mut runs = Vec::new();
    for _ in 0..2 {
        let mut g = gpu(&model, &state)?;
        g.advance(300).map_err(step_error)?;
        let e = g.energies().map_err(step_error)?;
        runs.push((g.state().map_err(step_error)?.clone(), e));
    }
    if runs[0] != runs[1] {
        return Err("two identical GPU runs differ".into());
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Instability

/// Five free particles (no gravity) flying up with exactly representable f32 numbers: particles
/// 3 and 4 overflow their position at step 300 (x = 2¹¹⁷(1748 + k), f32 max just below 2¹²⁸ =
/// 2¹¹⁷·2048), particle 1 at step 400, particles 0 and 2 never. The report must be step 300,
/// particle 3, position, across a submission boundary (256 steps per submission).
fn instability_is_exact() -> Result<(), Failed> {
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
    let mut g = gpu(&model, &state)?;
    match g.advance(1000) {
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
fn instability_matches_cpu() -> Result<(), Failed> {
    let scene = cube_scene(Integrator::Midpoint, 1e-3, 0.1, PLANE);
    let (model, mut state) = Model::build(&scene);
    state.v[37] = DVec3::new(0.0, f64::NAN, 0.0);
    let mut g = gpu(&model, &state)?;
    let mut cpu = CpuSolver::new(model, state, Some(1)).map_err(|e| e.to_string())?;
    let (got, want) = (g.advance(10), cpu.advance(10));
    println!("GPU: {got:?}\nCPU: {want:?}");
    match (got, want) {
        (Err(StepError::Unstable(a)), Err(StepError::Unstable(b))) if a == b => Ok(()),
        (got, want) => Err(format!("GPU {got:?} differs from CPU {want:?}").into()),
    }
}

/// After the device is gone, every call reports StepError::Device; nothing panics.
fn lost_device() -> Result<(), Failed> {
    let scene = cube_scene(Integrator::SymplecticEuler, 1e-3, 0.1, PLANE);
    let (model, state) = Model::build(&scene);
    let mut g = gpu(&model, &state)?;
    g.advance(10).map_err(step_error)?;
    g.debug_destroy_device();
    let results = [
        g.advance(10).err(),
        g.energies().err(),
        g.state().err(),
        g.advance(1).err(),
    ];
    for (call, result) in ["advance", "energies", "state", "advance again"]
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
fn two_dimensional_grids() -> Result<(), Failed> {
    let scene = cube_scene_of(8, Integrator::Rk4, 2.5e-4, 0.1, BOUNCY_PLANE);
    let (model, state) = Model::build(&scene);
    let mut runs = Vec::new();
    for width in [None, Some(1), Some(2)] {
        let mut g = GpuSolver::with_grid_width(model.clone(), state.clone(), width)
            .map_err(|e| e.to_string())?;
        g.advance(200).map_err(step_error)?;
        let e = g.energies().map_err(step_error)?;
        runs.push((g.state().map_err(step_error)?.clone(), e));
    }
    println!(
        "{} particles, {} springs; energies {:?}",
        model.len(),
        model.springs.len(),
        runs[0].1
    );
    if runs[1] != runs[0] || runs[2] != runs[0] {
        return Err("2-D grids give different results from 1-D grids".into());
    }
    Ok(())
}

/// Terrain only: nothing to dispatch, nothing to read, and no error.
fn no_bodies() -> Result<(), Failed> {
    let scene = Scene::from_toml(
        &format!("[simulation]\ndt = 0.001\nduration = 0.01\n{PLANE}"),
        "t.toml".as_ref(),
    )
    .map_err(|e| e.to_string())?;
    let (model, state) = Model::build(&scene);
    let mut g = gpu(&model, &state)?;
    g.advance(10).map_err(step_error)?;
    let e = g.energies().map_err(step_error)?;
    let s = g.state().map_err(step_error)?.clone();
    if !s.x.is_empty() || e.total() != 0.0 || g.steps_taken() != 10 {
        return Err(format!("{s:?} {e:?}").into());
    }
    Ok(())
}
