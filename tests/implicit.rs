//! Implicit Euler: its linear system and CG solution against an independent assembly and a
//! direct solve, and its behaviour on a stiff cube at a frame-sized step (where explicit Euler
//! must be reported unstable).

mod common;

use common::*;
use glam::{DMat3, DVec3};
use nalgebra::{DMatrix, DVector};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};
use softbody::cpu::integrators::implicit_euler::cg::{self, Constraint, Scratch};
use softbody::cpu::integrators::implicit_euler::system::System;
use softbody::cpu::integrators::implicit_euler::{CG_MAX_ITERATIONS, CG_TOLERANCE};
use softbody::output::{Frame, FrameSink, Header};
use softbody::run::{self, RunError};
use softbody::scene::SpringParams;
use softbody::{Integrator, Model, Scene, Solver, State, StepError};

// ---------------------------------------------------------------------------------------------
// The linear system against an independent assembly.

/// A 3×3×3 cube with uneven masses and stiffnesses, perturbed positions (some springs
/// compressed, some stretched), random velocities, drag, gravity, h = 10 ms, no terrain.
fn perturbed_cube() -> (Model, State) {
    let mut sim = simulation(Integrator::ImplicitEuler, 0.01);
    sim.drag = 0.3;
    let params = SpringParams {
        stiffness: 400.0,
        damping: 0.8,
    };
    let cube = cuboid(
        DVec3::splat(0.4),
        [3, 3, 3],
        DVec3::new(0.0, 1.0, 0.0),
        2.0,
        params,
    );
    let (mut model, mut state) = Model::build(&scene(sim, vec![cuboid_body(cube)], vec![]));
    let mut rng = Rng::new(42);
    for i in 0..model.len() {
        model.mass[i] = 0.05 + 0.1 * rng.unit();
        model.inv_mass[i] = 1.0 / model.mass[i];
        state.x[i] += rng.vec(0.03);
        state.v[i] = rng.vec(1.0);
    }
    for s in 0..model.springs.len() {
        model.springs.stiffness[s] *= 0.5 + rng.unit();
        model.springs.damping[s] *= 0.5 + rng.unit();
    }
    (model, state)
}

/// Triplets of A, the right-hand side b, and the counts of stretched and compressed springs.
type Assembled = (Vec<(usize, usize, f64)>, Vec<DVec3>, [usize; 2]);

/// A = M(1 + h·drag) + Σ_s B_s on the blocks (a,a), (b,b) and −B_s on (a,b), (b,a), with
/// B = h k_d uuᵀ + h² K, K = k_s[uuᵀ + α(I − uuᵀ)], α = max(0, 1 − r/ℓ); and
/// b = h(f + h ∂f/∂x v) with f = m g − drag·m·v + springs and (∂f/∂x v)_a = −K(v_a − v_b),
/// (∂f/∂x v)_b = +K(v_a − v_b). Assembled here from the documented formula, as triplets
/// (duplicates add) and the right-hand side.
fn assemble(model: &Model, state: &State) -> Assembled {
    let sim = &model.simulation;
    let h = sim.dt;
    let n = model.len();
    let mut triplets = Vec::new();
    let mut push_block = |i: usize, j: usize, m: DMat3| {
        for r in 0..3 {
            for c in 0..3 {
                triplets.push((3 * i + r, 3 * j + c, m.col(c)[r]));
            }
        }
    };
    let mut b: Vec<DVec3> = (0..n)
        .map(|i| {
            let m = model.mass[i];
            m * sim.gravity - sim.drag * m * state.v[i]
        })
        .collect();
    let mut dfdx_v = vec![DVec3::ZERO; n];
    for i in 0..n {
        push_block(
            i,
            i,
            DMat3::from_diagonal(DVec3::splat(model.mass[i] * (1.0 + h * sim.drag))),
        );
    }
    let mut kinds = [0usize; 2]; // [stretched (α > 0), compressed (α = 0)]
    let sp = &model.springs;
    for s in 0..sp.len() {
        let (a, bb) = (sp.a[s] as usize, sp.b[s] as usize);
        let (ks, kd, r) = (sp.stiffness[s], sp.damping[s], sp.rest[s]);
        let d = state.x[a] - state.x[bb];
        let len = d.length();
        let u = d / len;
        let alpha = (1.0 - r / len).max(0.0);
        kinds[usize::from(alpha == 0.0)] += 1;
        let uu = DMat3::from_cols(u * u.x, u * u.y, u * u.z);
        let k = ks * (uu + alpha * (DMat3::IDENTITY - uu));
        let block = h * kd * uu + h * h * k;
        push_block(a, a, block);
        push_block(bb, bb, block);
        push_block(a, bb, -block);
        push_block(bb, a, -block);
        let w = state.v[a] - state.v[bb];
        let f = -(ks * (len - r) + kd * w.dot(u)) * u;
        b[a] += f;
        b[bb] -= f;
        dfdx_v[a] -= k * w;
        dfdx_v[bb] += k * w;
    }
    let b = b
        .iter()
        .zip(&dfdx_v)
        .map(|(f, kv)| h * (*f + h * *kv))
        .collect();
    (triplets, b, kinds)
}

