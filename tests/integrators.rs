//! The integrators against closed forms: a damped two-body spring, free fall (the exact discrete
//! recurrences of each method), measured orders of convergence, and conservation of linear
//! momentum by the internal spring forces.

mod common;

use common::*;
use glam::DVec3;
use softbody::cpu::integrators::implicit_euler::{CG_TOLERANCE, system::System};
use softbody::scene::ExplicitSpring;
use softbody::{Integrator, Model, Solver, State};

/// Two particles on one damped spring, moving along the x axis, no gravity.
///
/// With masses m₁, m₂, the reduced mass μ = m₁m₂/(m₁ + m₂) and the stretch s = |x₂ − x₁| − r,
/// the separation obeys μ s'' = −k s − c s' exactly (the motion stays on the spring's axis, where
/// the spring force is linear in the separation, so even implicit Euler's linearisation is exact).
/// With σ = c/(2μ), ω₀² = k/μ and ω_d² = ω₀² − σ²:
/// s(t) = e^{−σt} (s₀ cos ω_d t + (s'₀ + σ s₀)/ω_d sin ω_d t).
///
/// Tolerances: the leading global error of each method on the oscillator ż = (σ-damped) iω₀z,
/// over the time T, with amplitude A (all twice the leading term, plus a round-off floor of
/// 10·N·ε·A for N steps):
/// - explicit / implicit Euler: the amplification factor |1 ± hλ| is off by h²ω₀²/2 per step, so
///   the amplitude drifts by A·ω₀²hT/2 (grows / decays);
/// - symplectic Euler: no drift, but its invariant ellipse is sheared by O(ω₀h): error A·ω₀h/2;
/// - midpoint: phase error ω₀³h²T/6 per unit amplitude (amplitude drift is O(h⁴));
/// - RK4: phase and amplitude error ω₀⁵h⁴T/120 per unit amplitude.
#[test]
fn two_body_spring_matches_the_damped_oscillator() {
    let (m1, m2, k, c, rest): (f64, f64, f64, f64, f64) = (1.0, 2.0, 100.0, 0.2, 1.0);
    let mu = m1 * m2 / (m1 + m2);
    let (s0, ds0) = (0.1, 0.3); // initial stretch and its rate
    let (va, vb) = (DVec3::new(-0.1, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0));
    assert!((vb.x - va.x - ds0).abs() < 1e-15);
    let sigma = c / (2.0 * mu);
    let w0 = (k / mu).sqrt();
    let wd = (w0 * w0 - sigma * sigma).sqrt();
    let exact = |t: f64| {
        (-sigma * t).exp() * (s0 * (wd * t).cos() + (ds0 + sigma * s0) / wd * (wd * t).sin())
    };
    let amplitude = (s0 * s0 + ((ds0 + sigma * s0) / wd).powi(2)).sqrt();
    let t_end: f64 = 1.0; // about two periods (2π/ω₀ = 0.51 s)

    for integrator in Integrator::ALL {
        let h: f64 = match order(integrator) {
            1 => 1e-4,
            _ => 1e-3,
        };
        let bound = 2.0
            * amplitude
            * match integrator {
                Integrator::ExplicitEuler | Integrator::ImplicitEuler => w0 * w0 * h * t_end / 2.0,
                Integrator::SymplecticEuler => w0 * h / 2.0,
                Integrator::Midpoint => w0.powi(3) * h * h * t_end / 6.0,
                Integrator::Rk4 => w0.powi(5) * h.powi(4) * t_end / 120.0,
            };
        let steps = (t_end / h).round() as u64;
        let bound = bound + 10.0 * steps as f64 * f64::EPSILON * amplitude;
        let mut sim = simulation(integrator, h);
        sim.gravity = DVec3::ZERO;
        let body = particles(
            vec![DVec3::ZERO, DVec3::new(rest + s0, 0.0, 0.0)],
            vec![va, vb],
            vec![m1, m2],
            vec![ExplicitSpring {
                rest: Some(rest),
                ..spring(0, 1, k, c)
            }],
        );
        let mut solver = solver(&scene(sim, vec![body], vec![]));
        let mut worst = 0.0f64;
        for n in 1..=steps {
            let st = step(&mut solver);
            let s = st.x[1].x - st.x[0].x - rest;
            worst = worst.max((s - exact(n as f64 * h)).abs());
            // The motion stays on the axis.
            assert!(st.x.iter().all(|x| x.y == 0.0 && x.z == 0.0));
        }
        println!("{integrator}: h = {h:e}, max |s − s_exact| = {worst:.3e} m, bound {bound:.3e} m");
        assert!(
            worst <= bound,
            "{integrator}: separation error {worst:e} m exceeds {bound:e} m"
        );
        // Not trivially loose either: within a factor 50 of the leading term, except RK4 at
        // round-off and symplectic Euler, whose sheared ellipse error can vanish at a sample.
        if matches!(
            integrator,
            Integrator::ExplicitEuler | Integrator::ImplicitEuler | Integrator::Midpoint
        ) {
            assert!(worst > bound / 50.0, "{integrator}: {worst:e} vs {bound:e}");
        }
    }
}

