//! The fused explicit step (`shaders/explicit.wgsl` with `fused`,
//! `softbody_gpu::integrators::fused`): one dispatch per integrator stage, each particle gathering
//! its springs' forces from its neighbours, with the update, the collision response and the
//! finiteness check in the same kernel.
//!
//! - Against the CPU, every explicit integrator, on a slope (contact and friction from the
//!   first step) with pinned particles: within the twin tests' bounds for smooth contact
//!   (`twins.rs`: 1e-5 m per particle, 5e-4 of the peak speed).
//! - Against the per-spring path on the GPU (`GpuOptions::per_spring`), the gather through the
//!   adjacency (`GpuOptions::gather`), with restitution and pinned particles, over submissions
//!   of odd and even step counts (the Euler methods' ping-pong and its copy back): the same
//!   bits, since each spring force is the same call on the same inputs, gathered in the same
//!   order.
//! - The stencil (every body a lattice: the default for these scenes) against the gather: the
//!   same bits, states and energies, for cuboids of several shapes (2- and 3-wide axes, where
//!   offsets share a linear offset), several bodies, a mesh body (masked lattice), pinned
//!   particles and terrain contact.
//! - Run to run: the same bits.
//! - An adapter that cannot bind the fused kernels' buffers (WebGPU's minimum of 8 storage
//!   buffers per stage) takes the per-spring path.
//! - The design's figures: 1, 2 and 4 dispatches per step, less traffic than the per-spring
//!   path, and the stencil less than the gather.
//! - The stencil route's energies (`energy_lattices`, per particle over the lattices) against
//!   the CPU's and the gather's, and that route holding no spring list, on the host or the
//!   device.
//! - Implicit Euler's fused product (`shaders/fused_product.wgsl`) against its two passes
//!   (`GpuOptions::per_spring`), with one spring chunk and with three: the same bits, and one
//!   dispatch fewer per CG iteration.

mod common;

use std::process::ExitCode;
use std::sync::Arc;

use common::{BOUNCY_PLANE, SLOPE, step_error};
use softbody_cpu::{CpuSolver, energy};
use softbody_gpu::{Gpu, GpuOptions, GpuSolver};
use softbody_scene::{Energies, Integrator, Model, Scene, Solver, State, StepError};
use softbody_testkit::{Failed, GpuTest, Rng, ensure};

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
    let stencil: [GpuTest; 4] = [
        |gpu| stencil_against_gather(gpu, Integrator::ExplicitEuler),
        |gpu| stencil_against_gather(gpu, Integrator::SymplecticEuler),
        |gpu| stencil_against_gather(gpu, Integrator::Midpoint),
        |gpu| stencil_against_gather(gpu, Integrator::Rk4),
    ];
    for (((integrator, cpu), per_spring), stencil) in
        EXPLICIT.iter().zip(cpu).zip(per_spring).zip(stencil)
    {
        let name = integrator.to_string().replace('-', "_");
        tests.push((format!("fused_stencil_{name}_matches_the_cpu"), cpu));
        tests.push((
            format!("fused_gather_{name}_equals_the_per_spring_path"),
            per_spring,
        ));
        tests.push((format!("fused_stencil_{name}_equals_the_gather"), stencil));
    }
    tests.push(("fused_runs_repeat_bit_for_bit".into(), repeatable));
    tests.push((
        "an_adapter_at_webgpus_minimum_takes_the_per_spring_path".into(),
        minimum_adapter,
    ));
    tests.push(("fused_design_figures".into(), design_figures));
    tests.push((
        "stencil_energies_match_the_cpu_and_the_gather".into(),
        stencil_energies,
    ));
    tests.push((
        "the_stencil_route_builds_no_spring_list".into(),
        no_spring_list,
    ));
    tests.push((
        "implicit_eulers_fused_product_equals_its_two_passes".into(),
        fused_product,
    ));
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

