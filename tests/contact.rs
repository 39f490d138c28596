//! Contact laws on a plane, for every integrator on every backend: restitution of a bounce, the
//! stopping distance of Coulomb friction, static friction on a shallow slope and kinetic friction
//! on a steep one, and a bouncy cube coming to rest (heavy on the GPU: 30,000 steps of lavapipe
//! per method).
//!
//! Each law runs as one trial per integrator and collects every failure of its cases before
//! reporting, so one run shows the numbers of all of them. Where the CPU holds a quantity to
//! 1e-9 or 1e-12, the bound adds the backend's rounding of it over the run
//! ([`Backend::roundoff`]): far below those on the CPU, what f32 resolves on the GPU.

use std::process::ExitCode;

use glam::DVec3;
use softbody::Integrator;
use softbody::scene::SpringParams;
use softbody_testkit::scenes::*;
use softbody_testkit::{Backend, Failed, Kind, Law, all};

fn main() -> ExitCode {
    softbody_testkit::run(
        "contact",
        [
            Law::per_integrator(
                "bounce_follows_the_restitution_law",
                bounce_follows_the_restitution_law,
            ),
            Law::per_integrator(
                "coulomb_friction_stops_a_slide_at_the_predicted_distance",
                coulomb_friction_stops_a_slide_at_the_predicted_distance,
            ),
            Law::per_integrator(
                "static_friction_holds_on_a_shallow_slope_and_kinetic_friction_on_a_steep_one",
                static_friction_holds_on_a_shallow_slope_and_kinetic_friction_on_a_steep_one,
            ),
            Law::per_integrator("a_bouncy_cube_comes_to_rest", a_bouncy_cube_comes_to_rest)
                .heavy_on(Kind::Gpu),
        ],
    )
}