fn dense(n: usize, triplets: &[(usize, usize, f64)]) -> DMatrix<f64> {
    let mut a = DMatrix::zeros(3 * n, 3 * n);
    for &(i, j, v) in triplets {
        a[(i, j)] += v;
    }
    a
}

fn flat(v: &[DVec3]) -> DVector<f64> {
    DVector::from_iterator(3 * v.len(), v.iter().flat_map(|p| p.to_array()))
}

fn unflat(v: &DVector<f64>) -> Vec<DVec3> {
    (0..v.len() / 3)
        .map(|i| DVec3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]))
        .collect()
}

fn norm(v: &[DVec3]) -> f64 {
    v.iter().map(|p| p.length_squared()).sum::<f64>().sqrt()
}

fn max_diff(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max)
}

/// The solver's b equals the independently assembled one to 1e-12 (relative to max |b_i|); its
/// matrix-free product A p equals the assembled matrix times p to 1e-12; and CG with every
/// particle free, at the production tolerance, matches a sparse Cholesky solve of the assembled
/// matrix to 1e-6 relative (its stopping rule bounds the preconditioned residual by 1e-8, and
/// the block-Jacobi-preconditioned matrix of this small system is well conditioned).
#[test]
fn cg_solution_matches_a_direct_sparse_solve() {
    let (model, state) = perturbed_cube();
    let n = model.len();
    let (triplets, b_ref, [stretched, compressed]) = assemble(&model, &state);
    assert!(
        stretched > 20 && compressed > 20,
        "both kinds of springs: {stretched} stretched, {compressed} compressed"
    );

    let mut system = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    system.assemble(&model, &state.x, &state.v, &mut b);
    let b_scale = b_ref.iter().map(|b| b.length()).fold(0.0, f64::max);
    let b_err = max_diff(&b, &b_ref);
    println!("b: max |b − b_ref| = {b_err:.2e} (max |b_i| = {b_scale:.3e})");
    assert!(b_err <= 1e-12 * b_scale, "b differs by {b_err:e}");

    // A p, matrix-free and assembled.
    let a_dense = dense(n, &triplets);
    let mut rng = Rng::new(3);
    let p: Vec<DVec3> = (0..n).map(|_| rng.vec(1.0)).collect();
    let mut ap = vec![DVec3::ZERO; n];
    system.apply(&model, &p, &mut ap);
    let ap_ref = unflat(&(&a_dense * flat(&p)));
    let ap_scale = ap_ref.iter().map(|v| v.length()).fold(0.0, f64::max);
    let ap_err = max_diff(&ap, &ap_ref);
    println!("A p: max error {ap_err:.2e} (max |(Ap)_i| = {ap_scale:.3e})");
    assert!(ap_err <= 1e-12 * ap_scale, "A p differs by {ap_err:e}");

    // Direct: sparse Cholesky of the assembled matrix.
    let mut coo = CooMatrix::new(3 * n, 3 * n);
    for &(i, j, v) in &triplets {
        coo.push(i, j, v);
    }
    let csc = CscMatrix::from(&coo);
    let chol = CscCholesky::factor(&csc).expect("A is symmetric positive definite");
    let direct = unflat(&DVector::from_column_slice(
        chol.solve(&flat(&b_ref)).as_slice(),
    ));

    let constraints = vec![Constraint::Free; n];
    let z = vec![DVec3::ZERO; n];
    let mut dv = vec![DVec3::ZERO; n];
    let mut scratch = Scratch::new(n);
    let outcome = cg::solve(
        &mut system,
        &model,
        &constraints,
        &b,
        &z,
        &mut dv,
        &mut scratch,
        CG_TOLERANCE,
        CG_MAX_ITERATIONS,
    );
    let diff: Vec<DVec3> = dv.iter().zip(&direct).map(|(a, b)| *a - *b).collect();
    let rel = norm(&diff) / norm(&direct);
    println!(
        "free: CG {} iterations, residual {:.1e}, ‖Δv − Δv_direct‖/‖Δv_direct‖ = {rel:.2e}",
        outcome.iterations, outcome.relative_residual
    );
    assert!(outcome.relative_residual <= CG_TOLERANCE, "{outcome:?}");
    assert!(
        rel <= 1e-6,
        "CG differs from the direct solve by {rel:e} relative"
    );
}

