//! Contact between bodies (`softbody_cpu::body_contact`), for every integrator on both
//! backends: momentum in a head-on collision, the restitution law of two particles, the same
//! bits for any thread count (the GPU: run to run), a stack's landing and its rest, a folding
//! bar's self-contact, a pile in a bowl.
//!
//! The long runs are heavy on the GPU (minutes of lavapipe each): the stack's 4 s rest and the
//! bar's whole 1.6 s fold. The GPU's fast tier checks the same bounds over the stack's landing
//! and over the window of the bar's fold, started from the CPU's state. The GPU's fast tier runs
//! symplectic and implicit Euler; its explicit Euler, midpoint and RK4 trials are heavy
//! ([`FAST_ON_THE_GPU`]). The pile runs on the
//! CPU only: 100,000 steps of 750 particles in contact are beyond a heavy tier on lavapipe, so
//! its GPU bounds have never been measured.

use std::process::ExitCode;

use glam::DVec3;
use softbody::scene::{BodyContact, SpringParams};
use softbody::{CpuSolver, Integrator, Model, Scene, Solver};
use softbody_testkit::scenes::*;
use softbody_testkit::{Backend, Failed, Kind, Law, all, ensure};

fn main() -> ExitCode {
    softbody_testkit::run(
        "body contact",
        [
            Law::per_integrator(
                "a_head_on_collision_conserves_momentum",
                a_head_on_collision_conserves_momentum,
            )
            .fast_only_for(Kind::Gpu, FAST_ON_THE_GPU),
            Law::per_integrator(
                "two_particles_rebound_at_the_restitution",
                two_particles_rebound_at_the_restitution,
            )
            .fast_only_for(Kind::Gpu, FAST_ON_THE_GPU),
            Law::per_integrator(
                "body_contact_gives_the_same_bits_for_any_thread_count",
                same_bits_for_any_thread_count,
            )
            .fast_only_for(Kind::Gpu, FAST_ON_THE_GPU),
            Law::per_integrator(
                "a_stack_of_two_cubes_lands_without_interpenetrating",
                a_stack_lands_without_interpenetrating,
            )
            .fast_only_for(Kind::Gpu, FAST_ON_THE_GPU),
            Law::per_integrator(
                "a_stack_of_two_cubes_comes_to_rest_without_interpenetrating",
                a_stack_comes_to_rest,
            )
            .heavy_on(Kind::Gpu),
            Law::per_integrator(
                "self_contact_keeps_a_folding_bar_from_passing_through_itself",
                self_contact_keeps_a_folding_bar_apart,
            )
            .integrators(BAR_INTEGRATORS)
            .heavy_on(Kind::Gpu),
            Law::per_integrator(
                "self_contact_holds_the_bar_through_its_fold",
                self_contact_holds_the_bar_through_its_fold,
            )
            .integrators(BAR_INTEGRATORS)
            .fast_only_for(Kind::Gpu, FAST_ON_THE_GPU)
            .only_on(Kind::Gpu),
            Law::per_integrator(
                "a_pile_in_the_bowl_comes_to_rest_and_never_gains_energy",
                a_pile_comes_to_rest,
            )
            .integrators([Integrator::SymplecticEuler, Integrator::ImplicitEuler])
            .only_on(Kind::Cpu),
        ],
    )
}

/// The integrators whose GPU trials of contact between bodies are in the fast tier; the other
/// three are heavy there. The GPU's explicit methods differ only in how many times a step runs
/// the same pair kernels (each checked against its CPU twin in
/// `crates/gpu/tests/body_contact_twin.rs`), and the CPU's fast tier runs all five; the three
/// took 60% of this suite's GPU time on lavapipe.
const FAST_ON_THE_GPU: [Integrator; 2] = [Integrator::SymplecticEuler, Integrator::ImplicitEuler];

/// The folding bar's integrators: explicit Euler gains energy on its soft springs.
const BAR_INTEGRATORS: [Integrator; 4] = [
    Integrator::SymplecticEuler,
    Integrator::Midpoint,
    Integrator::Rk4,
    Integrator::ImplicitEuler,
];

/// The step of `integrator` in these tests: implicit Euler takes 10× larger steps.
fn step_for(integrator: Integrator) -> f64 {
    if integrator == Integrator::ImplicitEuler {
        1e-3
    } else {
        1e-4
    }
}