/// A 1 kg particle dropped from rest at H = 1 m (and 0.73 m) onto the plane y = 0 with
/// restitution k_r = 0.5 (no friction), h = 1 ms, ε = 1 mm.
///
/// The impact speed is v_i = √(2gH). A method meets the plane at the end of a step at some height
/// y ∈ [−v_i h, ε) (implicit Euler: at the start of a step at y ∈ [0, v_i h + ε)), and first-order
/// methods carry a position bias of g·h·t/2 by then, so the speed it reflects is the speed of a
/// fall from H + δ with |δ| ≤ v_i h + ε + g h t_i: relative error ≤ δ/(2H) (4.9e-3 at H = 1 m). Hence
/// - rebound speed v_r: |v_r − k_r v_i| ≤ k_r v_i δ/(2H);
/// - apex after the bounce: |apex − v_r²/(2g)| ≤ ε + 2 v_r h: the rise starts below ε, its own
///   discretisation error is v_r h/2 (left or right sums), and a step that starts within ε of
///   the plane still gets the contact force −(N·f)N (the contract has no condition on the
///   velocity), which cancels gravity for the lift-off step and adds up to g·h of speed, v_r h of
///   height (measured: explicit Euler +3.4e-3 m = v_r h/2 + v_r h + y_b); and
///   |apex − k_r² H| ≤ k_r² H · 2δ/(2H) + ε + 2 v_r h.
///
/// Also: the particle never ends a step below the plane.
fn bounce_follows_the_restitution_law(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let (kr, h, eps) = (0.5, 1e-3, 1e-3);
    let mut failures = Vec::new();
    // Two heights, so that the impact falls at two different phases of a step.
    for height in [1.0f64, 0.73] {
        let vi = (2.0 * G * height).sqrt();
        let ti = vi / G;
        let delta = vi * h + eps + G * h * ti;
        let rel = delta / (2.0 * height);
        let sim = simulation(integrator, h);
        let ground = plane(DVec3::ZERO, DVec3::Y, kr, 0.0);
        let mut solver = backend.solver(&scene(
            sim,
            vec![particle(DVec3::new(0.0, height, 0.0), DVec3::ZERO)],
            vec![ground],
        ))?;
        let mut lowest = f64::INFINITY;
        // Fall until the velocity turns upward (the impact is near step 452 from 1 m).
        let mut n = 0;
        let bounce = loop {
            let st = step(solver.as_mut())?;
            n += 1;
            lowest = lowest.min(st.x[0].y);
            if st.v[0].y > 0.0 {
                break Some((st.x[0].y, st.v[0].y));
            }
            if n == 1000 {
                break None;
            }
        };
        let Some((y_bounce, vr)) = bounce else {
            let st = solver.state().map_err(|e| e.to_string())?;
            failures.push(format!(
                "{integrator}, H = {height} m: no rebound at all within {n} steps (expected {} m/s up): at rest at \
                 y = {:e} m, v = {:e} m/s",
                kr * vi,
                st.x[0].y,
                st.v[0].y
            ));
            continue;
        };
        // Rise to the apex.
        let mut apex = y_bounce;
        loop {
            let st = step(solver.as_mut())?;
            lowest = lowest.min(st.x[0].y);
            apex = apex.max(st.x[0].y);
            if st.v[0].y <= 0.0 {
                break;
            }
        }
        println!(
            "{integrator}, H = {height} m: bounce at step {n}, y = {y_bounce:.3e}, rebound {vr:.5} m/s = {:.5} × impact \
             speed (k_r = {kr}), apex {apex:.5} m (k_r²H = {:.5}, v_r²/2g = {:.5}), lowest y {lowest:.2e}",
            vr / vi,
            kr * kr * height,
            vr * vr / (2.0 * G)
        );
        if (vr - kr * vi).abs() > kr * vi * rel {
            failures.push(format!(
                "{integrator}, H = {height} m: rebound speed {vr} m/s, expected k_r·v_i = {} ± {}",
                kr * vi,
                kr * vi * rel
            ));
        }
        // Implicit Euler resolves an impact at the start of the step that would reach the
        // plane (φ + h v_n < ε) and rebounds from there: up to h·v_i above it.
        let early = if integrator == Integrator::ImplicitEuler {
            vi * h
        } else {
            0.0
        };
        let apex_tol = eps + 2.0 * vr.abs() * h + early;
        if (apex - vr * vr / (2.0 * G)).abs() > apex_tol {
            failures.push(format!(
                "{integrator}, H = {height} m: apex {apex} m, expected v_r²/2g = {} ± {apex_tol}",
                vr * vr / (2.0 * G)
            ));
        }
        let apex_tol = kr * kr * height * 2.0 * rel + apex_tol;
        if (apex - kr * kr * height).abs() > apex_tol {
            failures.push(format!(
                "{integrator}, H = {height} m: apex {apex} m, expected k_r²H = {} ± {apex_tol}",
                kr * kr * height
            ));
        }
        if lowest < -1e-12 - backend.roundoff(height, n) {
            failures.push(format!(
                "{integrator}, H = {height} m: ended a step at y = {lowest} m"
            ));
        }
    }
    all(failures)
}

