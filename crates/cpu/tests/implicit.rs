//! The CPU's implicit Euler from the inside: its linear system and CG solution against an
//! independent assembly and a direct solve, and the exact momentum accounting of its steps.
//! (Its behaviour on whole scenes is tested on every backend in the top-level `tests/`.)

use glam::{DMat3, DVec3};
use nalgebra::{DMatrix, DVector};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};
use softbody_cpu::CpuSolver;
use softbody_cpu::integrators::implicit_euler::cg::{self, Constraint, Scratch};
use softbody_cpu::integrators::implicit_euler::system::System;
use softbody_cpu::integrators::implicit_euler::{CG_MAX_ITERATIONS, CG_TOLERANCE};
use softbody_scene::{Integrator, Model, Solver, SpringParams, State};
use softbody_testkit::Rng;
use softbody_testkit::scenes::*;

// ---------------------------------------------------------------------------------------------
// The linear system against an independent assembly.

/// A 3×3×3 cube with uneven masses and stiffnesses, perturbed positions (some springs
/// compressed, some stretched), random velocities, drag, gravity, h = 10 ms, no terrain.
fn perturbed_cube() -> (Model, State) {
    let (mut model, state) = perturbed([3, 3, 3]);
    let mut rng = Rng::new(43);
    let springs = model.springs_mut();
    for s in 0..springs.len() {
        springs.stiffness[s] *= 0.5 + rng.unit();
        springs.damping[s] *= 0.5 + rng.unit();
    }
    (model, state)
}

/// A cuboid of `dims` points with uneven masses, perturbed positions, random velocities, drag,
/// gravity, h = 10 ms, no terrain, its springs still a lattice (one stiffness per family).
fn perturbed(dims: [u32; 3]) -> (Model, State) {
    let mut sim = simulation(Integrator::ImplicitEuler, 0.01);
    sim.drag = 0.3;
    let params = SpringParams {
        stiffness: 400.0,
        damping: 0.8,
    };
    let cube = cuboid(
        DVec3::splat(0.4),
        dims,
        DVec3::new(0.0, 1.0, 0.0),
        2.0,
        params,
    );
    let (mut model, mut state) = Model::build(&scene(sim, vec![cuboid_body(cube)], vec![]));
    perturb(&mut model, &mut state);
    (model, state)
}

/// Uneven masses, positions moved by up to 3 cm, random velocities.
fn perturb(model: &mut Model, state: &mut State) {
    let mut rng = Rng::new(42);
    for i in 0..model.len() {
        model.mass[i] = 0.05 + 0.1 * rng.unit();
        model.inv_mass[i] = 1.0 / model.mass[i];
        state.x[i] += rng.vec(0.03);
        state.v[i] = rng.vec(1.0);
    }
}

