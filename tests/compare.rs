//! The integrator study (`softbody::compare`) on scenes with known answers: free fall (closed-form
//! errors), an undamped two-body spring (orders of convergence, energy drift), a stiff spring at
//! a step too large (reported unstable), and pinned particles inside the terrain (penetration).

use glam::DVec3;
use softbody::compare::{Report, RunReport, Study, StudyError};
use softbody::scene::{Body, ExplicitSpring, Simulation, TerrainShape};
use softbody::{Integrator, Scene};
use softbody_testkit::scenes::*;

/// Two particles (1 kg and 2 kg) on an undamped spring along x, no gravity, no terrain:
/// μ = 2/3 kg, ω₀ = √(k/μ); the stretch starts at 0.1 m and grows at 0.3 m/s.
fn spring_scene(stiffness: f64, dt: f64, duration: f64) -> Scene {
    let mut sim: Simulation = simulation(Integrator::Rk4, dt);
    sim.gravity = DVec3::ZERO;
    sim.duration = duration;
    sim.frame_rate = 30.0;
    let body = particles(
        vec![DVec3::ZERO, DVec3::new(1.1, 0.0, 0.0)],
        vec![DVec3::new(-0.1, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0)],
        vec![1.0, 2.0],
        vec![ExplicitSpring {
            rest: Some(1.0),
            ..spring(0, 1, stiffness, 0.0)
        }],
    );
    scene(sim, vec![body], vec![])
}

fn study(scene: Scene, integrators: &[Integrator], dts: &[f64]) -> Study {
    Study {
        integrators: integrators.to_vec(),
        dts: dts.to_vec(),
        threads: Some(1),
        ..Study::new(scene)
    }
}

fn find(report: &Report, integrator: Integrator, dt: f64) -> &RunReport {
    report
        .runs
        .iter()
        .find(|r| r.integrator == integrator && r.dt == dt)
        .expect("a run per integrator and dt")
}

/// Halving dt divides each method's error by 2^order: the ratio of the errors at 2h and h on the
/// undamped spring (ω₀h = 0.012 and 0.024, one and a half periods), within 20 % (the leading
/// term dominates at these steps; the reference's error is 4096× below RK4's at h). The errors
/// also stay within twice the leading-term bounds of tests/integrators.rs.
#[test]
fn errors_decrease_at_each_method_order() {
    let (k, mu, h): (f64, f64, f64) = (100.0, 2.0 / 3.0, 1e-3);
    let w0 = (k / mu).sqrt();
    let t_end = 1.0;
    // The stretch's amplitude (s₀ = 0.1 m, ṡ₀ = 0.3 m/s); each particle moves a share of it.
    let amplitude = (0.1f64.powi(2) + (0.3 / w0).powi(2)).sqrt();
    let report = study(spring_scene(k, h, t_end), &Integrator::ALL, &[2.0 * h, h])
        .run(&mut |_, _| {})
        .expect("the study runs");
    assert_eq!(report.runs.len(), 10);
    for integrator in Integrator::ALL {
        let coarse = find(&report, integrator, 2.0 * h);
        let fine = find(&report, integrator, h);
        assert!(coarse.instability.is_none() && fine.instability.is_none());
        assert_eq!(fine.steps, 1000);
        let ratio = coarse.max_error / fine.max_error;
        let expected = 2f64.powi(order(integrator) as i32);
        let bound = 2.0
            * amplitude
            * match integrator {
                Integrator::ExplicitEuler | Integrator::ImplicitEuler => w0 * w0 * h * t_end / 2.0,
                Integrator::SymplecticEuler => w0 * h / 2.0,
                Integrator::Midpoint => w0.powi(3) * h * h * t_end / 6.0,
                Integrator::Rk4 => w0.powi(5) * h.powi(4) * t_end / 120.0,
            };
        println!(
            "{integrator}: errors {:.3e} m (2h), {:.3e} m (h), ratio {ratio:.3} (expected {expected}), bound at h {bound:.3e} m",
            coarse.max_error, fine.max_error
        );
        assert!(
            (ratio / expected - 1.0).abs() < 0.2,
            "{integrator}: ratio {ratio}, expected {expected} ± 20 %"
        );
        assert!(
            fine.max_error > 0.0 && fine.max_error < bound,
            "{integrator}"
        );
        assert_eq!(fine.samples.len(), 31);
        assert_eq!(fine.samples[0].error, 0.0);
        assert!(fine.deepest_penetration.is_none(), "no terrain");
    }
}