/// Free fall (one particle, no springs, no terrain) against each method's exact recurrence:
/// explicit Euler y_n = y₀ + nhv₀ + gh²n(n−1)/2; symplectic and implicit Euler
/// y_n = y₀ + nhv₀ + gh²n(n+1)/2; midpoint and RK4 y₀ + v₀t + gt²/2; v_n = v₀ + nhg for all.
/// Relative to the scale of the coordinates, to 1e-12 (round-off over 300 steps is ~1e-14).
#[test]
fn free_fall_follows_each_methods_exact_recurrence() {
    let (x0, v0, h) = (
        DVec3::new(0.5, 10.0, -2.0),
        DVec3::new(1.5, 3.0, -0.5),
        0.01,
    );
    let g = gravity();
    for integrator in Integrator::ALL {
        let mut solver = solver(&scene(
            simulation(integrator, h),
            vec![particle(x0, v0)],
            vec![],
        ));
        for n in 1..=300u64 {
            let st = step(&mut solver);
            let nf = n as f64;
            let t = nf * h;
            let quad = match integrator {
                Integrator::ExplicitEuler => h * h * nf * (nf - 1.0) / 2.0,
                Integrator::SymplecticEuler | Integrator::ImplicitEuler => {
                    h * h * nf * (nf + 1.0) / 2.0
                }
                Integrator::Midpoint | Integrator::Rk4 => t * t / 2.0,
            };
            let x = x0 + t * v0 + quad * g;
            let v = v0 + t * g;
            let x_scale = x0.length() + t * v0.length() + quad * G;
            let v_scale = v0.length() + t * G;
            let (ex, ev) = ((st.x[0] - x).length(), (st.v[0] - v).length());
            assert!(
                ex <= 1e-12 * x_scale && ev <= 1e-12 * v_scale,
                "{integrator} step {n}: x {} vs {x} (error {ex:e}), v {} vs {v} (error {ev:e})",
                st.x[0],
                st.v[0]
            );
        }
    }
}

/// Four particles, six damped, pre-stressed springs, gravity, no contact.
fn tetrahedron(integrator: Integrator, h: f64) -> softbody::Scene {
    let positions = vec![
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1.0, 0.1, 0.0),
        DVec3::new(0.2, 0.9, 0.1),
        DVec3::new(0.3, 0.3, 0.8),
    ];
    let velocities = vec![
        DVec3::new(0.3, -0.2, 0.1),
        DVec3::new(-0.4, 0.1, 0.2),
        DVec3::new(0.1, 0.5, -0.3),
        DVec3::new(0.0, -0.1, 0.4),
    ];
    let mut springs = Vec::new();
    let mut k = 30.0;
    for a in 0..4u32 {
        for b in a + 1..4 {
            let rest = 0.85 * positions[a as usize].distance(positions[b as usize]);
            springs.push(ExplicitSpring {
                rest: Some(rest),
                ..spring(a, b, k, 0.05 * k / 30.0)
            });
            k += 10.0;
        }
    }
    scene(
        simulation(integrator, h),
        vec![particles(
            positions,
            velocities,
            vec![1.0, 0.7, 1.3, 0.9],
            springs,
        )],
        vec![],
    )
}

fn run_to(integrator: Integrator, t_end: f64, steps: u64) -> State {
    let mut solver = solver(&tetrahedron(integrator, t_end / steps as f64));
    solver.advance(steps).unwrap();
    solver.state().unwrap().clone()
}