/// The filtered solve: particle 0 is `Fixed` with a prescribed Δv₀ = z₀, the centre particle 13
/// has a `Normal(n)` constraint with Δv₁₃·n = z₁₃·n, the rest are free, and CG starts from a
/// random warm start. Its Δv must keep the prescribed components (exactly for the fixed
/// particle, to round-off for the normal one) and solve the reduced system on the free
/// components: compared with a dense Cholesky solve of QᵀAQ y = Qᵀ(b − A z), Δv = z + Q y (Q an
/// orthonormal basis of the free directions) to 1e-6 relative, and with the free residual
/// ‖S(AΔv − b)‖ ≤ √κ(P)·tol·‖Sb‖, κ(P) bounding the condition of the block diagonal (the CG stops
/// on the P⁻¹-norm of the residual).
#[test]
fn filtered_cg_keeps_constraints_and_solves_the_free_subspace() {
    let (model, state) = perturbed_cube();
    let n = model.len();
    let (triplets, _, _) = assemble(&model, &state);
    let a = dense(n, &triplets);
    let mut system = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    system.assemble(&model, &state.x, &state.v, &mut b);

    let normal = DVec3::new(1.0, 2.0, -1.0).normalize();
    let (fixed, slid) = (0usize, 13usize);
    let mut constraints = vec![Constraint::Free; n];
    constraints[fixed] = Constraint::Fixed;
    constraints[slid] = Constraint::Normal(normal);
    let mut z = vec![DVec3::ZERO; n];
    z[fixed] = DVec3::new(0.01, -0.02, 0.03);
    z[slid] = 0.05 * normal;
    let mut rng = Rng::new(11);
    let mut dv: Vec<DVec3> = (0..n).map(|_| rng.vec(0.1)).collect();
    let mut scratch = Scratch::new(n);
    let outcome = cg::solve(
        &mut system,
        &model,
        &constraints,
        &b,
        &z,
        &mut dv,
        &mut scratch,
        CG_TOLERANCE,
        CG_MAX_ITERATIONS,
    );
    assert!(outcome.relative_residual <= CG_TOLERANCE, "{outcome:?}");
    assert_eq!(dv[fixed], z[fixed], "the fixed particle's Δv is z exactly");
    let along = dv[slid].dot(normal);
    assert!(
        (along - 0.05).abs() <= 1e-14,
        "the constrained normal component is {along}, not 0.05"
    );

    // The reduced direct solve.
    let (t1, t2) = normal.any_orthonormal_pair();
    let mut basis: Vec<(usize, DVec3)> = Vec::new();
    for (i, constraint) in constraints.iter().enumerate() {
        match constraint {
            Constraint::Free => basis.extend([DVec3::X, DVec3::Y, DVec3::Z].map(|e| (i, e))),
            Constraint::Normal(_) => basis.extend([(i, t1), (i, t2)]),
            Constraint::Fixed => {}
        }
    }
    let mut q = DMatrix::zeros(3 * n, basis.len());
    for (col, (i, e)) in basis.iter().enumerate() {
        for r in 0..3 {
            q[(3 * i + r, col)] = e[r];
        }
    }
    let rhs = q.transpose() * (flat(&b) - &a * flat(&z));
    let reduced = q.transpose() * &a * &q;
    let y = reduced
        .cholesky()
        .expect("QᵀAQ is positive definite")
        .solve(&rhs);
    let direct = unflat(&(flat(&z) + &q * y));
    let diff: Vec<DVec3> = dv.iter().zip(&direct).map(|(a, b)| *a - *b).collect();
    let rel = norm(&diff) / norm(&direct);

    // The free residual against the bound from the preconditioned stopping rule.
    let filter = |v: Vec<DVec3>| -> Vec<DVec3> {
        v.iter()
            .zip(&constraints)
            .map(|(p, s)| s.filter(*p))
            .collect()
    };
    let r = filter(unflat(&(&a * flat(&dv) - flat(&b))));
    let sb = filter(b.clone());
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for i in 0..n {
        let block = a.view((3 * i, 3 * i), (3, 3)).symmetric_eigenvalues();
        lo = lo.min(block.min());
        hi = hi.max(block.max());
    }
    let bound = (hi / lo).sqrt() * CG_TOLERANCE * norm(&sb);
    println!(
        "filtered: CG {} iterations, residual {:.1e}, ‖Δv − Δv_direct‖/‖Δv_direct‖ = {rel:.2e}, \
         ‖S(AΔv − b)‖ = {:.2e} (bound {bound:.2e}), normal component error {:.1e}",
        outcome.iterations,
        outcome.relative_residual,
        norm(&r),
        (along - 0.05).abs()
    );
    assert!(
        rel <= 1e-6,
        "filtered CG differs from the direct solve by {rel:e}"
    );
    assert!(
        norm(&r) <= bound,
        "free residual {:e} > {bound:e}",
        norm(&r)
    );
}

