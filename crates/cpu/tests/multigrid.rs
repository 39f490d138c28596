//! The multigrid preconditioner of implicit Euler's CG: the same steps as block Jacobi within
//! the CG tolerance, iteration counts that do not grow with the cube's size, the same bits for
//! any thread count, and a symmetric preconditioner.

use std::time::Instant;

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::integrators::implicit_euler::CG_TOLERANCE;
use softbody_cpu::integrators::implicit_euler::cg::{self, Constraint, Preconditioner, Scratch};
use softbody_cpu::integrators::implicit_euler::multigrid::{KEEP_ASSEMBLIES, Multigrid};
use softbody_cpu::integrators::implicit_euler::system::System;
use softbody_scene::{History, Integrator, Model, Solver, SpringParams, State};
use softbody_testkit::Rng;
use softbody_testkit::scenes::*;

/// The benchmark's stiff cube (`softbody bench --stiffness 1e4 --dt 1/60`): n³ particles on a
/// unit cube of mass 1, k_s = 10⁴ N/m, k_d = 5 N·s/m on every family, h = 1/60 s, its bottom
/// `lift` metres above the ground plane y = 0 (no friction, restitution 0.5), contact distance
/// 0.
fn stiff_cube(n: u32, lift: f64, preconditioner: softbody_scene::Preconditioner) -> (Model, State) {
    let mut sim = simulation(Integrator::ImplicitEuler, 1.0 / 60.0);
    sim.preconditioner = preconditioner;
    sim.contact_distance = 0.0;
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

/// The step's system of `model` at `state`.
fn assembled(model: &Model, state: &State) -> System {
    let mut system = System::new(model);
    let mut b = vec![DVec3::ZERO; model.len()];
    system.assemble(model, (None, None), &state.x, &state.v, &mut b);
    system
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
    system.assemble(model, (None, None), &state.x, &state.v, &mut b);
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
    let outcome = cg::CgProblem {
        preconditioner: match multigrid {
            Some(mg) => Preconditioner::Multigrid(mg),
            None => Preconditioner::BlockJacobi,
        },
        ..cg::CgProblem::new(&mut system, model, &constraints, &b, &z)
    }
    .solve(&mut dv, &mut scratch);
    (dv, outcome, started.elapsed().as_secs_f64())
}

/// Multigrid's iterations for one solve of the deformed stiff cube (k_s = 10⁴ N/m, h = 1/60 s,
/// the bottom layer sliding) at 10³, 22³ and 46³: those at 46³ at most 1.5 times those at 10³
/// (block Jacobi's grow like n: 112 and 248 at 10³ and 22³).
#[test]
fn multigrid_iterations_do_not_grow_with_the_size() {
    let mut iterations = Vec::new();
    for n in [10u32, 22, 46] {
        let (model, state) = deformed(n);
        let mut mg = Multigrid::new(&model, &System::new(&model)).expect("a lattice");
        let (dv, outcome, seconds) = solve_once(&model, &state, Some(&mut mg));
        assert!(
            outcome.relative_residual <= CG_TOLERANCE,
            "{n}³: {outcome:?}"
        );
        let mut line = format!(
            "{n}³: levels {:?}, multigrid {} iterations ({seconds:.3} s)",
            mg.level_sizes(),
            outcome.iterations
        );
        if n <= 22 {
            let (dv_bj, bj, bj_seconds) = solve_once(&model, &state, None);
            let diff = dv
                .iter()
                .zip(&dv_bj)
                .map(|(a, b)| (*a - *b).length_squared());
            let norm = dv_bj.iter().map(|v| v.length_squared()).sum::<f64>();
            line += &format!(
                ", block Jacobi {} ({bj_seconds:.3} s), |Δv_mg − Δv_bj|/|Δv| = {:.1e}",
                bj.iterations,
                (diff.sum::<f64>() / norm).sqrt()
            );
        }
        println!("{line}");
        iterations.push(outcome.iterations);
    }
    assert!(
        2 * iterations[2] <= 3 * iterations[0],
        "iterations {iterations:?}: 46³ takes more than 1.5 times 10³'s"
    );
}

/// `steps` steps of the scene with each preconditioner (two threads), and the largest
/// differences of positions and velocities relative to the largest displacement from the start
/// and the largest velocity (at least h|g|).
fn both_preconditioners((model, state): (Model, State), steps: u64) -> (f64, f64, [u64; 2]) {
    let run = |p: softbody_scene::Preconditioner| {
        let mut model = model.clone();
        model.simulation.preconditioner = p;
        let mut solver = CpuSolver::new(model, state.clone(), Some(2)).unwrap();
        solver.advance(steps).unwrap();
        let st = solver.statistics();
        assert_eq!(st.preconditioner, Some(p));
        (solver.state().unwrap().clone(), st.cg_iterations)
    };
    let (mg, mg_iterations) = run(softbody_scene::Preconditioner::Multigrid);
    let (bj, bj_iterations) = run(softbody_scene::Preconditioner::BlockJacobi);
    let max = |a: &[DVec3], b: &[DVec3]| {
        a.iter()
            .zip(b)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f64::max)
    };
    let moved = max(&bj.x, &state.x);
    // A body at rest still changes its velocity by about h|g| within a step (the scale of the
    // right-hand side the CG tolerance is relative to).
    let h_g = model.simulation.dt * model.simulation.gravity.length();
    let speed = bj.v.iter().map(|v| v.length()).fold(h_g, f64::max);
    (
        max(&mg.x, &bj.x) / moved,
        max(&mg.v, &bj.v) / speed,
        [mg_iterations, bj_iterations],
    )
}