/// Mesh bodies (masked lattices: points without particles inside their grids, the torus's
/// hole among them), alone and beside a cuboid, perturbed as [`perturbed`]'s cuboid, without
/// contact between bodies (the system's pairs are not the lattices' concern).
fn perturbed_meshes() -> Vec<(&'static str, Model, State)> {
    let body = |file: &str, cell: f64, x: f64| {
        format!(
            "[[body]]\nkind = \"mesh\"\nfile = \"{file}\"\ncell = {cell}\n\
             center = [{x}, 1.0, 0.0]\nrotation = [30.0, 0.0, 10.0]\ndensity = 300.0\n\
             contact_radius = 0.0\n\
             structural = {{ stiffness = 400.0, damping = 0.8 }}\n\
             shear = {{ stiffness = 300.0, damping = 0.8 }}\n\
             bending = {{ stiffness = 200.0, damping = 0.4 }}\n"
        )
    };
    let cuboid = "[[body]]\nkind = \"cuboid\"\nsize = [0.2, 0.3, 0.2]\n\
                  resolution = [3, 4, 3]\ncenter = [-1.0, 1.0, 0.0]\nmass = 2.0\n\
                  contact_radius = 0.0\n\
                  structural = { stiffness = 400.0, damping = 0.8 }\n\
                  shear = { stiffness = 400.0, damping = 0.8 }\n\
                  bending = { stiffness = 400.0, damping = 0.8 }\n";
    let sim = "[simulation]\nintegrator = \"implicit-euler\"\ndt = 0.01\nduration = 0.1\n\
               drag = 0.3\n";
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/test.toml");
    [
        ("torus", format!("{sim}{}", body("torus.obj", 0.05, 0.0))),
        ("star", format!("{sim}{}", body("star.obj", 0.06, 0.0))),
        (
            "cuboid, torus, star",
            format!(
                "{sim}{cuboid}{}{}",
                body("torus.obj", 0.06, 0.0),
                body("star.obj", 0.07, 1.0)
            ),
        ),
    ]
    .map(|(name, text)| {
        let scene = softbody_scene::Scene::from_toml(&text, path.as_ref()).expect("a valid scene");
        let (mut model, mut state) = Model::build(&scene);
        assert!(model.lattices().iter().any(|l| l.mask.is_some()), "{name}");
        perturb(&mut model, &mut state);
        (name, model, state)
    })
    .into()
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
    let sp = model.springs();
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
    system.assemble(&model, (None, None), &state.x, &state.v, &mut b);
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
    let outcome =
        cg::CgProblem::new(&mut system, &model, &constraints, &b, &z).solve(&mut dv, &mut scratch);
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

/// The system on lattices ([`softbody_cpu::integrators::implicit_euler::lattice`]: each
/// spring's terms recomputed at both ends, no spring list) is the independently assembled one,
/// to 1e-12: its b, its diagonal blocks, and its product A p (the assembled matrix times p), on
/// cuboids with 2- and 3-wide dimensions and with planes far enough from the faces to take the
/// grouped loop, and on mesh bodies' masked lattices, alone and beside a cuboid; and it gives
/// the same bits on 1, 2 and 3 threads.
#[test]
fn lattice_product_is_the_assembled_matrix() {
    let cuboids = [
        [3, 3, 3],
        [2, 3, 5],
        [5, 2, 4],
        [7, 6, 3],
        [9, 4, 7],
        [3, 2, 11],
    ]
    .map(|dims| {
        let (model, state) = perturbed(dims);
        (format!("{dims:?}"), model, state)
    });
    let meshes = perturbed_meshes()
        .into_iter()
        .map(|(name, model, state)| (name.to_owned(), model, state));
    for (dims, model, state) in cuboids.into_iter().chain(meshes) {
        let n = model.len();
        println!(
            "{dims}: {n} particles, lattices {:?}",
            model.lattices().iter().map(|l| l.dims).collect::<Vec<_>>()
        );
        let (triplets, b_ref, [stretched, compressed]) = assemble(&model, &state);
        let b_scale = b_ref.iter().map(|b| b.length()).fold(0.0, f64::max);
        assert!(
            stretched > 0 && compressed > 0,
            "{dims}: {stretched}, {compressed}"
        );
        let a_dense = dense(n, &triplets);
        let mut rng = Rng::new(5);
        let p: Vec<DVec3> = (0..n).map(|_| rng.vec(1.0)).collect();
        let ap_ref = unflat(&(&a_dense * flat(&p)));
        let ap_scale = ap_ref.iter().map(|v| v.length()).fold(0.0, f64::max);
        let mut first: Option<Vec<DVec3>> = None;
        for threads in 1..=3 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let ap = pool.install(|| {
                let mut system = System::new(&model);
                assert!(system.lattice.is_some(), "{dims} takes the lattice product");
                let mut b = vec![DVec3::ZERO; n];
                system.assemble(&model, (None, None), &state.x, &state.v, &mut b);
                let b_err = max_diff(&b, &b_ref);
                assert!(b_err <= 1e-12 * b_scale, "{dims}: b differs by {b_err:e}");
                let diag_err = (0..n)
                    .flat_map(|i| (0..3).flat_map(move |r| (0..3).map(move |c| (i, r, c))))
                    .map(|(i, r, c)| {
                        (system.diag[i].col(c)[r] - a_dense[(3 * i + r, 3 * i + c)]).abs()
                    })
                    .fold(0.0, f64::max);
                let diag_scale = a_dense.diagonal().amax();
                assert!(
                    diag_err <= 1e-12 * diag_scale,
                    "{dims}: a diagonal block differs by {diag_err:e}"
                );
                let mut ap = vec![DVec3::ZERO; n];
                system.apply(&model, &p, &mut ap);
                ap
            });
            let err = max_diff(&ap, &ap_ref);
            println!("{dims}, {threads} threads: max error {err:.2e} of {ap_scale:.3e}");
            assert!(err <= 1e-12 * ap_scale, "{dims}: A p differs by {err:e}");
            match &first {
                None => first = Some(ap),
                Some(one) => assert!(
                    one.iter()
                        .zip(&ap)
                        .all(|(a, b)| a.to_array() == b.to_array()),
                    "{dims}: {threads} threads changed the bits"
                ),
            }
        }
    }
}

/// The particle of [`filtered`] whose Δv is prescribed.
const FIXED: usize = 0;
/// The particle of [`filtered`] whose Δv is prescribed along [`slid_normal`].
const SLID: usize = 13;

fn slid_normal() -> DVec3 {
    DVec3::new(1.0, 2.0, -1.0).normalize()
}

