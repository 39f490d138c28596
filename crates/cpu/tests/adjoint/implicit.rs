//! Implicit Euler: held stretched (no contact), in contact with the terrain, and through
//! contact between bodies.

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::adjoint::run::gradient;
use softbody_scene::{Integrator, Model, Solver, State};

use crate::cases::cases;
use crate::harness::{Case, Probe, build, check_case, threads};

/// Implicit Euler's linearisation keeps a spring's transverse stiffness k_s·max(0, 1 − r/ℓ):
/// a kink where a spring passes its rest length, which the run's derivative has there (the
/// branch's one-sided one), and which central differences straddle whenever a spring passes
/// within their δ of it (the free-flying cube's springs do, several times in 120 steps: the
/// differences' error then falls as δ, not δ²). So its case holds every spring stretched,
/// which is asserted along the run with a margin (1 % of the rest length) far above the
/// differences' moves (~1e-6 of the values' scale).
///
/// The forward solves each step by CG to a relative residual τ = 1e-8 (`CG_TOLERANCE`), and
/// the adjoint the transposed system to the same τ: both are the exact steps' to O(τ)
/// relative, at a fixed iteration count a smooth function of the values (differences of
/// δ = 1e-6 of the scale change Δv by ~1e-6 of itself, and straddle no change of the count).
/// The adjoint matches the differences to O(τ·κ^½), κ the preconditioned system's condition
/// number, O(1) at h = 1e-3 for these springs (h²k_s/m ≈ 3e-2): the bound is 100 τ = 1e-6,
/// the explicit integrators' own.
#[test]
fn the_implicit_adjoint_is_the_derivative_of_the_computed_run() {
    let integrator = Integrator::ImplicitEuler;
    let case = cases(integrator)
        .into_iter()
        .find(|c| c.name == "held stretched")
        .unwrap();
    let (model, state) = build(&case);
    assert_stretched(&model, state);
    let mut failures = Vec::new();
    check_case(integrator, &case, &mut failures);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Implicit Euler in contact with the terrain: three particles on stretched springs (their
/// rest lengths 80 % of the start's, so that no spring passes the kink of its transverse
/// stiffness, asserted along the run as for the held cube) landing on a surface at 5 cm/s:
/// fresh impacts that rebound (restitution 0.3), releases, then contact throughout, sliding
/// down a 20° plane (kinetic Coulomb friction, μ = 0.1 < tan 20°) and in a bowl (viscous
/// friction, the normal turning with the particles). The contact band is the default 1 mm.
///
/// The forward refreshes a slipping contact's friction impulse until its normal impulse moves
/// by less than 1e-6 of itself (`FRICTION_REFRESH`), so the step's friction is its own solve's
/// to 1e-6 relative: the transpose of that consistent step matches the computed run's
/// differences to the friction's share of 1e-6 plus O(τ·κ^½) (the held cube's derivation),
/// within the bound 1e-6. The positions move along a symmetry of the terrain (down the slope, round
/// the bowl's axis), which keeps every contact's branch; the branches' margins (rebounds of
/// ~1 cm/s against −φ/h, impulses of ~1e-2 N·s against zero) are far above the differences'
/// moves. (A body coming to rest has contacts that turn from sticking to slipping, whose
/// friction direction the transpose holds: docs/physics.md.)
pub fn implicit_contact_cases() -> Vec<Case> {
    let sim = "[simulation]\nintegrator = \"implicit-euler\"\ndt = 1e-3\nduration = 0.12\n\
               frame_rate = 100.0\ndrag = 0.2\n";
    let n = DVec3::new(0.36397023426620234, 1.0, 0.0).normalize();
    let down = DVec3::new(0.9397, -0.3420, 0.0).normalize();
    let plane = {
        let x = [DVec3::ZERO, 0.05 * down, 0.03 * down + 0.04 * DVec3::Z];
        let v = x.map(|_| 0.3 * down + 0.1 * DVec3::Z - 0.05 * n);
        sim.to_string()
            + &triangle(x, v)
            + &format!(
                "[[terrain]]\nkind = \"plane\"\nnormal = {:?}\nfriction = 0.1\n\
                 friction_model = \"coulomb\"\nrestitution = 0.3\n",
                n.to_array()
            )
    };
    let center = DVec3::Y;
    let on_bowl = |x: f64, z: f64| DVec3::new(x, 1.0 - (1.0 - x * x - z * z).sqrt(), z);
    let x = [on_bowl(0.1, 0.0), on_bowl(0.14, 0.02), on_bowl(0.11, 0.05)];
    let v = x.map(|x| {
        let n = (center - x).normalize();
        let t = DVec3::new(-0.3, 0.0, 0.2);
        t - t.dot(n) * n - 0.05 * n
    });
    let bowl = sim.to_string()
        + &triangle(x, v)
        + "[[terrain]]\nkind = \"bowl\"\ncenter = [0.0, 1.0, 0.0]\nradius = 1.0\n\
           friction = 0.4\nfriction_model = \"viscous\"\nrestitution = 0.3\n";
    let case = |name, toml, x0: fn(usize, DVec3) -> DVec3| Case {
        name,
        toml,
        spin: 0.0,
        strain: 0.0,
        stretch: 1.0,
        x0,
    };
    let along: fn(usize, DVec3) -> DVec3 = |_, _| DVec3::new(0.9397, -0.3420, 0.0);
    vec![
        case("sliding on a slope", plane, along),
        case("in a bowl", bowl, |_, x| DVec3::Y.cross(x - DVec3::Y)),
    ]
}

/// Three particles at `x` with velocities `v`, on springs 80 % of their lengths long.
fn triangle(x: [DVec3; 3], v: [DVec3; 3]) -> String {
    let spring = |a: usize, b: usize| {
        format!(
            "{{ a = {a}, b = {b}, stiffness = 20.0, damping = 0.1, rest = {} }}",
            0.8 * (x[a] - x[b]).length()
        )
    };
    format!(
        "[[body]]\nkind = \"particles\"\npositions = {:?}\nmasses = [0.5, 0.7, 0.6]\n\
         velocities = {:?}\nsprings = [{}, {}, {}]\n",
        x.map(|p| p.to_array()),
        v.map(|p| p.to_array()),
        spring(0, 1),
        spring(1, 2),
        spring(0, 2)
    )
}

/// Every spring of the run from `state` stays stretched by more than 1 % (the margin of the
/// implicit cases: their differences move lengths by ~1e-6 of the scale).
fn assert_stretched(model: &Model, state: State) {
    let mut solver = CpuSolver::new(model.clone(), state, Some(1)).unwrap();
    let springs = model.springs();
    for step in 0..=model.simulation.steps() {
        let x = &solver.state().unwrap().x;
        for s in 0..springs.len() {
            let len = (x[springs.a[s] as usize] - x[springs.b[s] as usize]).length();
            let strain = len / springs.rest[s] - 1.0;
            assert!(strain > 0.01, "step {step}: spring {s} at strain {strain}");
        }
        solver.advance(1).unwrap();
    }
}

#[test]
fn the_implicit_adjoint_in_contact_is_the_derivative_of_the_computed_run() {
    let mut failures = Vec::new();
    for case in implicit_contact_cases() {
        let (model, state) = build(&case);
        assert_stretched(&model, state.clone());
        // The case reaches its laws: friction and fresh impacts.
        let back = gradient(&model, &state, &mut Probe::new(model.len()), threads(1)).unwrap();
        let g = &back.gradient;
        assert!(
            g.friction_of(0) != 0.0 && g.restitution_of(0) != 0.0,
            "{}",
            case.name
        );
        check_case(Integrator::ImplicitEuler, &case, &mut failures);
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Implicit Euler through contact between bodies: a particle on a stretched spring (rest 80 %
/// of the start's, as in the terrain's cases) meets a lone particle of another body, both in
/// free fall, so that no spring passes its kink and the pair's laws are the only branches.
///
/// - "bodies' impact": from 4.24 cm above at 3 m/s, 3 mm to the side, a fresh impact within the
///   11th step that ends at d = 0.9915 R (within R, not pushed: past the slop's 0.9 R),
///   kinetic Coulomb friction and restitution 0.5 (μ = 2e-4: implicit Euler's stiff penalty
///   presses the impact with h·(k (R − d) − c u_n) ≈ 58 N·s against a sticking impulse
///   |u_t|/W ≈ 0.2 N·s, so that μ above 3e-3 sticks); at the next step's start the pair
///   separates too fast for its penalty to push (F = −1.1e3 N against k (R − d) = 1.9e4 N),
///   so the system leaves it out, and then it is apart.
/// - "bodies grazing": at 0.25 m/s across 0.5 m/s of slip, a fresh impact within the 2nd step
///   that ends at 0.985 R, viscous friction under its cap (k_f = 2e-3: 0.04 N·s against
///   0.11 N·s); the pair's penalty then
///   pushes at the next two steps' starts (F = 3.1e4 N, then 8.7 N against its terms' 2e3 N)
///   and is in the system, which separates the pair (F < 0 at the step after: −29 N).
///
/// Every branch holds by far more than the differences' moves (1e-6 of each value's scale).
/// The pair's block in the system, β nnᵀ with β = (κ + 2√κ) m_red ≈ 1063 m_red (κ =
/// `PENALTY_IMPLICIT`), couples the two particles so strongly that the block-Jacobi
/// preconditioned system's condition number is ≈ 2β/m ≈ 2·10³ (the diagonal blocks hold β as
/// well): CG's relative residual τ bounds the error of Δv to ≈ κτ, 2e-5 at the default 1e-8,
/// past the differences' 1e-6; the cases solve to τ = 1e-12 (κτ ≈ 2e-9).
pub fn implicit_body_cases() -> Vec<Case> {
    let sim = |friction: &str| {
        format!(
            "[simulation]\nintegrator = \"implicit-euler\"\ndt = 1e-3\nduration = 0.02\n\
             frame_rate = 100.0\ndrag = 0.2\nbody_restitution = 0.5\ncg_tolerance = 1e-12\n{friction}"
        )
    };
    let bodies = |a: DVec3, v: DVec3| {
        let other = a + DVec3::new(0.03, 0.005, 0.01);
        format!(
            "[[body]]\nkind = \"particles\"\npositions = [[0.0, 0.0, 0.0]]\nmasses = [0.8]\n\
             contact_radius = 0.005\n\
             [[body]]\nkind = \"particles\"\npositions = {:?}\nmasses = [0.3, 0.4]\n\
             velocities = {:?}\ncontact_radius = 0.005\n\
             springs = [{{ a = 0, b = 1, stiffness = 20.0, damping = 0.1, rest = {} }}]\n",
            [a.to_array(), other.to_array()],
            [v.to_array(), v.to_array()],
            0.8 * (a - other).length()
        )
    };
    let case = |name, toml| Case {
        name,
        toml,
        spin: 0.0,
        strain: 0.0,
        stretch: 1.0,
        x0: crate::cases::scattered,
    };
    vec![
        case(
            "bodies' impact",
            sim("body_friction = 2e-4\n")
                + &bodies(DVec3::new(0.003, 0.0424, 0.0), DVec3::new(0.0, -3.0, 0.0)),
        ),
        case(
            "bodies grazing",
            sim("body_friction = 2e-3\nbody_friction_model = \"viscous\"\n")
                + &bodies(DVec3::new(0.0103, 0.0, 0.0), DVec3::new(-0.25, 0.0, 0.5)),
        ),
    ]
}

#[test]
fn the_implicit_adjoint_through_contact_between_bodies_is_the_derivative_of_the_computed_run() {
    let mut failures = Vec::new();
    for case in implicit_body_cases() {
        let (model, state) = build(&case);
        assert_stretched(&model, state.clone());
        // The case reaches its laws: kinetic or viscous friction (a sticking contact's impulse
        // does not depend on μ) and fresh impacts.
        let back = gradient(&model, &state, &mut Probe::new(model.len()), threads(1)).unwrap();
        let g = &back.gradient;
        assert!(
            g.body_friction_total() != 0.0 && g.body_restitution_total() != 0.0,
            "{}",
            case.name
        );
        check_case(Integrator::ImplicitEuler, &case, &mut failures);
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