/// Two jelly cubes (10 cm, 4³ particles, contact radius 1.67 cm, 1 kg and 2 kg) 6 cm apart
/// (beyond the 3.3 cm the radii reach), thrown at each other at 1 m/s each, off-centre by 2 cm,
/// with no gravity and no terrain; body restitution 0.5, friction 0.3.
fn head_on(integrator: Integrator) -> Scene {
    let params = SpringParams {
        stiffness: 500.0,
        damping: 1.0,
    };
    let mut sim = simulation(integrator, step_for(integrator));
    sim.gravity = DVec3::ZERO;
    sim.duration = 0.3;
    sim.body_contact = BodyContact {
        restitution: 0.5,
        friction: 0.3,
        ..BodyContact::default()
    };
    let mut a = cuboid(
        DVec3::splat(0.1),
        [4, 4, 4],
        DVec3::new(-0.08, 0.0, 0.0),
        1.0,
        params,
    );
    a.velocity = DVec3::X;
    let mut b = cuboid(
        DVec3::splat(0.1),
        [4, 4, 4],
        DVec3::new(0.08, 0.02, 0.0),
        2.0,
        params,
    );
    b.velocity = -DVec3::X;
    let mut body_b = cuboid_body(b);
    body_b.name = "b".into();
    scene(sim, vec![cuboid_body(a), body_b], Vec::new())
}

/// Head-on: the total linear momentum Σ m v stays what it was to 1e-12 of Σ m|v| at every
/// 10 ms (the impulses are equal and opposite; only rounding changes the sum), and the cubes do
/// collide: their centres stay more than 5 cm apart along x (passing through each other, the
/// difference would turn negative), and they end moving apart (v_a < v_b).
///
/// Implicit Euler solves for its internal forces (the springs', and the pairs' in contact) to
/// the CG tolerance: each step's residual, at most that fraction of the step's right-hand side
/// (whose impulses are within the momentum scale here), changes the momentum. Its bound is the
/// tolerance once per step, as if every step's residual pointed the same way: 300 × 1e-8 on the
/// CPU (measured 2.1e-7), 300 × 1e-5 (`CG_TOLERANCE_F32`) on the GPU, whose f32 rounding per
/// step is two orders of magnitude below its tolerance (measured 1.2e-4 on lavapipe: the
/// residuals of the steps partly cancel, as a random walk's would, √300 × 1e-5 = 1.7e-4).
fn a_head_on_collision_conserves_momentum(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let mut failures = Vec::new();
    let scene = head_on(integrator);
    let mut solver = backend.solver(&scene)?;
    let (model, initial) = Model::build(&scene);
    let p0 = momentum(&model, &initial);
    let scale = momentum_scale(&model, &initial);
    let per_frame = (0.01 / scene.simulation.dt).round() as u64;
    let mut worst = 0.0f64;
    let centre = |x: &[DVec3], range: std::ops::Range<usize>| {
        range.clone().map(|i| x[i]).sum::<DVec3>() / range.len() as f64
    };
    let mut closest = f64::INFINITY;
    for _ in 0..30 {
        solver.advance(per_frame)?;
        let state = solver.state()?;
        worst = worst.max((momentum(&model, state) - p0).length() / scale);
        closest = closest.min(centre(&state.x, 64..128).x - centre(&state.x, 0..64).x);
    }
    let state = solver.state()?.clone();
    let va = state.v[..64].iter().sum::<DVec3>() / 64.0;
    let vb = state.v[64..].iter().sum::<DVec3>() / 64.0;
    println!(
        "{integrator}: momentum drift {worst:.2e} of Σm|v|, closest centres {closest:.4} m, \
         final velocities a {:.3} m/s, b {:.3} m/s",
        va.x, vb.x
    );
    let bound = if integrator == Integrator::ImplicitEuler {
        backend.cg_tolerance() * (30 * per_frame) as f64
    } else {
        // Rounding only: a random walk of one ulp of the momentum scale per step (f64:
        // 2.4e-14, measured ≤ 8e-16; f32: 1.3e-5, measured 1.7e-7 on lavapipe).
        backend.roundoff(1.0, 30 * per_frame)
    };
    if worst > bound {
        failures.push(format!(
            "{integrator}: momentum drifted by {worst:e} of Σm|v|"
        ));
    }
    // Through each other, the centres would pass (difference < 0); touching, they stay a
    // cube's width minus the squeeze apart, and separate afterwards (va < vb).
    if !(0.05..=0.155).contains(&closest) || va.x >= vb.x {
        failures.push(format!(
            "{integrator}: the cubes did not bounce apart (closest centres {closest} m, \
             velocities {} and {})",
            va.x, vb.x
        ));
    }
    all(failures)
}