/// The reference: RK4 at the smallest dt / 16, checked against RK4 at / 8. Its estimate is the
/// RK4 error at 2·dt_ref, ~(1/8)⁴ of the RK4 error at dt: far below every run's error.
#[test]
fn reference_estimates_its_own_error() {
    let h = 1e-3;
    let report = study(spring_scene(100.0, h, 1.0), &[Integrator::Rk4], &[h])
        .run(&mut |_, _| {})
        .expect("the study runs");
    let r = &report.reference;
    assert_eq!(r.integrator, Integrator::Rk4);
    assert_eq!(r.dt, h / 16.0);
    assert_eq!(r.check_dt, h / 8.0);
    assert_eq!(r.steps, 16_000);
    let rk4 = report.runs[0].max_error;
    println!(
        "reference estimate {:.3e} m, rk4 at h {rk4:.3e} m",
        r.error_estimate
    );
    assert!(r.error_estimate > 0.0 && r.error_estimate < 1e-12);
    assert!(r.error_estimate < rk4 / 500.0);
    // No gravity: the energy scale is the initial energy, ½ μ ṡ₀² + ½ k s₀² (the centre of mass
    // moves at 0.1 m/s: ½ · 3 kg · 0.01).
    let e0 = 0.5 * (2.0 / 3.0) * 0.09 + 0.5 * 100.0 * 0.01 + 0.5 * 3.0 * 0.01;
    assert!((report.energy_scale - e0).abs() < 1e-12 * e0);
}

/// Free fall from rest: x_exact = x₀ − g t²/2. Explicit, symplectic and implicit Euler all fall
/// by g h² n(n ∓ 1)/2 after n steps, an error of g·h·t/2 at time t: the largest at the last frame
/// (t = 1 s). Midpoint and RK4 are exact (round-off only), and so is the reference.
#[test]
fn free_fall_errors_match_the_closed_form() {
    let h = 0.01;
    let sim = simulation(Integrator::Rk4, h);
    let scene = scene(
        sim,
        vec![particle(DVec3::new(0.0, 10.0, 0.0), DVec3::ZERO)],
        vec![],
    );
    let report = study(scene, &Integrator::ALL, &[h])
        .run(&mut |_, _| {})
        .expect("the study runs");
    let expected = G * h * 1.0 / 2.0;
    for r in &report.runs {
        println!(
            "{}: max error {:.6e} m at {} s",
            r.integrator, r.max_error, r.max_error_time
        );
        match r.integrator {
            Integrator::Midpoint | Integrator::Rk4 => assert!(r.max_error < 1e-12),
            _ => {
                assert!((r.max_error - expected).abs() < 1e-9 * expected);
                assert_eq!(r.max_error_time, 1.0);
            }
        }
        // Falling at g·t: not at rest.
        assert_eq!(r.at_rest, Some(false));
        assert!((r.final_max_speed - G).abs() < 1e-9);
    }
    assert!(report.reference.error_estimate < 1e-12);
}

