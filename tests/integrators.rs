//! The integrators against closed forms, on every backend: a damped two-body spring, free fall
//! (the exact discrete recurrences of each method), measured orders of convergence, and
//! conservation of linear momentum by the internal spring forces.
//!
//! Each bound is the method's analytic error plus the rounding the backend gathers over the run
//! ([`Backend::roundoff`]): on the CPU (f64) that term is far below every bound, on the GPU (f32)
//! it is what the arithmetic resolves.

use std::process::ExitCode;

use glam::DVec3;
use softbody::cpu::integrators::implicit_euler::system::System;
use softbody::scene::ExplicitSpring;
use softbody::{Integrator, State};
use softbody_testkit::scenes::*;
use softbody_testkit::{Backend, Failed, Law, cg_momentum_bound, ensure};

fn main() -> ExitCode {
    softbody_testkit::run(
        "integrators",
        [
            Law::per_integrator(
                "two_body_spring_matches_the_damped_oscillator",
                two_body_spring_matches_the_damped_oscillator,
            ),
            Law::per_integrator(
                "free_fall_follows_each_methods_exact_recurrence",
                free_fall_follows_each_methods_exact_recurrence,
            ),
            Law::per_integrator(
                "measured_orders_of_convergence",
                measured_orders_of_convergence,
            ),
            Law::per_integrator(
                "internal_springs_conserve_linear_momentum",
                internal_springs_conserve_linear_momentum,
            ),
        ],
    )
}

/// Two particles on one damped spring, moving along the x axis, no gravity.
///
/// With masses m₁, m₂, the reduced mass μ = m₁m₂/(m₁ + m₂) and the stretch s = |x₂ − x₁| − r,
/// the separation obeys μ s'' = −k s − c s' exactly (the motion stays on the spring's axis, where
/// the spring force is linear in the separation, so even implicit Euler's linearisation is exact).
/// With σ = c/(2μ), ω₀² = k/μ and ω_d² = ω₀² − σ²:
/// s(t) = e^{−σt} (s₀ cos ω_d t + (s'₀ + σ s₀)/ω_d sin ω_d t).
///
/// Tolerances: the leading global error of each method on the oscillator ż = (σ-damped) iω₀z,
/// over the time T, with amplitude A (all twice the leading term), plus the backend's rounding
/// of positions of magnitude |x| ≈ 1.1 m over the N steps:
/// - explicit / implicit Euler: the amplification factor |1 ± hλ| is off by h²ω₀²/2 per step, so
///   the amplitude drifts by A·ω₀²hT/2 (grows / decays);
/// - symplectic Euler: no drift, but its invariant ellipse is sheared by O(ω₀h): error A·ω₀h/2;
/// - midpoint: phase error ω₀³h²T/6 per unit amplitude (amplitude drift is O(h⁴));
/// - RK4: phase and amplitude error ω₀⁵h⁴T/120 per unit amplitude.
fn two_body_spring_matches_the_damped_oscillator(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
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
    // The separation is a difference of positions near 1.1 m: it carries their rounding.
    let floor = 2.0 * backend.roundoff(1.0 + rest + s0, steps);
    let analytic = bound;
    let bound = analytic + floor;
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
    let mut solver = backend.solver(&scene(sim, vec![body], vec![]))?;
    let mut worst = 0.0f64;
    // A thousand samples of the run (a GPU state is a read-back).
    let every = (steps / 1000).max(1);
    for n in (every..=steps).step_by(every as usize) {
        solver.advance(every).map_err(|e| e.to_string())?;
        let st = solver.state().map_err(|e| e.to_string())?;
        let s = st.x[1].x - st.x[0].x - rest;
        worst = worst.max((s - exact(n as f64 * h)).abs());
        ensure(st.x.iter().all(|x| x.y == 0.0 && x.z == 0.0), || {
            format!("{integrator}: the motion left the x axis at step {n}")
        })?;
    }
    println!(
        "{integrator}: h = {h:e}, max |s − s_exact| = {worst:.3e} m, bound {bound:.3e} m \
         (rounding {floor:.1e} m)"
    );
    ensure(worst <= bound, || {
        format!("{integrator}: separation error {worst:e} m exceeds {bound:e} m")
    })?;
    // Not trivially loose either: within a factor 50 of the leading term, except RK4 at
    // round-off and symplectic Euler, whose sheared ellipse error can vanish at a sample;
    // where the backend's rounding is not well below the leading term, it says nothing.
    if matches!(
        integrator,
        Integrator::ExplicitEuler | Integrator::ImplicitEuler | Integrator::Midpoint
    ) && floor < analytic / 10.0
    {
        ensure(worst > analytic / 50.0, || {
            format!("{integrator}: {worst:e} vs {analytic:e}")
        })?;
    }
    Ok(())
}