/// Three bodies of contrasting shapes, apart (no contact radius: they never touch), each with
/// its own spring parameters, tilted onto the bouncy plane, a particle of each pinned: 2×3×5
/// (an axis 2 wide: the bending offset (2, 0, 0) has no spring, and shares its linear offset
/// with (0, 1, 0)), 3×2×4 (3 wide: (2, 0, 0) and (−1, 1, 0) share theirs) and 5×4×3.
fn bodies(integrator: Integrator) -> (Model, State) {
    let body = |name: &str, resolution: [u32; 3], x: f64, k: f64, pinned: u32| {
        format!(
            r#"
[[body]]
name = "{name}"
kind = "cuboid"
size = [0.1, 0.15, 0.2]
resolution = {resolution:?}
center = [{x}, 0.12, 0.0]
rotation = [20.0, 10.0, 25.0]
velocity = [0.2, -1.0, 0.1]
mass = 0.5
pinned = [{pinned}]
contact_radius = 0.0
structural = {{ stiffness = {k}, damping = 0.8 }}
shear = {{ stiffness = {}, damping = 0.5 }}
bending = {{ stiffness = {}, damping = 0.3 }}
"#,
            0.8 * k,
            0.5 * k
        )
    };
    let text = format!(
        r#"
[simulation]
integrator = "{integrator}"
dt = 2.5e-4
duration = 0.1
frame_rate = 20.0
gravity = [0.0, -9.81, 0.0]
drag = 0.1
{}{}{}{BOUNCY_PLANE}"#,
        body("a", [2, 3, 5], -0.5, 300.0, 0),
        body("b", [3, 2, 4], 0.0, 500.0, 23),
        body("c", [5, 4, 3], 0.5, 400.0, 7),
    );
    let scene = Scene::from_toml(&text, "test.toml".as_ref()).expect("test scene is valid");
    Model::build(&scene)
}

/// The torus of `scenes/torus-on-stairs.toml` as a mesh body (a masked lattice: a hole, and
/// points without a particle), tilted onto the bouncy plane, two particles pinned.
fn torus(integrator: Integrator) -> (Model, State) {
    let text = format!(
        r#"
[simulation]
integrator = "{integrator}"
dt = 2.5e-4
duration = 0.1
frame_rate = 20.0
gravity = [0.0, -9.81, 0.0]
drag = 0.1

[[body]]
name = "torus"
kind = "mesh"
file = "torus.obj"
cell = 0.07
center = [0.0, 0.12, 0.0]
rotation = [30.0, 0.0, 10.0]
velocity = [0.5, -1.0, 0.0]
density = 300.0
pinned = [0, 40]
structural = {{ stiffness = 600.0, damping = 2.0 }}
shear = {{ stiffness = 500.0, damping = 2.0 }}
bending = {{ stiffness = 300.0, damping = 1.0 }}
{BOUNCY_PLANE}"#
    );
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/test.toml");
    let scene = Scene::from_toml(&text, path.as_ref()).expect("test scene is valid");
    Model::build(&scene)
}

/// How the explicit integrators find their springs.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Path {
    /// Spring forces per spring, then the gather.
    PerSpring,
    /// Fused, through the spring records and the adjacency.
    Gather,
    /// Fused, on the lattices.
    Stencil,
}