// ---------------------------------------------------------------------------------------------
// A stiff cube at a frame-sized step.

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
///   3.4 J; backward Euler with damping and perfectly inelastic contact only dissipates);
/// - it never sinks: min y ≥ −ε at every step;
/// - at the end (5 s) it is at rest (kinetic energy < 1e-8 J), every spring is within 10 % of its
///   rest length, and the bounding box is within 5 % of the original 0.5 m per axis, resting on
///   the plane (bottom within ε of y = 0).
#[test]
fn implicit_euler_keeps_a_stiff_cube_stable_at_a_frame_step() {
    let scene = stiff_cube(Integrator::ImplicitEuler);
    let (model, state) = Model::build(&scene);
    let stable = model.stable_dt().unwrap();
    assert!(scene.simulation.dt > 50.0 * stable, "stable dt {stable:e}");
    let eps = scene.simulation.contact_distance;
    let mut solver = solver_from(model.clone(), state, 1);
    let steps = scene.simulation.steps();
    let mut e_prev = solver.energies().unwrap().total();
    let e0 = e_prev;
    let (mut worst_rise, mut worst_step, mut lowest) = (f64::NEG_INFINITY, 0, f64::INFINITY);
    for k in 1..=steps {
        solver.advance(1).unwrap();
        let e = solver.energies().unwrap().total();
        assert!(e.is_finite());
        if e - e_prev > worst_rise {
            (worst_rise, worst_step) = (e - e_prev, k);
        }
        e_prev = e;
        let st = solver.state().unwrap();
        lowest = lowest.min(st.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min));
    }
    let energies = solver.energies().unwrap();
    let stats = solver.statistics();
    let st = solver.state().unwrap();
    let sp = &model.springs;
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
         final kinetic {:.2e} J, worst strain {worst_strain:.4}, box {size:.4}, lowest y {lowest:.2e}, \
         {} CG iterations in {} solves (max residual {:.1e})",
        energies.total(),
        energies.kinetic,
        stats.cg_iterations,
        stats.cg_solves,
        stats.cg_max_residual
    );
    let mut failures = Vec::new();
    if worst_rise > 1e-9 {
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
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

/// The same scene with explicit Euler at h = 1/60 (≈ 100× its stable step) must be reported
/// unstable: `advance` stops with `StepError::Unstable` naming a step ≥ 1 within the run and a
/// particle of the model, and `run::run` stops with `RunError::Unstable` (the energy guard or the
/// non-finite check), having written only frames before the instability, frame 0 included.
#[test]
fn explicit_euler_on_the_stiff_cube_is_reported_unstable() {
    let scene = stiff_cube(Integrator::ExplicitEuler);
    let steps = scene.simulation.steps();
    let (model, state) = Model::build(&scene);
    let n = model.len() as u32;
    let mut solver = solver_from(model.clone(), state.clone(), 1);
    match solver.advance(steps) {
        Err(StepError::Unstable(i)) => {
            println!("advance: {i}");
            assert!(i.step >= 1 && i.step <= steps, "{i:?}");
            assert_eq!(solver.steps_taken(), i.step);
            assert!((i.time - i.step as f64 * scene.simulation.dt).abs() < 1e-12);
            assert!(i.particle < n, "{i:?}");
            let st = solver.state().unwrap();
            let p = i.particle as usize;
            assert!(!(st.x[p].is_finite() && st.v[p].is_finite()), "{i:?}");
            // It names the first such particle.
            assert!(
                st.x[..p]
                    .iter()
                    .zip(&st.v[..p])
                    .all(|(x, v)| x.is_finite() && v.is_finite())
            );
        }
        other => panic!("explicit Euler at h = 1/60 on k = 1e4: {other:?}"),
    }

    let mut solver = solver_from(model, state, 1);
    let mut sink = Frames::default();
    match run::run(&mut solver, None, &mut sink, &mut |_, _| {}) {
        Err(RunError::Unstable(i)) => {
            println!("run: {i}; {} frames written", sink.steps.len());
            assert!(i.step >= 1 && i.step <= steps, "{i:?}");
            assert!(i.particle < n, "{i:?}");
            assert!(sink.header, "the header is written first");
            assert!(
                !sink.steps.is_empty() && sink.steps[0] == 0,
                "frame 0 is written"
            );
            assert!(
                sink.steps.iter().all(|&s| s < i.step),
                "frames {:?} after the instability at step {}",
                sink.steps,
                i.step
            );
            assert!(sink.energies.iter().all(|e| e.is_finite()));
        }
        other => panic!("run of explicit Euler at h = 1/60: {other:?}"),
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