/// Frame times that are not whole reference steps: with dts {3e-3, 2.5e-3} s the reference steps
/// 2.5e-3/16 = 1.5625e-4 s, and the 3e-3 run's frames (t = 3e-3·n) fall at 19.2·n reference
/// steps, so the reference is interpolated there (cubic Hermite). Free fall is quadratic in t, so
/// the interpolation is exact: midpoint and RK4 keep errors at round-off, and explicit Euler's is
/// its closed form g·h·t/2 at the last frame (step 333, t = 0.999 s).
#[test]
fn interpolated_reference_is_exact_for_free_fall() {
    let h = 3e-3;
    let sim = simulation(Integrator::Rk4, h);
    let scene = scene(
        sim,
        vec![particle(DVec3::new(0.0, 10.0, 0.0), DVec3::ZERO)],
        vec![],
    );
    let integrators = [
        Integrator::ExplicitEuler,
        Integrator::Midpoint,
        Integrator::Rk4,
    ];
    let report = study(scene, &integrators, &[h, 2.5e-3])
        .run(&mut |_, _| {})
        .expect("the study runs");
    assert_eq!(report.reference.dt, 2.5e-3 / 16.0);
    for r in report.runs.iter().filter(|r| r.dt == h) {
        println!(
            "{}: max error {:.6e} m at {} s",
            r.integrator, r.max_error, r.max_error_time
        );
        if r.integrator == Integrator::ExplicitEuler {
            let expected = G * h * (333.0 * h) / 2.0;
            assert!((r.max_error - expected).abs() < 1e-9 * expected);
        } else {
            assert!(r.max_error < 1e-12, "{}: {}", r.integrator, r.max_error);
        }
    }
    assert!(report.reference.error_estimate < 1e-12);
}

/// A stiff spring (k = 10⁶ N/m, ω₀ = 1414 rad/s) at h = 0.01 s (ω₀h = 14): explicit Euler's
/// amplification |1 + iω₀h| = 14 diverges at once; implicit Euler is stable at any step. The
/// study still completes and reports where explicit Euler stopped.
#[test]
fn too_large_a_step_is_reported_unstable() {
    let h = 0.01;
    let report = study(
        spring_scene(1e6, h, 1.0),
        &[Integrator::ExplicitEuler, Integrator::ImplicitEuler],
        &[h],
    )
    .run(&mut |_, _| {})
    .expect("an unstable run is a result, not an error");
    let explicit = &report.runs[0];
    let i = explicit
        .instability
        .as_ref()
        .expect("explicit Euler diverges");
    println!("explicit Euler: {i}");
    assert!(i.step >= 1 && i.step < 100);
    assert_eq!(i.time, i.step as f64 * h);
    assert_eq!(explicit.steps, i.step);
    assert_eq!(explicit.at_rest, None);
    assert!(explicit.samples.len() < 31);
    let implicit = &report.runs[1];
    assert!(implicit.instability.is_none());
    assert_eq!(implicit.steps, 100);
}

/// A reference that diverges is the study's failure: there is nothing to measure against.
#[test]
fn an_unstable_reference_is_an_error() {
    let mut s = study(spring_scene(1e6, 1e-3, 1.0), &[Integrator::Rk4], &[0.5]);
    s.refinement = 2; // dt_ref = 0.25 s, ω₀·dt_ref = 354
    s.scene.simulation.frame_rate = 1.0;
    match s.run(&mut |_, _| {}) {
        Err(StudyError::ReferenceUnstable { dt, .. }) => assert_eq!(dt, 0.25),
        other => panic!("expected ReferenceUnstable, got {other:?}"),
    }
}