fn open(gpu: &Arc<Gpu>, model: &Model, state: &State, path: Path) -> Result<GpuSolver, Failed> {
    let options = GpuOptions {
        per_spring: path == Path::PerSpring,
        gather: path == Path::Gather,
        ..GpuOptions::default()
    };
    let g = GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
        .map_err(|e| e.to_string())?;
    let want = match path {
        Path::PerSpring => "per-spring + gather",
        Path::Gather => "fused gather",
        Path::Stencil => "fused stencil",
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
    let mut g = open(gpu, &model, &state, Path::Stencil)?;
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

/// Relative difference allowed between the elastic energies of the stencil route
/// (`energy_lattices`: per particle, the springs starting at its point) and of the spring list
/// (`energy_springs`: per spring): the same f32 terms, bit for bit, added in other orders, a
/// per-thread sum of up to 13 and trees of 256 terms, all non-negative: a relative rounding of
/// about 25 u (1.5e-6).
const ELASTIC_ROUNDING: f64 = 1e-5;

/// Whether two runs' energies agree as their paths allow: bit for bit where both take their
/// elastic energy from the same kernel; where one is the stencil, the kinetic and
/// gravitational energies bit for bit (one kernel) and the elastic within
/// [`ELASTIC_ROUNDING`].
fn energies_agree(a: Path, b: Path, ea: &Energies, eb: &Energies) -> bool {
    if (a == Path::Stencil) == (b == Path::Stencil) {
        return ea == eb;
    }
    let largest = ea.elastic.abs().max(eb.elastic.abs());
    ea.kinetic.to_bits() == eb.kinetic.to_bits()
        && ea.gravitational.to_bits() == eb.gravitational.to_bits()
        && (ea.elastic - eb.elastic).abs() <= ELASTIC_ROUNDING * largest
}

/// Runs `model` by paths `a` and `b`: the same bits, states after every batch, the energies
/// as [`energies_agree`]; and the bodies moved.
fn same_bits(
    gpu: &Arc<Gpu>,
    (model, state): &(Model, State),
    a: Path,
    b: Path,
) -> Result<(), Failed> {
    let integrator = model.simulation.integrator;
    let first = batches(&mut open(gpu, model, state, a)?, &BATCHES)?;
    let second = batches(&mut open(gpu, model, state, b)?, &BATCHES)?;
    let (last, _) = first.last().expect("batches");
    let (dx, _) = differences(last, state);
    println!(
        "{integrator}, {} particles, {:?} and {:?}: {} steps, particles moved up to {dx:.3} m",
        model.len(),
        a,
        b,
        BATCHES.iter().sum::<u64>()
    );
    for (k, (f, p)) in first.iter().zip(&second).enumerate() {
        let (x, v) = differences(&f.0, &p.0);
        ensure(f.0 == p.0 && energies_agree(a, b, &f.1, &p.1), || {
            format!(
                "{integrator}: after batch {k} the {a:?} run differs from the {b:?} run \
                 (|Δx| {x:e}, |Δv| {v:e}; energies {:?} and {:?})",
                f.1, p.1
            )
        })?;
    }
    ensure(dx > 0.01, || "the bodies did not move".into())
}

/// The fused gather against the per-spring path: the same bits after every batch.
fn against_per_spring(gpu: &Arc<Gpu>, integrator: Integrator) -> Result<(), Failed> {
    let model = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
    same_bits(gpu, &model, Path::Gather, Path::PerSpring)
}

/// The stencil against the fused gather: the same bits after every batch, for the cube, three
/// cuboids of other shapes, and a mesh body.
fn stencil_against_gather(gpu: &Arc<Gpu>, integrator: Integrator) -> Result<(), Failed> {
    let (model, state) = bodies(integrator);
    let pinned = (0..model.len()).filter(|&i| model.inv_mass[i] == 0.0);
    ensure(model.bodies.len() == 3 && pinned.count() == 3, || {
        "three bodies, a particle of each pinned".into()
    })?;
    let torus = torus(integrator);
    let masked = torus.0.lattices().iter().any(|l| l.mask.is_some());
    ensure(masked, || "the torus is a masked lattice".into())?;
    for model in [
        cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE),
        (model, state),
        torus,
    ] {
        same_bits(gpu, &model, Path::Stencil, Path::Gather)?;
    }
    Ok(())
}

/// Each explicit integrator twice: the same bits.
fn repeatable(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    for integrator in EXPLICIT {
        let (model, state) = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
        let a = batches(&mut open(gpu, &model, &state, Path::Stencil)?, &BATCHES)?;
        let b = batches(&mut open(gpu, &model, &state, Path::Stencil)?, &BATCHES)?;
        ensure(a == b, || format!("{integrator}: two fused runs differ"))?;
    }
    Ok(())
}

/// With 8 storage buffers per stage (the fused kernels bind 11 to 13), every explicit
/// integrator takes the per-spring path, with the fused path's bits (and, holding the spring
/// list, its energies by `energy_springs`).
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
        let fused = batches(
            &mut open(gpu, &model, &state, Path::Stencil)?,
            &BATCHES[..3],
        )?;
        let fallback = batches(&mut g, &BATCHES[..3])?;
        let same = fused
            .iter()
            .zip(&fallback)
            .all(|(f, p)| f.0 == p.0 && energies_agree(Path::Stencil, Path::PerSpring, &f.1, &p.1));
        ensure(same, || {
            format!("{integrator}: the fallback differs from the fused run")
        })?;
    }
    Ok(())
}