/// Multigrid and block Jacobi take the same steps within the CG tolerance: a stiff 8³ cube
/// falling (free), the same cube landing on the ground and resting on it (contacts sticking,
/// slipping and released, the active set changing), and a cube hanging from its pinned top
/// corners. Each solve stops at 1e-8 of the preconditioned residual; the errors of Δv this
/// leaves are bounded by √κ·1e-8 with κ ≈ 3·10⁴ the condition of the block-Jacobi-preconditioned
/// system ((hω)² of these springs), so ~2·10⁻⁶ per solve, and the two runs must agree to
/// 1e-5 of the displacement and velocity scales.
#[test]
fn multigrid_and_block_jacobi_take_the_same_steps() {
    use softbody_scene::Preconditioner::Multigrid as Mg;
    let falling = stiff_cube(8, 1.0, Mg);
    let landing = stiff_cube(8, 0.02, Mg);
    let hanging = {
        let mut sim = simulation(Integrator::ImplicitEuler, 1.0 / 60.0);
        sim.drag = 0.5;
        let params = SpringParams {
            stiffness: 1e4,
            damping: 5.0,
        };
        let mut body = cuboid_body(cuboid(
            DVec3::ONE,
            [8; 3],
            DVec3::new(0.0, 2.0, 0.0),
            1.0,
            params,
        ));
        // The four top corners.
        body.pinned = vec![7 * 8, 7 * 8 + 7, 7 * 64 + 7 * 8, 7 * 64 + 7 * 8 + 7];
        Model::build(&scene(sim, vec![body], vec![]))
    };
    let bound = 1e-5;
    for (name, case, steps) in [
        ("falling", falling, 20),
        ("landing", landing, 60),
        ("hanging", hanging, 60),
    ] {
        let (dx, dv, [mg, bj]) = both_preconditioners(case, steps);
        println!(
            "{name}: {steps} steps, |x_mg − x_bj| = {dx:.1e}, |v_mg − v_bj| = {dv:.1e} of the \
             scales; CG iterations multigrid {mg}, block Jacobi {bj}"
        );
        assert!(dx <= bound && dv <= bound, "{name}: {dx:e}, {dv:e}");
    }
}