/// A 1 kg particle on the plane y = 0 sliding at v₀ = 2 m/s (along (0.6, 0, 0.8)) with Coulomb
/// friction μ = 0.5 decelerates at μg and stops after v₀²/(2μg) = 0.4077 m, along its initial
/// direction, and stays stopped.
///
/// Tolerances: while it slides the deceleration is the constant μg, which every method
/// integrates exactly in velocity, so the speed at t = 0.2 s is v₀ − μgt to 1e-9. The distance is
/// a quadrature of that linear ramp: explicit Euler's left sums overshoot by v₀h/2, symplectic
/// and implicit Euler's right sums undershoot by v₀h/2, midpoint and RK4 are exact but for the
/// final step (at most μgh² ≪ v₀h); so |distance − v₀²/(2μg)| ≤ v₀h. The particle stays on the
/// plane (|y| ≤ 1e-12) and does not drift sideways (≤ 1e-12 m), each plus the backend's
/// rounding.
fn coulomb_friction_stops_a_slide_at_the_predicted_distance(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let (mu, v0, h) = (0.5, 2.0, 1e-3);
    let dir = DVec3::new(0.6, 0.0, 0.8);
    let stop = v0 * v0 / (2.0 * mu * G);
    let mut failures = Vec::new();
    let sim = simulation(integrator, h);
    let ground = plane(DVec3::ZERO, DVec3::Y, 0.0, mu);
    let mut solver = backend.solver(&scene(
        sim,
        vec![particle(DVec3::ZERO, v0 * dir)],
        vec![ground],
    ))?;
    let mut worst_y = 0.0f64;
    for n in 1..=800u64 {
        let st = step(solver.as_mut())?;
        worst_y = worst_y.max(st.x[0].y.abs());
        if n == 200 {
            let expected = v0 - mu * G * 0.2;
            let speed = st.v[0].length();
            if (speed - expected).abs() > 1e-9 + backend.roundoff(v0, n) {
                failures.push(format!(
                    "{integrator}: speed {speed} m/s at t = 0.2 s, expected v₀ − μgt = {expected}"
                ));
            }
        }
    }
    let st = solver.state().map_err(|e| e.to_string())?;
    let (x, v) = (st.x[0], st.v[0]);
    let along = x.dot(dir);
    let sideways = (x - along * dir).length();
    println!(
        "{integrator}: stopped after {along:.6} m (v₀²/2μg = {stop:.6}, error {:.2e}, tolerance {:.1e}), \
         |v| = {:.1e}, sideways {sideways:.1e} m, max |y| {worst_y:.1e}",
        along - stop,
        v0 * h,
        v.length()
    );
    if (along - stop).abs() > v0 * h {
        failures.push(format!(
            "{integrator}: stopping distance {along} m, expected {stop} ± {}",
            v0 * h
        ));
    }
    if v.length() > 1e-9 + backend.roundoff(v0, 800) {
        failures.push(format!("{integrator}: still moving at {v} m/s after 0.8 s"));
    }
    let still = 1e-12 + backend.roundoff(stop, 800);
    if sideways > still || worst_y > still {
        failures.push(format!(
            "{integrator}: left its line (sideways {sideways} m, |y| up to {worst_y} m)"
        ));
    }
    all(failures)
}

/// A particle at rest on a plane tilted by θ (normal (sin θ, cos θ, 0), downhill (cos θ, −sin θ,
/// 0)) with μ = 0.5 (atan μ = 26.6°), h = 1 ms, for 1 s:
/// - θ = 20°: static friction holds it; it moves less than 1e-9 m (plus the backend's rounding
///   of a 1 m coordinate over the run).
/// - θ = 35°: it slides downhill at a = g(sin θ − μ cos θ) = 1.609 m/s², so after t = 1 s it has
///   gone a t²/2 = 0.8045 m. The acceleration is constant, so as for the slide above the
///   first-order methods are off by a·h·t/2 (left or right sums) and midpoint/RK4 are exact;
///   tolerance a·h·t. It stays on the plane (|φ| ≤ 1e-9 m) and does not veer (≤ 1e-9 m).
fn static_friction_holds_on_a_shallow_slope_and_kinetic_friction_on_a_steep_one(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let (mu, h, t) = (0.5, 1e-3, 1.0);
    let steps = (t / h) as u64;
    let mut failures = Vec::new();
    for degrees in [20.0f64, 35.0] {
        let th = degrees.to_radians();
        let normal = DVec3::new(th.sin(), th.cos(), 0.0);
        let downhill = DVec3::new(th.cos(), -th.sin(), 0.0);
        let sim = simulation(integrator, h);
        let slope = plane(DVec3::ZERO, normal, 0.0, mu);
        let mut solver = backend.solver(&scene(
            sim,
            vec![particle(DVec3::ZERO, DVec3::ZERO)],
            vec![slope],
        ))?;
        let mut worst_phi = 0.0f64;
        for _ in 0..steps {
            let st = step(solver.as_mut())?;
            worst_phi = worst_phi.max(st.x[0].dot(normal).abs());
        }
        let x = solver.state().map_err(|e| e.to_string())?.x[0];
        let still = 1e-9 + backend.roundoff(1.0, steps);
        let along = x.dot(downhill);
        let veer = x.z.abs();
        if degrees < mu.atan().to_degrees() {
            println!(
                "{integrator}, {degrees}°: moved {:.2e} m, max |φ| {worst_phi:.1e}",
                x.length()
            );
            if x.length() > still {
                failures.push(format!(
                    "{integrator}: slid {} m on a {degrees}° slope with μ = {mu}",
                    x.length()
                ));
            }
        } else {
            let a = G * (th.sin() - mu * th.cos());
            let expected = 0.5 * a * t * t;
            let tol = a * h * t;
            println!(
                "{integrator}, {degrees}°: slid {along:.6} m (at²/2 = {expected:.6}, error {:.2e}, \
                 tolerance {tol:.1e}), max |φ| {worst_phi:.1e}",
                along - expected
            );
            if (along - expected).abs() > tol {
                failures.push(format!(
                    "{integrator}: slid {along} m down a {degrees}° slope in {t} s, expected {expected} ± {tol}"
                ));
            }
            if veer > still {
                failures.push(format!("{integrator}: veered {veer} m across the slope"));
            }
        }
        if worst_phi > still {
            failures.push(format!(
                "{integrator}, {degrees}°: left the plane by up to {worst_phi} m"
            ));
        }
    }
    all(failures)
}