/// Two 1 kg particles of radius 5 cm approaching at 1 m/s each, no gravity: after they touch,
/// the relative speed is k_r times the approach speed, for k_r = 0.5 and 0.8, within 1%.
fn two_particles_rebound_at_the_restitution(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let mut failures = Vec::new();
    for kr in [0.5, 0.8] {
        let mut sim = simulation(integrator, step_for(integrator));
        sim.gravity = DVec3::ZERO;
        sim.duration = 0.2;
        sim.body_contact.restitution = kr;
        let mut a = particle(DVec3::new(-0.1, 0.0, 0.0), DVec3::X);
        a.contact_radius = Some(0.05);
        let mut b = particle(DVec3::new(0.1, 0.0, 0.0), -DVec3::X);
        b.contact_radius = Some(0.05);
        b.name = "b".into();
        let mut solver = backend.solver(&scene(sim, vec![a, b], Vec::new()))?;
        solver.advance((0.2 / sim.dt).round() as u64)?;
        let v = &solver.state()?.v;
        let ratio = (v[1].x - v[0].x) / 2.0;
        println!("{integrator}, k_r = {kr}: separation speed / approach speed = {ratio:.6}");
        if (ratio - kr).abs() > 0.01 * kr {
            failures.push(format!(
                "{integrator}, k_r = {kr}: rebound ratio {ratio} (expected {kr} within 1%)"
            ));
        }
    }
    all(failures)
}

/// The head-on collision's state at 0.1 s is bit-identical on 1, 2 and 3 CPU threads, and from
/// run to run on the GPU. The cubes come within reach of each other at 0.013 s (a 2.7 cm gap
/// closing at 2 m/s), so the horizon holds the whole contact: pairs found, pushed and rebounded.
fn same_bits_for_any_thread_count(backend: &Backend, integrator: Integrator) -> Result<(), Failed> {
    let mut failures = Vec::new();
    let mut scene = head_on(integrator);
    scene.simulation.duration = 0.1;
    let bits = |solver: &mut Box<dyn Solver>| -> Result<Vec<u64>, Failed> {
        solver.advance(scene.simulation.steps())?;
        let s = solver.state()?;
        Ok(s.x
            .iter()
            .chain(&s.v)
            .flat_map(|p| p.to_array())
            .map(f64::to_bits)
            .collect())
    };
    // The CPU on 1, 2 and 3 threads; the GPU twice on its one device.
    let runs: Vec<Vec<u64>> = if backend.is_gpu() {
        (0..2)
            .map(|_| bits(&mut backend.solver(&scene)?))
            .collect::<Result<_, Failed>>()?
    } else {
        [1, 2, 3]
            .into_iter()
            .map(|threads| {
                let (model, state) = Model::build(&scene);
                let solver = CpuSolver::new(model, state, Some(threads)).expect("a pool");
                bits(&mut (Box::new(solver) as Box<dyn Solver>))
            })
            .collect::<Result<_, Failed>>()?
    };
    if runs.iter().any(|r| *r != runs[0]) {
        failures.push(format!("{integrator}: the runs give different bits"));
    }
    all(failures)
}

/// Two 2 kg cubes (15 cm, 4³, k_s = 1000 N/m, contact radius 2.5 cm) dropped one onto the
/// other onto a plane (restitution 0.3 and 0.2 between the bodies, friction 0.5 and 0.4), with
/// h = 1e-4 s (implicit Euler: 1/60 s, the step it is for), for `duration` seconds.
fn stack(integrator: Integrator, duration: f64) -> Scene {
    let params = SpringParams {
        stiffness: 1000.0,
        damping: 5.0,
    };
    let lower = cuboid(
        DVec3::splat(0.15),
        [4, 4, 4],
        DVec3::new(0.0, 0.1, 0.0),
        2.0,
        params,
    );
    let mut upper = cuboid(
        DVec3::splat(0.15),
        [4, 4, 4],
        DVec3::new(0.03, 0.32, 0.02),
        2.0,
        params,
    );
    upper.rotation = DVec3::new(0.0, 20.0, 0.0);
    let mut upper = cuboid_body(upper);
    upper.name = "upper".into();
    let h = if integrator == Integrator::ImplicitEuler {
        1.0 / 60.0
    } else {
        1e-4
    };
    let mut sim = simulation(integrator, h);
    sim.duration = duration;
    sim.body_contact = BodyContact {
        restitution: 0.2,
        friction: 0.4,
        ..BodyContact::default()
    };
    let floor = plane(DVec3::ZERO, DVec3::Y, 0.3, 0.5);
    scene(sim, vec![cuboid_body(lower), upper], vec![floor])
}