/// The same bits with multigrid on 1, 2 and 3 threads: a 16³ stiff cube landing on the ground
/// (several chunks of particles and of coarse rows).
#[test]
fn multigrid_steps_have_the_same_bits_on_any_thread_count() {
    let (model, state) = stiff_cube(16, 0.02, softbody_scene::Preconditioner::Multigrid);
    let run = |threads: usize| {
        let mut solver = CpuSolver::new(model.clone(), state.clone(), Some(threads)).unwrap();
        solver.advance(20).unwrap();
        assert_eq!(
            solver.statistics().preconditioner,
            Some(softbody_scene::Preconditioner::Multigrid)
        );
        solver.state().unwrap().clone()
    };
    let one = run(1);
    for threads in [2, 3] {
        let other = run(threads);
        assert!(
            one.x == other.x && one.v == other.v,
            "{threads} threads differ from one"
        );
    }
}

/// S·MG·S is symmetric and positive definite: for random filtered x, y (some particles fixed,
/// some sliding on a plane), |xᵀ(MG y) − yᵀ(MG x)| ≤ 1e-12·|x||MG y| and xᵀ(MG x) > 0.
#[test]
fn the_multigrid_preconditioner_is_symmetric_positive_definite() {
    let (model, state) = deformed(12);
    let n = model.len();
    let system = assembled(&model, &state);
    let mut rng = Rng::new(5);
    let constraints: Vec<Constraint> = (0..n)
        .map(|i| match i % 7 {
            0 => Constraint::Fixed,
            1 | 2 => Constraint::Normal(rng.vec(1.0).normalize()),
            _ => Constraint::Free,
        })
        .collect();
    let mut mg = Multigrid::new(&model, &system).unwrap();
    mg.prepare(&system, &model, &constraints);
    let dot = |a: &[DVec3], b: &[DVec3]| a.iter().zip(b).map(|(a, b)| a.dot(*b)).sum::<f64>();
    let norm = |a: &[DVec3]| dot(a, a).sqrt();
    for _ in 0..5 {
        let mut random = || -> Vec<DVec3> {
            (0..n)
                .map(|i| constraints[i].filter(rng.vec(1.0)))
                .collect()
        };
        let (x, y) = (random(), random());
        let (mut mx, mut my) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
        let xmx = mg.apply(&constraints, &x, &mut mx);
        let ymy = mg.apply(&constraints, &y, &mut my);
        // What it returns is the product with its input (summed in chunks, so to rounding).
        assert!((xmx - dot(&x, &mx)).abs() <= 1e-12 * xmx.abs(), "{xmx:e}");
        assert!((ymy - dot(&y, &my)).abs() <= 1e-12 * ymy.abs(), "{ymy:e}");
        let asymmetry = (dot(&x, &my) - dot(&y, &mx)).abs();
        let scale = norm(&x) * norm(&my);
        println!(
            "|xᵀMy − yᵀMx| = {asymmetry:.1e} ({scale:.1e}), xᵀMx = {:.3e}",
            dot(&x, &mx)
        );
        assert!(asymmetry <= 1e-12 * scale, "{asymmetry:e} of {scale:e}");
        assert!(dot(&x, &mx) > 0.0 && dot(&y, &my) > 0.0);
    }
}