/// A 1 kg jelly cube (20 cm, 5³ particles, k_s = 2000 N/m, k_d = 5 N·s/m) dropped from 10 cm
/// onto a plane with restitution 0.5 and friction 0.5 comes to rest: its kinetic energy falls
/// below 1e-9 J by t = 2 s and stays there at every 10 ms up to t = 3 s, for every integrator
/// (h = 1e-4 s; implicit Euler 1e-3 s).
///
/// Restitution acts on fresh impacts only (docs/physics.md, "Collision response"). Were it
/// applied on every entry into the band, the bottom layer would keep bouncing at the band's
/// edge with a kinetic energy floor near 1e-6 J (measured before the rule: 6e-6 J with explicit
/// Euler).
///
/// The bound adds what the backend's precision leaves: a velocity v below ulp(x)/(2h) moves
/// nothing (x + h·v rounds back to x), so the forces' rounding imbalance can hold such a
/// velocity on a body standing still, ½·M·(ε·|x|max/(2h))². Measured: 1e-27 J on the CPU; on
/// the GPU (f32, |x|max = 0.2 m: bound 8.2e-9 J at h = 1e-4 s) 2e-10 to 1.2e-9 J, the top
/// particles holding 7e-5 m/s upward while their positions stay put to the bit.
fn a_bouncy_cube_comes_to_rest(backend: &Backend, integrator: Integrator) -> Result<(), Failed> {
    const MASS: f64 = 1.0;
    let mut failures = Vec::new();
    let h = if integrator == Integrator::ImplicitEuler {
        1e-3
    } else {
        1e-4
    };
    let params = SpringParams {
        stiffness: 2000.0,
        damping: 5.0,
    };
    let cube = cuboid(
        DVec3::splat(0.2),
        [5, 5, 5],
        DVec3::new(0.0, 0.2, 0.0),
        MASS,
        params,
    );
    let mut sim = simulation(integrator, h);
    sim.duration = 3.0;
    let floor = plane(DVec3::ZERO, DVec3::Y, 0.5, 0.5);
    let mut solver = backend.solver(&scene(sim, vec![cuboid_body(cube)], vec![floor]))?;
    let per_frame = (0.01 / h).round() as u64;
    let mut worst_after_2s = 0.0f64;
    let mut at_2s = f64::NAN;
    for frame in 1..=300u64 {
        solver.advance(per_frame)?;
        if frame >= 200 {
            let kinetic = solver.energies()?.kinetic;
            if frame == 200 {
                at_2s = kinetic;
            }
            worst_after_2s = worst_after_2s.max(kinetic);
        }
    }
    let x_max = solver
        .state()?
        .x
        .iter()
        .map(|x| x.abs().max_element())
        .fold(0.0, f64::max);
    let still = backend.epsilon() * x_max / (2.0 * h);
    let rest = 1e-9 * MASS + 0.5 * MASS * still * still;
    println!(
        "{integrator}: kinetic energy {at_2s:.2e} J at 2 s, at most {worst_after_2s:.2e} J from 2 s to 3 s (bound {rest:.2e} J)"
    );
    if worst_after_2s >= rest || worst_after_2s.is_nan() {
        failures.push(format!(
            "{integrator}: kinetic energy up to {worst_after_2s:.3e} J between 2 s and 3 s (rest: < {rest:e} J)"
        ));
    }
    all(failures)
}