/// Energy on the undamped spring over 3 s (six periods) at h = 1e-3: explicit Euler multiplies
/// the energy by 1 + (ω₀h)² every step, so its drift grows monotonically to
/// 0.97·(e^{(ω₀h)²·3000} − 1) ≈ 0.55; symplectic Euler's energy oscillates within O(ω₀h) = 0.012 of E₀ and
/// does not grow: its worst drift over the last second is no more than over the first.
#[test]
fn symplectic_energy_stays_bounded_while_explicit_grows() {
    let (k, h) = (100.0, 1e-3);
    let w0h = (k / (2.0 / 3.0f64)).sqrt() * h;
    let report = study(
        spring_scene(k, h, 3.0),
        &[Integrator::ExplicitEuler, Integrator::SymplecticEuler],
        &[h],
    )
    .run(&mut |_, _| {})
    .expect("the study runs");
    let explicit = &report.runs[0];
    // Only the oscillation's energy grows: E₀ = 0.03 J (½μṡ₀²) + 0.5 J (½ks₀²) + 0.015 J (the
    // centre of mass, ½·3 kg·(0.1 m/s)², which the internal force leaves alone).
    let share = 0.53 / 0.545;
    let grown = share * ((w0h * w0h * 3000.0).exp() - 1.0);
    println!(
        "explicit Euler drift {:.4}, predicted {grown:.4}",
        explicit.energy_drift
    );
    assert!((explicit.energy_drift / grown - 1.0).abs() < 0.01);
    assert!(explicit.samples.windows(2).all(|w| w[1].drift > w[0].drift));

    let symplectic = &report.runs[1];
    let worst = |from: f64, to: f64| {
        symplectic
            .samples
            .iter()
            .filter(|s| s.time >= from && s.time <= to)
            .map(|s| s.drift.abs())
            .fold(0.0, f64::max)
    };
    println!(
        "symplectic Euler drift {:.4e} (first second {:.4e}, last {:.4e}), bound ω₀h = {w0h:.4e}",
        symplectic.energy_drift,
        worst(0.0, 1.0),
        worst(2.0, 3.0)
    );
    assert!(symplectic.energy_drift < w0h);
    assert!(worst(2.0, 3.0) <= 1.1 * worst(0.0, 1.0));
}

/// Two pinned particles held inside the terrain, which never moves them: one 5 cm below the
/// ground plane y = 0, one 0.3 m from the centre of a ball of radius 0.5 m (φ = −0.2 m, while
/// the plane's φ there is +0.3 m). A free particle falls 5 cm onto the plane and stops there
/// (restitution 0). Deepest penetration: −0.2 m, whatever the integrator; the free particle ends
/// at rest.
#[test]
fn deepest_penetration_is_the_hand_computed_depth() {
    let mut sim = simulation(Integrator::Rk4, 1e-3);
    sim.duration = 0.5;
    let body = Body {
        pinned: vec![0, 1],
        contact_radius: None,
        self_contact: false,
        ..particles(
            vec![
                DVec3::new(0.0, -0.05, 0.0),
                DVec3::new(2.0, 0.3, 0.0),
                DVec3::new(-1.0, 0.05, 0.0),
            ],
            vec![DVec3::ZERO; 3],
            vec![1.0; 3],
            Vec::new(),
        )
    };
    let mut ball = plane(DVec3::ZERO, DVec3::Y, 0.0, 0.5);
    ball.shape = TerrainShape::Sphere {
        center: DVec3::new(2.0, 0.0, 0.0),
        radius: 0.5,
    };
    let scene = scene(
        sim,
        vec![body],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.0, 0.5), ball],
    );
    let report = study(scene, &Integrator::ALL, &[1e-3])
        .run(&mut |_, _| {})
        .expect("the study runs");
    for r in &report.runs {
        println!(
            "{}: deepest {:?}, end speed {:.3e} m/s",
            r.integrator, r.deepest_penetration, r.final_max_speed
        );
        let deepest = r.deepest_penetration.expect("terrain");
        assert!((deepest + 0.2).abs() < 1e-12, "{}: {deepest}", r.integrator);
        assert_eq!(r.at_rest, Some(true), "{}", r.integrator);
    }
}

/// Bad parameters are refused before anything runs.
#[test]
fn bad_parameters_are_refused() {
    let scene = spring_scene(100.0, 1e-3, 1.0);
    for (integrators, dts) in [
        (vec![], vec![1e-3]),
        (vec![Integrator::Rk4], vec![0.0]),
        (vec![Integrator::Rk4], vec![-1e-3]),
        (vec![Integrator::Rk4], vec![f64::NAN]),
        // One frame per step at most: 30 frames/s needs dt ≤ 1/30 s.
        (vec![Integrator::Rk4], vec![0.1]),
    ] {
        let s = study(scene.clone(), &integrators, &dts);
        assert!(
            matches!(s.run(&mut |_, _| {}), Err(StudyError::Invalid(_))),
            "{integrators:?} {dts:?}"
        );
    }
}