/// Dispatches and bytes per step of each explicit integrator, stencil, gather and per-spring,
/// over 20 steps after the first (which also computes the response's band masks once).
fn design_figures(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    for (integrator, stages) in EXPLICIT.into_iter().zip([1, 1, 2, 4]) {
        let (model, state) = cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE);
        let mut figures = Vec::new();
        for path in [Path::Stencil, Path::Gather, Path::PerSpring] {
            let mut g = open(gpu, &model, &state, path)?;
            g.advance(1).and_then(|()| g.sync()).map_err(step_error)?;
            let before = g.statistics();
            g.advance(20).and_then(|()| g.sync()).map_err(step_error)?;
            let after = g.statistics();
            let dispatches = (after.dispatches - before.dispatches) as f64 / 20.0;
            let bytes =
                (after.device_bytes - before.device_bytes) as f64 / 20.0 / model.len() as f64;
            figures.push((dispatches, bytes));
        }
        let [
            (stencil, stencil_bytes),
            (fused, fused_bytes),
            (per_spring, per_spring_bytes),
        ] = figures[..]
        else {
            unreachable!("three paths")
        };
        println!(
            "{integrator}: stencil {stencil} dispatches, {stencil_bytes:.0} B per \
             particle-step; fused gather {fused}, {fused_bytes:.0} B; per-spring {per_spring}, \
             {per_spring_bytes:.0} B"
        );
        ensure(
            stencil == f64::from(stages)
                && fused == stencil
                && per_spring > fused
                && per_spring_bytes > fused_bytes
                && fused_bytes > stencil_bytes,
            || format!("{integrator}: {figures:?}"),
        )?;
    }
    Ok(())
}

/// The state perturbed by up to 2 cm and 1 m/s, rounded to f32 (what the GPU holds), so that
/// every spring is stretched or compressed and the CPU sees the GPU's input.
fn perturbed(state: &State, seed: u64) -> State {
    let mut rng = Rng::new(seed);
    let mut jitter = |p: &[glam::DVec3], by: f64| -> Vec<glam::DVec3> {
        p.iter()
            .map(|&p| (p + rng.vec(by)).as_vec3().as_dvec3())
            .collect()
    };
    State {
        x: jitter(&state.x, 0.02),
        v: jitter(&state.v, 1.0),
    }
}

