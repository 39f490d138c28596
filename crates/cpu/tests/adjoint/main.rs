//! The adjoint against central finite differences of the forward solver, for every explicit
//! integrator: free flight, a cube sliding down a slope (contact and kinetic Coulomb friction
//! throughout), a cube in a bowl (viscous friction on a curved surface), bouncing particles
//! (fresh impacts and restitution), particles sliding round a box's edge, off a
//! heightfield's peak and round a mesh's edge (the normal turning past edges and corners), and
//! contact between bodies: particles falling onto a cube's corners (fresh impacts with
//! restitution, pushed apart past the slop, one pair slipping and one sticking, then an impact
//! that is not fresh) and a particle pressed into a corner, sliding across it (the penalty at
//! every stage, viscous friction pressed by the impulse and the penalty); and implicit Euler's
//! (`implicit.rs`) held stretched, in contact with the terrain and through contact between
//! bodies.
//!
//! Each group of values θ (initial positions, initial velocities, masses, stiffnesses,
//! dampings, gravity, drag, friction, restitution) is moved along a fixed pseudo-random
//! direction d, and ⟨∇L, d⟩ is compared with (L(θ + δd) − L(θ − δd))/2δ. With δ = 1e-6 of the
//! values' scale the central difference's truncation error, δ²/6·|L'''|, is ~1e-13 of L's scale
//! and its rounding error ~1e-16/δ = 1e-10; the tolerance, 1e-6 of the larger of |⟨∇L, d⟩| and
//! the difference's own size, leaves room for both while a wrong term (a missing factor, a
//! sign) is off by O(1). Gravity and drag move by 1e-3 and 1e-4 absolute: the held cube's
//! loss depends on them by ~1e-4 of its size, where 1e-6 would leave the rounding of L over δ
//! at 1e-6 of their derivatives; L is smooth in both (they enter the forces linearly), so the
//! truncation error stays ~1e-8. Dampings move by 1e-5: the small damping gradients of the
//! sliding pairs (3e-3) leave the rounding at 1e-6 above the tolerance (see `check_case`), and
//! the restitution of contact between bodies by 1e-4: under implicit Euler the grazing pair's
//! penalty takes most of its rebound back at the next steps, leaving a gradient of 3e-5, whose
//! differences at δ = 1e-6 round to 4e-6 of it; the rebounds move by ≤ 3e-4 m/s, far from
//! every case's branches, and L is smooth in k_r on them.

mod cases;
mod harness;
mod implicit;

use std::path::Path;

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::adjoint::run::{Backward, Options, gradient};
use softbody_scene::{Controls, Integrator, Model, Scene, Solver};

use cases::cases;
use harness::{Case, Probe, build, check, check_case, direction, dot, forward_loss_with, threads};
use implicit::{implicit_body_cases, implicit_contact_cases};

const EXPLICIT: [Integrator; 4] = [
    Integrator::ExplicitEuler,
    Integrator::SymplecticEuler,
    Integrator::Midpoint,
    Integrator::Rk4,
];