/// A later solve of the same step computes again only the values of the nodes whose
/// constraints changed: the preconditioner then gives the same bits as one prepared afresh
/// for the new constraints (contacts made, released and switched between fixed and sliding,
/// in the cube's bottom layer and inside it); a system assembled again keeps the values for
/// the same constraints, [`KEEP_ASSEMBLIES`] times, and is prepared anew for others or after.
#[test]
fn a_second_solves_preconditioner_is_the_fresh_one() {
    let (model, state) = deformed(12);
    let n = model.len();
    let mut system = assembled(&model, &state);
    let bottom = |i: usize| model.contact.lattice[i].unwrap()[1] == 0;
    let first: Vec<Constraint> = (0..n)
        .map(|i| match () {
            _ if bottom(i) => Constraint::Normal(DVec3::Y),
            _ if i % 97 == 0 => Constraint::Fixed,
            _ => Constraint::Free,
        })
        .collect();
    let mut second = first.clone();
    for (i, s) in second.iter_mut().enumerate() {
        match i % 11 {
            0 if bottom(i) => *s = Constraint::Free,
            1 if bottom(i) => *s = Constraint::Fixed,
            2 => *s = Constraint::Normal(DVec3::new(0.6, 0.8, 0.0)),
            _ => {}
        }
    }
    let mut rng = Rng::new(9);
    let r: Vec<DVec3> = (0..n).map(|i| second[i].filter(rng.vec(1.0))).collect();
    let applied = |mg: &mut Multigrid| {
        let mut z = vec![DVec3::ZERO; n];
        mg.apply(&second, &r, &mut z);
        z
    };
    let mut fresh = Multigrid::new(&model, &system).unwrap();
    fresh.prepare(&system, &model, &second);
    let expected = applied(&mut fresh);
    let mut incremental = Multigrid::new(&model, &system).unwrap();
    incremental.prepare(&system, &model, &first);
    incremental.prepare(&system, &model, &second);
    assert!(
        applied(&mut incremental) == expected,
        "the incremental values differ"
    );
    // A new assembly (other positions) with the same constraints keeps the values, for up to
    // KEEP_ASSEMBLIES assemblies; other constraints, or one assembly more, compute them anew.
    let kept = applied(&mut incremental);
    let mut moved = state.clone();
    moved.x.iter_mut().for_each(|x| *x *= 1.01);
    let mut b = vec![DVec3::ZERO; n];
    for _ in 0..KEEP_ASSEMBLIES {
        system.assemble(&model, (None, None), &moved.x, &moved.v, &mut b);
        incremental.prepare(&system, &model, &second);
        assert!(
            applied(&mut incremental) == kept,
            "the values were not kept"
        );
    }
    let mut afresh = Multigrid::new(&model, &system).unwrap();
    afresh.prepare(&system, &model, &second);
    let expected = applied(&mut afresh);
    assert!(expected != kept, "the positions do not matter");
    fresh.prepare(&system, &model, &first);
    fresh.prepare(&system, &model, &second);
    assert!(
        applied(&mut fresh) == expected,
        "other constraints kept old values"
    );
    system.assemble(&model, (None, None), &moved.x, &moved.v, &mut b);
    incremental.prepare(&system, &model, &second);
    assert!(
        applied(&mut incremental) == expected,
        "values kept past KEEP_ASSEMBLIES"
    );
}

/// CG's weight norm wᵀ S MG S w (w_i = S m_i h g: its stopping scale's floor) is computed once
/// for as long as the multigrid keeps its values: the kept norm is the bits those values give,
/// a solve under it the bits of one that computed it, and new values (other constraints) or
/// another h g find none.
#[test]
fn the_weight_norm_lasts_as_long_as_the_values() {
    let (model, state) = deformed(8);
    let n = model.len();
    let hg = model.simulation.dt * model.simulation.gravity;
    // `solve_once`'s constraints: the bottom layer slides.
    let sliding: Vec<Constraint> = (0..n)
        .map(|i| match model.contact.lattice[i].unwrap()[1] {
            0 => Constraint::Normal(DVec3::Y),
            _ => Constraint::Free,
        })
        .collect();
    let system = assembled(&model, &state);
    let mut kept = Multigrid::new(&model, &system).unwrap();
    assert_eq!(kept.weight_norm(hg), None, "nothing before the values");
    let first = solve_once(&model, &state, Some(&mut kept));
    let norm = kept
        .weight_norm(hg)
        .expect("the first solve keeps the weight norm");
    let w: Vec<DVec3> = (0..n)
        .map(|i| sliding[i].filter(model.mass[i] * hg))
        .collect();
    let mut z = vec![DVec3::ZERO; n];
    assert_eq!(norm.to_bits(), kept.apply(&sliding, &w, &mut z).to_bits());
    // A second solve of the same system takes the kept norm; a fresh multigrid computes it.
    let second = solve_once(&model, &state, Some(&mut kept));
    let mut fresh = Multigrid::new(&model, &system).unwrap();
    let third = solve_once(&model, &state, Some(&mut fresh));
    let bits = |v: &[DVec3]| -> Vec<u64> {
        v.iter()
            .flat_map(|v| v.to_array())
            .map(f64::to_bits)
            .collect()
    };
    for (a, b) in [(&first, &second), (&second, &third)] {
        assert!(bits(&a.0) == bits(&b.0), "Δv differs");
        assert_eq!(a.1.iterations, b.1.iterations);
        assert_eq!(
            a.1.relative_residual.to_bits(),
            b.1.relative_residual.to_bits()
        );
    }
    assert_eq!(kept.weight_norm(2.0 * hg), None, "another h g");
    let mut other = sliding.clone();
    other[n / 2] = Constraint::Fixed;
    kept.prepare(&system, &model, &other);
    assert_eq!(kept.weight_norm(hg), None, "new values");
}