/// The stencil route's energies on a perturbed state, for the cube, the three cuboids and the
/// mesh body: against the CPU's on the same state within 1e-5 of each energy's scale (the sum
/// of its terms' magnitudes, the twin tests' bound: f32 rounding of each term), against the
/// gather route's as [`energies_agree`] (the elastic energy by the other kernel), and twice
/// the same bits.
fn stencil_energies(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let integrator = Integrator::SymplecticEuler;
    for (name, (model, state)) in [
        ("cube", cube(integrator, 2.5e-4, 0.1, BOUNCY_PLANE)),
        ("three cuboids", bodies(integrator)),
        ("torus", torus(integrator)),
    ] {
        let state = perturbed(&state, 11);
        let mut g = open(gpu, &model, &state, Path::Stencil)?;
        let got = g.energies().map_err(step_error)?;
        let again = g.energies().map_err(step_error)?;
        let gather = open(gpu, &model, &state, Path::Gather)?
            .energies()
            .map_err(step_error)?;
        let want = energy::energies(&model, &state);
        let g_len = model.simulation.gravity.length();
        let gravitational_scale: f64 = (0..model.len())
            .map(|i| model.mass[i] * g_len * state.x[i].length())
            .sum();
        let mut elastic_scale = 0.0;
        model.for_each_spring(|a, b, rest, k, _| {
            let d = state.x[a as usize].distance(state.x[b as usize]);
            elastic_scale += 0.5 * k * (d + rest) * (d + rest);
        });
        println!(
            "{name}: {} particles, {} springs; elastic energy {:.6e} J on the stencil, {:.6e} J \
             on the gather, {:.6e} J on the CPU",
            model.len(),
            model.spring_count(),
            got.elastic,
            gather.elastic,
            want.elastic
        );
        ensure(want.elastic > 1e-3 * elastic_scale, || {
            format!("{name}: the springs are barely stretched")
        })?;
        for (what, got, want, scale) in [
            ("kinetic", got.kinetic, want.kinetic, want.kinetic),
            (
                "gravitational",
                got.gravitational,
                want.gravitational,
                gravitational_scale,
            ),
            ("elastic", got.elastic, want.elastic, elastic_scale),
        ] {
            let error = (got - want).abs();
            ensure(error <= 1e-5 * scale, || {
                format!(
                    "{name}: the {what} energy {got:e} J is {error:e} J from the CPU's {want:e} J \
                     ({:e} of its scale)",
                    error / scale
                )
            })?;
        }
        ensure(
            energies_agree(Path::Stencil, Path::Gather, &got, &gather),
            || format!("{name}: the stencil's energies {got:?}, the gather's {gather:?}"),
        )?;
        ensure(got == again, || {
            format!("{name}: two reductions of one state differ: {got:?}, {again:?}")
        })?;
    }
    Ok(())
}

/// The stencil route builds no spring list: the model the solver holds is as lean after it
/// opened, stepped and summed the energies as before (the gather route's grows by the list it
/// builds, so the check can fail), and the device holds at least 24 bytes per spring less
/// than on the gather (a 20-byte record and two adjacency words, less a mesh body's mask,
/// which only the stencil holds: a few words per lattice point). The gather holds no
/// per-spring vectors and no accelerations: 16 bytes per spring and per particle less than the
/// per-spring path, which for its part needs no second state pair (32 per particle). The
/// per-spring read-backs, which need the per-spring path's buffers, are refused on the fused
/// routes, not a panic.
fn no_spring_list(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    for (name, (model, state)) in [
        (
            "cube",
            cube(Integrator::SymplecticEuler, 2.5e-4, 0.1, BOUNCY_PLANE),
        ),
        ("torus", torus(Integrator::Rk4)),
    ] {
        let lean = model.memory_bytes();
        let mut g = open(gpu, &model, &state, Path::Stencil)?;
        g.advance(3).map_err(step_error)?;
        g.energies().map_err(step_error)?;
        g.state().map_err(step_error)?;
        let held = g.model().memory_bytes();
        ensure(held == lean, || {
            format!("{name}: the stencil route built the spring list ({lean} B, then {held} B)")
        })?;
        let mut gather = open(gpu, &model, &state, Path::Gather)?;
        ensure(gather.model().memory_bytes() > lean, || {
            format!("{name}: the gather built no spring list")
        })?;
        for (route, solver) in [("stencil", &mut g), ("gather", &mut gather)] {
            match solver.debug_spring_forces() {
                Err(StepError::Invalid(_)) => {}
                other => {
                    return Err(format!(
                        "{name}: spring forces read back on the {route}: {other:?}"
                    )
                    .into());
                }
            }
        }
        let per_spring = open(gpu, &model, &state, Path::PerSpring)?;
        let (m, n) = (model.spring_count() as u64, model.len() as u64);
        let (lean_device, listed_device, written_device) = (
            g.memory_bytes(),
            gather.memory_bytes(),
            per_spring.memory_bytes(),
        );
        println!(
            "{name}: {n} particles, {m} springs; device memory {:.0} B per particle on the \
             stencil, {:.0} B on the gather, {:.0} B on the per-spring path",
            lean_device as f64 / n as f64,
            listed_device as f64 / n as f64,
            written_device as f64 / n as f64
        );
        ensure(listed_device >= lean_device + 24 * m, || {
            format!("{name}: {lean_device} B on the stencil, {listed_device} B on the gather")
        })?;
        ensure(
            written_device == listed_device + 16 * (m + n) - 32 * n,
            || {
                format!(
                    "{name}: {listed_device} B on the gather, {written_device} B on the per-spring \
                 path"
                )
            },
        )?;
    }
    Ok(())
}