#[test]
fn the_adjoint_is_the_derivative_of_the_computed_run() {
    let mut failures = Vec::new();
    for integrator in EXPLICIT {
        for case in cases(integrator) {
            check_case(integrator, &case, &mut failures);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The gradient of external forces held over each frame's steps (a control input) against
/// central differences of the run, as the other groups' (δ = 1e-6 N on forces of 0.05 N):
/// free flight, the slope and the pressed pair between bodies for every explicit integrator
/// (on the slope, forces and their change along it, which keep every contact's branch; between
/// bodies the forces beside the penalty), implicit Euler held stretched.
#[test]
fn the_controls_gradient_is_the_derivative_of_the_computed_run() {
    let slope = DVec3::new(0.9397, -0.3420, 0.0);
    let mut failures = Vec::new();
    let runs = EXPLICIT
        .iter()
        .flat_map(|&i| {
            [
                (i, "free flight"),
                (i, "sliding on a slope"),
                (i, "bodies pressed, sliding"),
            ]
        })
        .chain([(Integrator::ImplicitEuler, "held stretched")]);
    for (integrator, name) in runs {
        let case = cases(integrator)
            .into_iter()
            .find(|c| c.name == name)
            .unwrap();
        let (model, state) = build(&case);
        let n = model.len();
        let count = model.simulation.frame_count() as usize * n;
        let along = |k: usize, salt: f64| match name {
            "sliding on a slope" => direction(k, salt).x * slope,
            _ => direction(k, salt),
        };
        let u: Vec<DVec3> = (0..count).map(|k| 0.05 * along(k, 5.0)).collect();
        let d: Vec<DVec3> = (0..count).map(|k| along(k, 9.0)).collect();
        let controls = Controls::new(&model, u.as_slice()).unwrap();
        let options = Options {
            threads: Some(1),
            controls: Some(&controls),
            ..Options::default()
        };
        let back = gradient(&model, &state, &mut Probe::new(n), options).unwrap();
        let what = format!("{integrator:?}, {name}");
        check(
            &format!("{what}: loss"),
            back.loss,
            forward_loss_with(&model, &state, Some(&u)),
            &mut failures,
        );
        let delta = 1e-6;
        let at = |s: f64| {
            let moved: Vec<DVec3> = u.iter().zip(&d).map(|(u, d)| *u + s * *d).collect();
            forward_loss_with(&model, &state, Some(&moved))
        };
        let fd = (at(delta) - at(-delta)) / (2.0 * delta);
        check(
            &format!("{what}: controls"),
            dot(&back.controls, &|k| d[k]),
            fd,
            &mut failures,
        );
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The cases touch what they are meant to: the slope's and the bowl's particles press on the
/// terrain, the bouncing ones make fresh impacts (their restitution's gradient is not zero),
/// the bodies' pairs slide and the falling ones bounce off the cube.
#[test]
fn the_cases_reach_their_laws() {
    for case in cases(Integrator::SymplecticEuler) {
        let (model, state) = build(&case);
        let back = gradient(&model, &state, &mut Probe::new(model.len()), threads(1)).unwrap();
        let g = &back.gradient;
        match case.name {
            "sliding on a slope"
            | "in a bowl"
            | "round a box's edge"
            | "on a tent's peak"
            | "round a mesh's edge" => {
                assert!(g.friction_of(0) != 0.0, "{}", case.name)
            }
            "bouncing" => assert!(g.restitution_of(0) != 0.0),
            "bodies' impact" => {
                assert!(g.body_restitution_total() != 0.0);
                assert!(g.body_friction_total() != 0.0);
            }
            "bodies pressed, sliding" => assert!(g.body_friction_total() != 0.0),
            _ => assert!(model.terrain.is_empty()),
        }
    }
}

/// The gradient's bits do not depend on the thread count (RK4 in contact with the terrain and
/// between bodies, implicit Euler held stretched, sliding on a slope and grazing another body); the states the
/// backward pass recomputes are the forward run's (the loss sees the bits a plain run has at
/// each frame).
#[test]
fn the_same_bits_on_any_thread_count_and_recomputed_states_are_the_forward_ones() {
    for (integrator, name) in [
        (Integrator::Rk4, "sliding on a slope"),
        (Integrator::Rk4, "bodies' impact"),
        (Integrator::ImplicitEuler, "held stretched"),
    ] {
        let case = cases(integrator)
            .into_iter()
            .find(|c| c.name == name)
            .unwrap();
        same_bits_on_any_thread_count(&case);
    }
    same_bits_on_any_thread_count(&implicit_contact_cases()[0]);
    same_bits_on_any_thread_count(&implicit_body_cases()[1]);
}

fn same_bits_on_any_thread_count(case: &Case) {
    let (model, state) = build(case);
    let bits = |b: &Backward| {
        let mut out: Vec<u64> =
            b.x0.iter()
                .chain(&b.v0)
                .flat_map(|p| p.to_array())
                .map(f64::to_bits)
                .collect();
        out.extend(
            b.gradient
                .stiffness
                .iter()
                .chain(&b.gradient.mass)
                .chain(&b.gradient.inv_mass)
                .map(|x| x.to_bits()),
        );
        out.push(b.gradient.friction_of(0).to_bits());
        out.push(b.gradient.body_friction_total().to_bits());
        out.push(b.gradient.body_restitution_total().to_bits());
        out.push(b.loss.to_bits());
        out
    };
    let mut probe = Probe::new(model.len());
    let one = gradient(&model, &state, &mut probe, threads(1)).unwrap();
    for n in [2, 3] {
        let other = gradient(&model, &state, &mut Probe::new(model.len()), threads(n)).unwrap();
        assert_eq!(bits(&one), bits(&other), "{n} threads");
    }
    let sim = &model.simulation;
    let mut solver = CpuSolver::new(model.clone(), state.clone(), Some(1)).unwrap();
    let mut at = 0;
    probe.seen.sort_by_key(|(f, _)| *f);
    assert_eq!(probe.seen.len() as u64, sim.frame_count());
    for (f, seen) in &probe.seen {
        let step = sim.frame_step(*f);
        solver.advance(step - at).unwrap();
        at = step;
        assert_eq!(solver.state().unwrap(), seen, "frame {f}");
    }
}

/// Checkpoints every ⌈√T⌉ steps: over T = 10⁴ steps at most 2√T + 2 states are held.
#[test]
fn memory_grows_as_the_square_root_of_the_steps() {
    let toml = "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 1e-4\nduration = 1.0\nframe_rate = 10.0\n\
                [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0], [0.1, 1.0, 0.0]]\n\
                masses = [1.0, 1.0]\nsprings = [{ a = 0, b = 1, stiffness = 10.0 }]\n";
    let scene = Scene::from_toml(toml, Path::new("long.toml")).unwrap();
    let (model, state) = Model::build(&scene);
    let back = gradient(&model, &state, &mut Probe::new(2), threads(1)).unwrap();
    assert_eq!(back.steps, 10_000);
    assert_eq!(back.interval, 100);
    assert!(back.peak_states <= 2 * 100 + 2, "{}", back.peak_states);
}