/// Global error at T = 0.5 s against RK4 at h = T/20000 (its own error there is ~1e-7 of RK4's
/// smallest error below), for four step sizes each halving the last; the observed order
/// log₂(e(h)/e(h/2)) of each halving must be within ±0.25 of the method's order. The step
/// sizes are in the asymptotic range (the first halving of RK4 from T/50 measured only 3.7) and
/// keep RK4's errors (≥ 1e-10) far above round-off.
#[test]
fn measured_orders_of_convergence() {
    let t_end = 0.5;
    let reference = run_to(Integrator::Rk4, t_end, 20000);
    let error = |s: &State| {
        let mut e = 0.0;
        for i in 0..s.x.len() {
            e += (s.x[i] - reference.x[i]).length_squared()
                + (t_end * (s.v[i] - reference.v[i])).length_squared();
        }
        e.sqrt()
    };
    for integrator in Integrator::ALL {
        let p = order(integrator) as f64;
        let base: u64 = match integrator {
            Integrator::Rk4 => 100,
            Integrator::Midpoint => 200,
            _ => 250,
        };
        let errors: Vec<f64> = (0..4)
            .map(|j| error(&run_to(integrator, t_end, base << j)))
            .collect();
        let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
        println!(
            "{integrator}: errors {}, observed orders {orders:.3?}",
            errors
                .iter()
                .map(|e| format!("{e:.3e}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        for (j, q) in orders.iter().enumerate() {
            assert!(
                (q - p).abs() <= 0.25,
                "{integrator}: observed order {q:.3} between h = T/{} and T/{} (expected {p})",
                base << j,
                base << (j + 1)
            );
        }
    }
}

/// A small cuboid, no gravity, no drag, no terrain, perturbed positions and velocities, damped
/// springs: Σ m v is constant, since every spring force acts on its two ends with opposite
/// signs.
///
/// Explicit methods: the spring terms cancel up to round-off of the per-particle gathers,
/// ~ε·h·Σ|f| per step; over 400 steps ≪ 1e-12 of the momentum scale Σ m|v|.
///
/// Implicit Euler: Σ m Δv = Σ (AΔv)_i exactly (the spring blocks of A have zero column sums and
/// there is no drag), and Σ b_i = 0 (b is h(spring forces + h K v), also equal and opposite), so
/// the momentum change of a step is −Σ r_i with r = b − AΔv the CG residual. CG stops at
/// rᵀP⁻¹r ≤ ρ²·bᵀP⁻¹b (P the block diagonal, ρ the reported relative residual ≤ 1e-8), so
/// |Σ r_i| ≤ √n‖r‖ ≤ √n·ρ·√(λmax(P)/λmin(P))·‖b‖. The test sums this bound over the steps
/// (re-assembling b and P at each state) and asserts the drift stays below it; and it checks
/// the accounting itself, ΔP = −Σ r_i with r recomputed from Δv = v' − v, to 1e-14 of Σ m|v|.
#[test]
fn internal_springs_conserve_linear_momentum() {
    for integrator in Integrator::ALL {
        let mut sim = simulation(integrator, 1e-3);
        sim.gravity = DVec3::ZERO;
        let params = softbody::scene::SpringParams {
            stiffness: 50.0,
            damping: 0.1,
        };
        let cube = cuboid(DVec3::splat(0.3), [3, 3, 3], DVec3::ZERO, 1.0, params);
        let scene = scene(sim, vec![cuboid_body(cube)], vec![]);
        let (mut model, mut state) = Model::build(&scene);
        model.simulation.dt = 0.25 * model.stable_dt().unwrap();
        let h = model.simulation.dt;
        let mut rng = Rng::new(7);
        for (x, v) in state.x.iter_mut().zip(&mut state.v) {
            *x += rng.vec(0.03);
            *v = DVec3::new(0.3, -0.2, 0.1) + rng.vec(0.5);
        }
        let p0 = momentum(&model, &state);
        let scale: f64 = model
            .mass
            .iter()
            .zip(&state.v)
            .map(|(m, v)| m * v.length())
            .sum();
        let n = model.len();
        let mut system = System::new(&model);
        let mut b = vec![DVec3::ZERO; n];
        let mut solver = solver_from(model.clone(), state, 1);
        let mut cg_bound = 0.0;
        let steps = 400;
        for _ in 0..steps {
            if integrator == Integrator::ImplicitEuler {
                let st = solver.state().unwrap();
                system.assemble(&model, &st.x, &st.v, &mut b);
                let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
                for i in 0..n {
                    let mut top = system.mass_diag[i];
                    for &e in model.adjacency.of(i) {
                        let s = (e >> 1) as usize;
                        top += system.beta[s] + system.gamma[s];
                    }
                    lo = lo.min(system.mass_diag[i]);
                    hi = hi.max(top);
                }
                let norm_b = b.iter().map(|b| b.length_squared()).sum::<f64>().sqrt();
                cg_bound += (n as f64).sqrt() * CG_TOLERANCE * (hi / lo).sqrt() * norm_b;
                // The exact accounting: this step's momentum change is −Σ r_i.
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
                assert!(
                    (dp + residual_sum).length() <= 1e-14 * scale,
                    "implicit step: ΔP = {dp} but −Σr = {}",
                    -residual_sum
                );
                continue;
            }
            solver.advance(1).unwrap();
        }
        let stats = solver.statistics();
        let drift = (momentum(&model, solver.state().unwrap()) - p0).length();
        println!(
            "{integrator}: h = {h:.3e}, |ΔP| = {drift:.3e} (scale {scale:.3e}), CG bound {cg_bound:.3e}, \
             max CG residual {:.1e}",
            stats.cg_max_residual
        );
        let bound = 1e-12 * scale
            + if integrator == Integrator::ImplicitEuler {
                assert!(stats.cg_max_residual <= CG_TOLERANCE, "{stats:?}");
                cg_bound
            } else {
                0.0
            };
        assert!(
            drift <= bound,
            "{integrator}: momentum drifted by {drift:e} (bound {bound:e})"
        );
        // The springs did work: the state is not trivially a rigid drift.
        let v = &solver.state().unwrap().v;
        let mean = p0 / model.mass.iter().sum::<f64>();
        assert!(v.iter().any(|v| (*v - mean).length() > 0.01));
    }
}