/// Free fall (one particle, no springs, no terrain) against each method's exact recurrence:
/// explicit Euler y_n = y₀ + nhv₀ + gh²n(n−1)/2; symplectic and implicit Euler
/// y_n = y₀ + nhv₀ + gh²n(n+1)/2; midpoint and RK4 y₀ + v₀t + gt²/2; v_n = v₀ + nhg for all.
/// Relative to the scale of the coordinates, to 1e-12 plus the backend's rounding over the steps
/// (in f64 round-off over 300 steps is ~1e-14).
fn free_fall_follows_each_methods_exact_recurrence(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let (x0, v0, h) = (
        DVec3::new(0.5, 10.0, -2.0),
        DVec3::new(1.5, 3.0, -0.5),
        0.01,
    );
    let g = gravity();
    let mut solver = backend.solver(&scene(
        simulation(integrator, h),
        vec![particle(x0, v0)],
        vec![],
    ))?;
    for n in 1..=300u64 {
        let st = step(solver.as_mut())?;
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
        let bound = |scale: f64| 1e-12 * scale + backend.roundoff(scale, n);
        ensure(ex <= bound(x_scale) && ev <= bound(v_scale), || {
            format!(
                "{integrator} step {n}: x {} vs {x} (error {ex:e}), v {} vs {v} (error {ev:e})",
                st.x[0], st.v[0]
            )
        })?;
    }
    Ok(())
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

fn run_to(
    backend: &Backend,
    integrator: Integrator,
    t_end: f64,
    steps: u64,
) -> Result<State, Failed> {
    let mut solver = backend.solver(&tetrahedron(integrator, t_end / steps as f64))?;
    solver.advance(steps).map_err(|e| e.to_string())?;
    Ok(solver.state().map_err(|e| e.to_string())?.clone())
}

/// Global error at T = 0.5 s against RK4 on the CPU at h = T/20000 (its own error there is ~1e-7
/// of RK4's smallest error below), for four step sizes each halving the last; the observed order
/// log₂(e(h)/e(h/2)) of each halving must be within ±0.25 of the method's order. The step
/// sizes are in the asymptotic range (the first halving of RK4 from T/50 measured only 3.7).
///
/// The errors must also stand well above the backend's rounding, or the ratio measures the
/// rounding: on the CPU every ladder keeps RK4's errors ≥ 1e-10. In f32 the GPU resolves about
/// 1e-6 here, so its ladders start at larger steps (errors ≥ 20 times the rounding estimate,
/// checked). RK4's error falls below that before its asymptotic range begins (measured on
/// lavapipe: orders 3.3 from T/25 to T/100, errors down to 1.6e-6), so on the GPU RK4 is held
/// to the CPU's RK4 at the same steps instead: the same truncation error, to within 10 times the
/// rounding estimate.
fn measured_orders_of_convergence(backend: &Backend, integrator: Integrator) -> Result<(), Failed> {
    let t_end = 0.5;
    let reference = run_to(&Backend::cpu(), Integrator::Rk4, t_end, 20000)?;
    let error = |s: &State| {
        let mut e = 0.0;
        for i in 0..s.x.len() {
            e += (s.x[i] - reference.x[i]).length_squared()
                + (t_end * (s.v[i] - reference.v[i])).length_squared();
        }
        e.sqrt()
    };
    let scale = reference.x.iter().map(|x| x.length()).fold(0.0, f64::max);
    let p = order(integrator) as f64;
    if backend.is_gpu() && integrator == Integrator::Rk4 {
        for steps in [100, 200] {
            let cpu = run_to(&Backend::cpu(), integrator, t_end, steps)?;
            let gpu = run_to(backend, integrator, t_end, steps)?;
            let (dx, dv) = softbody_testkit::max_difference(&cpu, &gpu);
            let difference = dx.max(t_end * dv);
            let rounding = backend.roundoff(scale, steps);
            println!(
                "{integrator} at T/{steps}: error {:.3e}, GPU − CPU {difference:.3e} (rounding {rounding:.1e})",
                error(&gpu)
            );
            ensure(difference <= 10.0 * rounding, || {
                format!("{integrator} at T/{steps}: the GPU differs from the CPU by {difference:e}")
            })?;
        }
        return Ok(());
    }
    let (base, sizes): (u64, u32) = match (backend.is_gpu(), integrator) {
        (false, Integrator::Rk4) => (100, 4),
        (false, Integrator::Midpoint) => (200, 4),
        (false, _) => (250, 4),
        (true, Integrator::Midpoint) => (50, 4),
        (true, _) => (125, 4),
    };
    let mut errors = Vec::new();
    for j in 0..sizes {
        errors.push(error(&run_to(backend, integrator, t_end, base << j)?));
    }
    let orders: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    let rounding = backend.roundoff(scale, base << (sizes - 1));
    println!(
        "{integrator}: errors {} (rounding {rounding:.1e}), observed orders {orders:.3?}",
        errors
            .iter()
            .map(|e| format!("{e:.3e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let smallest = errors.iter().copied().fold(f64::INFINITY, f64::min);
    ensure(smallest >= 20.0 * rounding, || {
        format!(
            "{integrator}: the smallest error {smallest:e} is within 20× the rounding {rounding:e}"
        )
    })?;
    for (j, q) in orders.iter().enumerate() {
        ensure((q - p).abs() <= 0.25, || {
            format!(
                "{integrator}: observed order {q:.3} between h = T/{} and T/{} (expected {p})",
                base << j,
                base << (j + 1)
            )
        })?;
    }
    Ok(())
}

/// A small cuboid, no gravity, no drag, no terrain, perturbed positions and velocities, damped
/// springs: Σ m v is constant, since every spring force acts on its two ends with opposite
/// signs.
///
/// Explicit methods: the spring terms cancel up to round-off of the per-particle gathers,
/// ~ε·h·Σ|f| per step; over 400 steps ≪ 1e-12 of the momentum scale Σ m|v| in f64, and within
/// the backend's rounding of that scale in f32.
///
/// Implicit Euler: Σ m Δv = Σ (AΔv)_i exactly (the spring blocks of A have zero column sums and
/// there is no drag), and Σ b_i = 0 (b is h(spring forces + h K v), also equal and opposite), so
/// the momentum change of a step is −Σ r_i with r = b − AΔv the CG residual. CG stops at
/// rᵀP⁻¹r ≤ ρ²·bᵀP⁻¹b (P the block diagonal, ρ the backend's tolerance), so
/// |Σ r_i| ≤ √n‖r‖ ≤ √n·ρ·√(λmax(P)/λmin(P))·‖b‖. The test sums this bound over the steps
/// (assembling b and P with the CPU's `System` at each state the backend reached) and asserts
/// the drift stays below it. (The CPU's exact accounting, ΔP = −Σ r_i, is tested in
/// `crates/cpu/tests`.)
fn internal_springs_conserve_linear_momentum(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let (model, state) = tumbling_cube(integrator);
    let h = model.simulation.dt;
    let p0 = momentum(&model, &state);
    let scale = momentum_scale(&model, &state);
    let mut system = System::new(&model);
    let mut solver = backend.solver_from(model.clone(), state)?;
    let mut cg_bound = 0.0;
    let steps = 400;
    for _ in 0..steps {
        if integrator == Integrator::ImplicitEuler {
            let st = solver.state().map_err(|e| e.to_string())?;
            cg_bound += cg_momentum_bound(backend, &mut system, &model, &st.x, &st.v);
        }
        solver.advance(1).map_err(|e| e.to_string())?;
    }
    let stats = solver.statistics();
    let end = solver.state().map_err(|e| e.to_string())?;
    let drift = (momentum(&model, end) - p0).length();
    let bound = 1e-12 * scale
        + backend.roundoff(scale, steps)
        + if integrator == Integrator::ImplicitEuler {
            ensure(stats.cg_max_residual <= backend.cg_tolerance(), || {
                format!("{integrator}: {stats:?}")
            })?;
            cg_bound
        } else {
            0.0
        };
    println!(
        "{integrator}: h = {h:.3e}, |ΔP| = {drift:.3e} (scale {scale:.3e}, bound {bound:.3e}), \
         max CG residual {:.1e}",
        stats.cg_max_residual
    );
    ensure(drift <= bound, || {
        format!("{integrator}: momentum drifted by {drift:e} (bound {bound:e})")
    })?;
    // The springs did work: the state is not trivially a rigid drift.
    let mean = p0 / model.mass.iter().sum::<f64>();
    ensure(end.v.iter().any(|v| (*v - mean).length() > 0.01), || {
        format!("{integrator}: every particle moves with the mean velocity")
    })?;
    Ok(())
}