/// Implicit Euler on the bouncy plane (contacts from the first step, the active set changing)
/// with its product fused and in two passes: the same bits after every batch, CG iteration for
/// iteration, with the spring list in one chunk and in three (the fused product then reads each
/// spring's record and block from its chunk, `spring_at`/`block_at`). The fused product takes
/// one dispatch per product where the two passes take one per chunk and one more. On an
/// adapter allowing exactly the storage buffers of the assembly's gather (2k + 5 for k = 3
/// chunks), one fewer than the fused product of the CG's direction binds, the solver takes
/// the two passes, with the same bits.
fn fused_product(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cube(Integrator::ImplicitEuler, 0.01, 0.5, BOUNCY_PLANE);
    // 1,024 blocks of 32 bytes per binding: the cube's 2,556 springs in three chunks.
    for (chunks, max_binding_size) in [(1, None), (3, Some(32 * 1024))] {
        let run = |per_spring: bool, max_storage_buffers| -> Result<_, Failed> {
            let options = GpuOptions {
                per_spring,
                max_binding_size,
                max_storage_buffers,
                ..GpuOptions::default()
            };
            let mut g = GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
                .map_err(|e| e.to_string())?;
            let want = match per_spring || max_storage_buffers.is_some() {
                true => "matrix-free",
                false => "matrix-free, fused product",
            };
            let kernel = g.statistics().kernel;
            ensure(kernel == want, || format!("kernel {kernel}, want {want}"))?;
            let states = batches(&mut g, &[1, 2, 7, 40])?;
            Ok((states, g.statistics()))
        };
        let (fused, fused_stats) = run(false, None)?;
        let (two, two_stats) = run(true, None)?;
        // With one chunk that limit is 7, below what the force kernel binds (8): no implicit
        // model runs there.
        if chunks > 1 {
            let (limited, _) = run(false, Some(2 * chunks as u32 + 5))?;
            ensure(limited == two, || {
                format!("{chunks} chunk(s): the run at the assembly's limit differs")
            })?;
        }
        let (last, _) = fused.last().expect("batches");
        let (dx, _) = differences(last, &state);
        println!(
            "implicit Euler, {chunks} chunk(s): {} CG iterations, {} and {} dispatches \
             (fused, two passes), particles moved up to {dx:.3} m",
            fused_stats.cg_iterations, fused_stats.dispatches, two_stats.dispatches
        );
        for (k, (f, t)) in fused.iter().zip(&two).enumerate() {
            let (x, v) = differences(&f.0, &t.0);
            ensure(f == t, || {
                format!(
                    "{chunks} chunk(s): after batch {k} the fused product's run differs \
                     (|Δx| {x:e}, |Δv| {v:e}; energies {:?} and {:?})",
                    f.1, t.1
                )
            })?;
        }
        ensure(fused_stats.cg_iterations == two_stats.cg_iterations, || {
            "the CG iteration counts differ".into()
        })?;
        ensure(dx > 0.01, || "the cube did not move".into())?;
        // Every encoded product saves `chunks` dispatches: at least one per CG iteration.
        ensure(
            two_stats.dispatches >= fused_stats.dispatches + chunks * fused_stats.cg_iterations,
            || {
                format!(
                    "{} dispatches fused against {} in two passes over {} CG iterations",
                    fused_stats.dispatches, two_stats.dispatches, fused_stats.cg_iterations
                )
            },
        )?;
    }
    Ok(())
}