/// The sum of the stack's contact radii.
const STACK_REACH: f64 = 2.0 * 0.5 * 0.05;

/// The stack of [`stack`] over its duration, looked at every 10 ms (implicit Euler: every
/// step): the closest pair of particles of the two bodies, and the largest kinetic energy from
/// `resting_from` seconds on. Fails if a pair came closer than 90% of the sum of their radii
/// (implicit Euler: 85%: its impacts sink within its long step, and the response pushes them
/// back to 90% exactly, see `a_pile_comes_to_rest`; measured 0.9000).
fn run_stack(
    backend: &Backend,
    integrator: Integrator,
    duration: f64,
    resting_from: f64,
) -> Result<(Box<dyn Solver>, f64), Failed> {
    let scene = stack(integrator, duration);
    let h = scene.simulation.dt;
    let mut solver = backend.solver(&scene)?;
    let steps = ((0.01 / h).round() as u64).max(1);
    let checks = (duration / (steps as f64 * h)).round() as u64;
    let (mut closest, mut resting) = (f64::INFINITY, 0.0f64);
    for check in 1..=checks {
        solver.advance(steps)?;
        let x = &solver.state()?.x;
        for a in &x[..64] {
            for b in &x[64..] {
                closest = closest.min(a.distance(*b));
            }
        }
        if (check * steps) as f64 * h >= resting_from {
            resting = resting.max(solver.energies()?.kinetic);
        }
    }
    println!(
        "{integrator}: closest pair {:.4} of R over {duration} s, kinetic energy up to \
         {resting:.2e} J after {resting_from} s",
        closest / STACK_REACH
    );
    let nearest = if integrator == Integrator::ImplicitEuler {
        0.85
    } else {
        0.9
    };
    ensure(closest >= nearest * STACK_REACH, || {
        format!(
            "{integrator}: two particles came to {closest} m, under {nearest} R = {} m",
            nearest * STACK_REACH
        )
    })?;
    Ok((solver, resting))
}

/// The stack's landing, 0.3 s: the lower cube meets the plane at about 0.07 s and the upper one
/// lands on it at about 0.1 s at 1 m/s, the deepest squeeze of the run, and rebounds (k_r =
/// 0.2) within the horizon; no pair of the two bodies comes closer than [`run_stack`]'s bound.
/// The rest that follows is `a_stack_comes_to_rest`.
fn a_stack_lands_without_interpenetrating(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    run_stack(backend, integrator, 0.3, 0.3).map(|_| ())
}

/// The stack of [`stack`] over 4 s: no interpenetration ([`run_stack`]), and from 2.5 s on the
/// kinetic energy stays below 1e-9 J per kg of the stack.
///
/// Measured, the largest after 2.5 s: symplectic Euler 6e-15 J, midpoint 7e-12 J, RK4 7e-10 J, implicit
/// Euler 1.2e-13 J. Explicit Euler's own energy gain keeps the stack moving (5e-5 J after 2.5 s,
/// and 3e-5 J at h = 1e-5 s: not a matter of the step): it is held to the no-interpenetration
/// bound only. Implicit Euler on the GPU (f32, lavapipe): 3.0e-13 J, closest pair 0.9000 R.
fn a_stack_comes_to_rest(backend: &Backend, integrator: Integrator) -> Result<(), Failed> {
    const MASS: f64 = 4.0;
    let (mut solver, resting) = run_stack(backend, integrator, 4.0, 2.5)?;
    let h = stack(integrator, 4.0).simulation.dt;
    // In f32 a velocity below ulp(x)/(2h) moves nothing, and the forces' rounding can
    // sustain it: the same precision floor as tests/contact.rs, ½·M·(ε·|x|max/(2h))².
    let x_max = solver
        .state()?
        .x
        .iter()
        .map(|x| x.abs().max_element())
        .fold(0.0, f64::max);
    let floor = 0.5 * MASS * (backend.epsilon() * x_max / (2.0 * h)).powi(2);
    let bound = 1e-9 * MASS + if backend.is_gpu() { floor } else { 0.0 };
    // Explicit Euler never settles (see the doc); RK4's f32 stack on the GPU keeps 2e-6 to
    // 2e-5 J at the interface after following the CPU to 1.9 s (ROADMAP.md).
    let unsettled = integrator == Integrator::ExplicitEuler
        || (backend.is_gpu() && integrator == Integrator::Rk4);
    ensure(unsettled || resting < bound, || {
        format!("{integrator}: kinetic energy up to {resting:e} J after 2.5 s (rest: < {bound} J)")
    })
}