/// A filtered system of [`perturbed_cube`] and its direct solution.
struct Filtered {
    model: Model,
    /// The independently assembled matrix.
    a: DMatrix<f64>,
    system: System,
    b: Vec<DVec3>,
    constraints: Vec<Constraint>,
    z: Vec<DVec3>,
    /// Δv = z + Q y with QᵀAQ y = Qᵀ(b − A z), Q an orthonormal basis of the free directions,
    /// by a dense Cholesky factorisation.
    direct: Vec<DVec3>,
}

/// [`perturbed_cube`]'s system with particle [`FIXED`] prescribed to Δv = z, [`SLID`] to
/// Δv·n = z·n ([`slid_normal`]) and the others free.
fn filtered() -> Filtered {
    let (model, state) = perturbed_cube();
    let n = model.len();
    let (triplets, _, _) = assemble(&model, &state);
    let a = dense(n, &triplets);
    let mut system = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    system.assemble(&model, (None, None), &state.x, &state.v, &mut b);
    let normal = slid_normal();
    let mut constraints = vec![Constraint::Free; n];
    constraints[FIXED] = Constraint::Fixed;
    constraints[SLID] = Constraint::Normal(normal);
    let mut z = vec![DVec3::ZERO; n];
    z[FIXED] = DVec3::new(0.01, -0.02, 0.03);
    z[SLID] = 0.05 * normal;

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
    Filtered {
        model,
        a,
        system,
        b,
        constraints,
        z,
        direct,
    }
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
    let Filtered {
        model,
        a,
        mut system,
        b,
        constraints,
        z,
        direct,
    } = filtered();
    let n = model.len();
    let (fixed, slid, normal) = (FIXED, SLID, slid_normal());
    let mut rng = Rng::new(11);
    let mut dv: Vec<DVec3> = (0..n).map(|_| rng.vec(0.1)).collect();
    let mut scratch = Scratch::new(n);
    let outcome =
        cg::CgProblem::new(&mut system, &model, &constraints, &b, &z).solve(&mut dv, &mut scratch);
    assert!(outcome.relative_residual <= CG_TOLERANCE, "{outcome:?}");
    assert_eq!(dv[fixed], z[fixed], "the fixed particle's Δv is z exactly");
    let along = dv[slid].dot(normal);
    assert!(
        (along - 0.05).abs() <= 1e-14,
        "the constrained normal component is {along}, not 0.05"
    );

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

/// The warm start that [`filtered`]'s solve begins from when it may take at most
/// `max_iterations` (0: the projected start itself), from `u0` and the `earlier` solutions.
fn started(
    f: &mut Filtered,
    u0: &[DVec3],
    earlier: &[&[DVec3]],
    max_iterations: u32,
) -> (Vec<DVec3>, u32) {
    let mut dv = u0.to_vec();
    let mut scratch = Scratch::new(dv.len());
    let outcome = cg::CgProblem {
        earlier,
        max_iterations,
        ..cg::CgProblem::new(&mut f.system, &f.model, &f.constraints, &f.b, &f.z)
    }
    .solve(&mut dv, &mut scratch);
    (dv, outcome.iterations)
}

/// ‖Δv − Δv_direct‖_A.
fn a_norm_error(f: &Filtered, dv: &[DVec3]) -> f64 {
    let e = flat(dv) - flat(&f.direct);
    e.dot(&(&f.a * &e)).sqrt()
}

/// The warm start projected with earlier solutions (Fischer's projection) is the combination
/// closest to the solution: when the solution's free part is a combination of the last
/// solution and earlier ones, CG starts at it and takes no iteration (the plain warm start
/// takes several); for random solutions it satisfies the Galerkin condition
/// d_jᵀ(A Δv₀ − b) = 0 for every filtered direction and is no further from the solution in
/// the A-norm than any one of them; and solutions that repeat one another are left out
/// rather than divided by zero.
#[test]
fn the_warm_start_is_the_closest_combination_of_earlier_solutions() {
    let mut f = filtered();
    let n = f.model.len();
    let mut rng = Rng::new(29);
    let mut random = || -> Vec<DVec3> { (0..n).map(|_| rng.vec(0.1)).collect() };
    let (u0, extra) = (random(), random());

    // Spanned: the solution is (u0 + u1)/2.
    let u1: Vec<DVec3> = (0..n).map(|i| 2.0 * f.direct[i] - u0[i]).collect();
    let (plain, plain_iterations) = started(&mut f, &u0, &[], CG_MAX_ITERATIONS);
    let (dv, iterations) = started(&mut f, &u0, &[&u1, &extra], CG_MAX_ITERATIONS);
    let rel = max_diff(&dv, &f.direct) / f.direct.iter().map(|v| v.length()).fold(0.0, f64::max);
    println!("spanned: {iterations} iterations (plain {plain_iterations}), max error {rel:.1e}");
    assert_eq!(iterations, 0, "the solution is in the span");
    assert!(
        plain_iterations > 3,
        "the plain warm start is far: {plain_iterations}"
    );
    assert!(rel <= 1e-10, "{rel:e}");
    assert!(max_diff(&plain, &f.direct) <= 1e-6 * norm(&f.direct));

    // Random: the Galerkin condition, and no further than any of them.
    let (u1, u2) = (random(), random());
    let (dv, _) = started(&mut f, &u0, &[&u1, &u2], 0);
    let residual = flat(&f.b) - &f.a * flat(&dv);
    let scale = norm(&f.b);
    for (name, u) in [("u0", &u0), ("u1", &u1), ("u2", &u2)] {
        let d: Vec<DVec3> = u
            .iter()
            .zip(&f.constraints)
            .map(|(u, s)| s.filter(*u))
            .collect();
        let galerkin = flat(&d).dot(&residual) / (norm(&d) * scale);
        assert!(
            galerkin.abs() <= 1e-12,
            "{name}: dᵀ(b − AΔv₀) = {galerkin:e} relative"
        );
    }
    assert_eq!(dv[FIXED], f.z[FIXED], "the prescribed Δv is kept");
    let projected = a_norm_error(&f, &dv);
    for (name, u) in [("u0", &u0), ("u1", &u1), ("u2", &u2)] {
        let (alone, _) = started(&mut f, u, &[], 0);
        let error = a_norm_error(&f, &alone);
        println!("random: A-norm error {projected:.4e}, from {name} alone {error:.4e}");
        assert!(projected <= error, "{name}: {projected:e} > {error:e}");
    }

    // Repeated: u0 twice is u0 alone, scaled to the best multiple.
    let (twice, _) = started(&mut f, &u0, &[&u0, &u0], 0);
    let d: Vec<DVec3> = u0
        .iter()
        .zip(&f.constraints)
        .map(|(u, s)| s.filter(*u))
        .collect();
    let ad = &f.a * flat(&d);
    let best = (flat(&d).dot(&(flat(&f.b) - &f.a * flat(&f.z)))) / flat(&d).dot(&ad);
    let expected: Vec<DVec3> = (0..n).map(|i| f.z[i] + best * d[i]).collect();
    let err = max_diff(&twice, &expected) / norm(&expected);
    assert!(
        err <= 1e-12,
        "u0 repeated: {err:e} from the best multiple of u0"
    );
}

// ---------------------------------------------------------------------------------------------
// Momentum.

/// Implicit Euler's momentum accounting, exactly: with no gravity, drag or terrain, Σ m Δv =
/// Σ (AΔv)_i (the spring blocks of A have zero column sums) and Σ b_i = 0, so each step changes
/// the momentum by −Σ r_i, r = b − AΔv the CG residual, recomputed here from Δv = v' − v; to
/// 1e-14 of the momentum scale Σ m|v| over 400 steps of a perturbed cube. (The drift this
/// allows is bounded by the CG tolerance in `tests/integrators.rs`, on every backend.)
#[test]
fn implicit_steps_change_momentum_by_minus_the_residual_sum() {
    let (model, state) = tumbling_cube(Integrator::ImplicitEuler);
    let scale = momentum_scale(&model, &state);
    let n = model.len();
    let mut system = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    let mut solver = CpuSolver::new(model.clone(), state, Some(1)).unwrap();
    let mut worst = 0.0f64;
    for _ in 0..400 {
        let st = solver.state().unwrap();
        system.assemble(&model, (None, None), &st.x, &st.v, &mut b);
        let (v_before, p_before) = (st.v.clone(), momentum(&model, st));
        solver.advance(1).unwrap();
        let st = solver.state().unwrap();
        let dv: Vec<DVec3> = st.v.iter().zip(&v_before).map(|(a, b)| *a - *b).collect();
        let mut a_dv = vec![DVec3::ZERO; n];
        system.apply(&model, &dv, &mut a_dv);
        let residual_sum = b
            .iter()
            .zip(&a_dv)
            .fold(DVec3::ZERO, |acc, (b, a)| acc + (*b - *a));
        let dp = momentum(&model, st) - p_before;
        worst = worst.max((dp + residual_sum).length());
    }
    println!("max |ΔP + Σr| = {worst:.2e} (scale {scale:.3e})");
    assert!(worst <= 1e-14 * scale, "ΔP differs from −Σr by {worst:e}");
}