/// The stiff 10³ cube at rest on the ground after its bounces is solved once a step, in a few
/// iterations: its bottom layer's contacts are made before the first solve (their predicted
/// φ + h v·N is zero to rounding: `resting_slack`), and the solve's target does not fall to the
/// rounding of its springs' forces against its weight (the weight's floor of the CG
/// tolerance). Before both, the same steps took two or three solves and 55–175 iterations.
#[test]
fn a_cube_at_rest_is_solved_once_a_step_in_a_few_iterations() {
    for p in softbody_scene::Preconditioner::ALL {
        let (model, state) = stiff_cube(10, 0.5, p);
        let mut solver = CpuSolver::new(model, state, Some(2)).unwrap();
        solver.advance(90).unwrap();
        let before = solver.statistics().clone();
        solver.advance(30).unwrap();
        let after = solver.statistics();
        let (solves, iterations) = (
            after.cg_solves - before.cg_solves,
            after.cg_iterations - before.cg_iterations,
        );
        let speed = (solver.state().unwrap().v.iter()).fold(0.0, |m: f64, v| m.max(v.length()));
        println!("{p}: steps 90–120, {solves} solves, {iterations} iterations, |v| ≤ {speed:.1e}");
        assert!(speed < 1e-3, "{p}: not at rest ({speed} m/s)");
        assert_eq!(solves, 30, "{p}: more than one solve a step");
        assert!(iterations <= 12 * 30, "{p}: {iterations} iterations");
    }
}

/// The stiff 10³ cube's 120 benchmark steps (the fall, the bounces, the rest) with the warm
/// start projected on the last three steps' Δv: at most 7 CG iterations a step with the
/// multigrid and 15 with block Jacobi (5.2 and 11.8 measured; from the last Δv alone they were
/// 13.2 and 20.7). Fails if the earlier solutions are not kept from step to step.
#[test]
fn the_projected_warm_start_keeps_the_bounces_solves_short() {
    for (p, bound) in [
        (softbody_scene::Preconditioner::Multigrid, 7.0),
        (softbody_scene::Preconditioner::BlockJacobi, 15.0),
    ] {
        let (model, state) = stiff_cube(10, 0.5, p);
        let mut solver = CpuSolver::new(model, state, Some(2)).unwrap();
        solver.advance(120).unwrap();
        let per_step = solver.statistics().cg_iterations as f64 / 120.0;
        println!("{p}: {per_step:.2} CG iterations a step");
        assert!(per_step <= bound, "{p}: {per_step} iterations a step");
    }
}