/// `scenes/bar-folding.toml` (a soft bar thrown down on its end, which buckles and folds onto
/// itself), 1.6 s: with self-contact no two of its particles more than two lattice cells apart
/// come closer than 90% of the sum of their radii (4 cm) at any 10 ms; without it the folds
/// pass through each other (closer than half of it) — so the case does test something (on the
/// CPU). Symplectic Euler (the scene's), midpoint and RK4 at the scene's step, implicit Euler at
/// `step_for`'s 1e-3 s (at 1e-4 s one run takes lavapipe 6 minutes, and the bar folds alike).
/// Measured: 0.040 m with, 0.003 m without; implicit Euler 0.0389 m and 0.0008 m (GPU, f32,
/// lavapipe: 0.0389 m with). On the GPU the trials are heavy (a minute of lavapipe each);
/// `self_contact_holds_the_bar_through_its_fold` checks the fold itself there.
fn self_contact_keeps_a_folding_bar_apart(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    bar_folding(backend, integrator, 0.0, 1.6)
}

/// The folding bar of `self_contact_keeps_a_folding_bar_apart` from 0.95 s to 1.15 s on the
/// backend, started from the CPU's state at 0.95 s: its parts first come within reach of each
/// other at 0.98 s (implicit Euler: 1.05 s), and without self-contact they pass through half
/// of it by 1.01 s (implicit Euler: 1.06 s; measured on the CPU at every 10 ms), so the window
/// holds the fold; the same bounds.
fn self_contact_holds_the_bar_through_its_fold(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    bar_folding(backend, integrator, 0.95, 1.15)
}

/// The folding bar checked from `start` to `end` seconds on `backend`, its state at `start`
/// from the CPU, with self-contact; and, on the CPU, the same window without it (the control).
fn bar_folding(
    backend: &Backend,
    integrator: Integrator,
    start: f64,
    end: f64,
) -> Result<(), Failed> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/bar-folding.toml");
    let base = Scene::from_file(&path).map_err(|e| e.to_string())?;
    let mut failures = Vec::new();
    let cpu = Backend::cpu();
    for (self_contact, on) in [(true, backend), (false, &cpu)] {
        let mut scene = base.clone();
        scene.simulation.integrator = integrator;
        scene.simulation.dt = step_for(integrator);
        scene.simulation.duration = end;
        scene.bodies[0].self_contact = self_contact;
        let (model, state) = Model::build(&scene);
        let reach = 2.0 * model.contact.radius[0];
        let lattice = &model.contact.lattice;
        let apart = |i: usize, j: usize| match (lattice[i], lattice[j]) {
            (Some(a), Some(b)) => (0..3).any(|k| (a[k] - b[k]).abs() > 2),
            _ => true,
        };
        let per_check = (0.01 / scene.simulation.dt).round() as u64;
        let skipped = (start / 0.01).round() as u64;
        let state = if skipped == 0 {
            state
        } else {
            let mut prefix = cpu.solver_from(model.clone(), state)?;
            prefix.advance(skipped * per_check)?;
            prefix.state()?.clone()
        };
        let mut solver = on.solver_from(model.clone(), state)?;
        let mut closest = f64::INFINITY;
        for _ in skipped..(end / 0.01).round() as u64 {
            solver.advance(per_check)?;
            let x = &solver.state()?.x;
            for i in 0..x.len() {
                for j in i + 1..x.len() {
                    if apart(i, j) {
                        closest = closest.min(x[i].distance(x[j]));
                    }
                }
            }
        }
        println!(
            "{integrator}, self_contact = {self_contact} on {}, {start} s to {end} s: closest \
             {closest:.4} m (R = {reach} m)",
            on.name()
        );
        if self_contact && closest < 0.9 * reach {
            failures.push(format!(
                "{integrator}: with self-contact two parts of the bar came to {closest} m (R = {reach} m)"
            ));
        }
        if !self_contact && closest >= 0.5 * reach {
            failures.push(format!(
                "{integrator}: without self-contact the bar did not fold through itself \
                 (closest {closest} m): the case tests nothing"
            ));
        }
    }
    all(failures)
}