/// A solver restored from another's state and history where the multigrid's values were
/// kept from an earlier step (the stiff 10³ cube at rest: the constraints do not change)
/// computes those values again from the positions in the history and goes on with the
/// uninterrupted run's bits.
#[test]
fn a_restored_solver_rebuilds_the_kept_multigrid_values() {
    let (model, state) = stiff_cube(10, 0.5, softbody_scene::Preconditioner::Multigrid);
    let mut first = CpuSolver::new(model.clone(), state.clone(), Some(2)).unwrap();
    first.advance(100).unwrap();
    let history = first.history().unwrap();
    let kept = history
        .parts
        .iter()
        .find(|(n, _)| n == "multigrid-kept")
        .unwrap();
    let kept = u32::from_le_bytes(kept.1[..].try_into().unwrap());
    assert!(
        (1..=KEEP_ASSEMBLIES).contains(&kept),
        "kept by {kept} assemblies"
    );
    let halfway = first.state().unwrap().clone();
    let mut second = CpuSolver::new(model, state, Some(3)).unwrap();
    second.restore(100, &halfway, &history).unwrap();
    let before = first.statistics().cg_iterations;
    first.advance(20).unwrap();
    second.advance(20).unwrap();
    let bits = |s: &State| -> Vec<u64> {
        (s.x.iter().chain(&s.v))
            .flat_map(|v| v.to_array())
            .map(f64::to_bits)
            .collect()
    };
    assert!(bits(first.state().unwrap()) == bits(second.state().unwrap()));
    assert_eq!(
        first.statistics().cg_iterations - before,
        second.statistics().cg_iterations
    );
    // A history without the multigrid's parts (a checkpoint of a build before values were
    // kept) restores as one whose multigrid kept nothing: the values computed anew.
    let model = first.model().clone();
    let resumed = |history: &History| {
        let mut solver = CpuSolver::new(model.clone(), halfway.clone(), Some(2)).unwrap();
        solver.restore(100, &halfway, history).unwrap();
        solver.advance(20).unwrap();
        bits(solver.state().unwrap())
    };
    let mut older = history.clone();
    older
        .parts
        .retain(|(name, _)| !name.starts_with("multigrid-"));
    let mut nothing = history.clone();
    for (name, bytes) in &mut nothing.parts {
        if name == "multigrid-kept" {
            *bytes = u32::MAX.to_le_bytes().to_vec();
        }
    }
    assert!(resumed(&older) == resumed(&nothing));
    assert!(
        resumed(&older) != bits(first.state().unwrap()),
        "the kept values were used"
    );
}

/// Not a check, a measurement (`-- --ignored --nocapture`; set `SIZES`, e.g. `10,22,46`,
/// `PRECONDITIONERS` and `THREADS`, default 2): CG iterations and solves per step over the
/// first 120 steps (2 s: the fall, the impact, the settling) of `softbody bench`'s stiff cube
/// (its bottom 0.5 m above the ground, k_s = 10⁴ N/m, h = 1/60 s), the wall-clock steps per
/// second and each stage's time a step.
#[test]
#[ignore]
fn iterations_per_step_of_the_benchmark_run() {
    let list = |name: &str, default: &str| std::env::var(name).unwrap_or(default.into());
    let threads: usize = list("THREADS", "2").parse().unwrap();
    for n in list("SIZES", "10,22").split(',') {
        let n: u32 = n.parse().unwrap();
        for p in list("PRECONDITIONERS", "multigrid,block-jacobi").split(',') {
            let p: softbody_scene::Preconditioner = p.parse().unwrap();
            let (model, state) = stiff_cube(n, 0.5, p);
            let mut solver = CpuSolver::new(model, state, Some(threads)).unwrap();
            let started = Instant::now();
            solver.advance(120).unwrap();
            let seconds = started.elapsed().as_secs_f64();
            let st = solver.statistics();
            println!(
                "{n}³ {p}: {:.1} CG iterations and {:.2} solves per step, {:.2} steps/s",
                st.cg_iterations as f64 / 120.0,
                st.cg_solves as f64 / 120.0,
                120.0 / seconds
            );
            for (stage, t) in st.timings.iter() {
                println!(
                    "    {stage}: {:.2} ms a step ({} calls)",
                    1e3 * t.seconds / 120.0,
                    t.calls
                );
            }
        }
    }
}