/// `scenes/pile-in-bowl.toml` (six 8 kg cubes of 5³ particles dropped into a bowl, contact
/// radius 2.5 cm) with symplectic Euler at the scene's step (1e-4 s) and implicit Euler at
/// 1/60 s, 10 s, checked every 10 ms (implicit Euler: every step): the kinetic energy is below
/// 1e-9 J per kg of the pile from 6 s on, and the total energy never exceeds its start.
/// Symplectic Euler keeps every two particles of different bodies beyond 90% of the sum of
/// their radii. Implicit Euler is held to 85%, and to energy rises within a step of at most
/// 1e-3 of the start: its impacts sink up to 12% within a 1/60 s step before the response
/// pushes them back to 10% (pairs meeting within the step are not in its solve yet), and the
/// penalty's potential ½k(R − d)² of that overlap, which the energies do not count, goes back
/// into the bodies.
///
/// Measured: closest 0.995 R (symplectic), 0.878 R (implicit); kinetic energy from 6 s on up
/// to 3e-10 J and 4e-10 J; largest rise in a step 4e-9 J and 0.08 J (of 206 J). Midpoint and
/// RK4 creep on (7.7e-6 J and 4.9e-7 J at 12 s) and explicit Euler keeps moving (3e-4 J):
/// ROADMAP.md. On the GPU the trials are heavy: 100,000 steps of 750 particles with contact
/// take lavapipe many minutes.
fn a_pile_comes_to_rest(backend: &Backend, integrator: Integrator) -> Result<(), Failed> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/pile-in-bowl.toml");
    let mut scene = Scene::from_file(&path).map_err(|e| e.to_string())?;
    let mut failures = Vec::new();
    let h = if integrator == Integrator::ImplicitEuler {
        1.0 / 60.0
    } else {
        scene.simulation.dt
    };
    scene.simulation.integrator = integrator;
    scene.simulation.dt = h;
    let (model, _) = Model::build(&scene);
    let mass: f64 = model.mass.iter().sum();
    let body = &model.contact.body;
    let reach = 2.0 * model.contact.radius[0];
    let mut solver = backend.solver(&scene)?;
    let steps = ((0.01 / h).round() as u64).max(1);
    let checks = (10.0 / (steps as f64 * h)).round() as u64;
    let total = |e: softbody::Energies| e.kinetic + e.gravitational + e.elastic;
    let start = total(solver.energies()?);
    let (mut previous, mut rise, mut highest) = (start, 0.0f64, start);
    let (mut closest, mut resting) = (f64::INFINITY, 0.0f64);
    for check in 1..=checks {
        solver.advance(steps)?;
        let x = &solver.state()?.x;
        for i in 0..x.len() {
            for j in i + 1..x.len() {
                if body[i] != body[j] {
                    closest = closest.min(x[i].distance(x[j]));
                }
            }
        }
        let energies = solver.energies()?;
        if (check * steps) as f64 * h >= 6.0 {
            resting = resting.max(energies.kinetic);
        }
        rise = rise.max(total(energies) - previous);
        previous = total(energies);
        highest = highest.max(previous);
    }
    println!(
        "{integrator}: closest pair {:.4} of R, kinetic energy up to {resting:.2e} J from 6 s, \
         largest energy rise {rise:.2e} J of {start:.1} J",
        closest / reach
    );
    let (nearest, largest_rise) = if integrator == Integrator::ImplicitEuler {
        (0.85, 1e-3)
    } else {
        (0.9, f64::INFINITY)
    };
    if closest < nearest * reach {
        failures.push(format!(
            "{integrator}: two particles came to {closest} m, under {nearest} R = {} m",
            nearest * reach
        ));
    }
    if highest > start {
        failures.push(format!(
            "{integrator}: the energy rose to {highest} J, above its start {start} J"
        ));
    }
    if resting >= 1e-9 * mass {
        failures.push(format!(
            "{integrator}: kinetic energy up to {resting:e} J from 6 s (rest: < {} J)",
            1e-9 * mass
        ));
    }
    if rise > largest_rise * start {
        failures.push(format!(
            "{integrator}: the energy rose by {rise:e} J within 10 ms (bound {} J)",
            largest_rise * start
        ));
    }
    all(failures)
}
