//! What every case shares: the probe loss, the forward run, the cases' build and the check of
//! each group of values against central differences (the module doc of `main.rs` derives its
//! steps and bound).

use std::path::Path;

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::adjoint::run::{Backward, FrameBar, Loss, Options, gradient};
use softbody_scene::{Controls, Integrator, Model, Scene, Solver, State};

/// L = Σ_frames Σ_i (c_i·x_i + ½ w |v_i|²): linear in the positions with fixed pseudo-random
/// weights, quadratic in the velocities.
pub struct Probe {
    pub weights: Vec<DVec3>,
    pub w: f64,
    /// The states the loss saw, by frame.
    pub seen: Vec<(u64, State)>,
}

impl Probe {
    pub fn new(n: usize) -> Probe {
        Probe {
            weights: (0..n).map(|i| direction(i, 7.0)).collect(),
            w: 0.3,
            seen: Vec::new(),
        }
    }

    pub fn term(&self, state: &State) -> f64 {
        let mut l = 0.0;
        for (i, (x, v)) in state.x.iter().zip(&state.v).enumerate() {
            l += self.weights[i].dot(*x) + 0.5 * self.w * v.length_squared();
        }
        l
    }
}

impl Loss for Probe {
    fn frame(&mut self, frame: u64, state: &State, bar: FrameBar<'_>) -> f64 {
        for i in 0..bar.x.len() {
            bar.x[i] += self.weights[i];
            bar.v[i] += self.w * state.v[i];
        }
        self.seen.push((frame, state.clone()));
        self.term(state)
    }
}

/// The gradient's options on `n` threads.
pub fn threads(n: usize) -> Options<'static> {
    Options {
        threads: Some(n),
        ..Options::default()
    }
}

/// A fixed pseudo-random unit-ish vector for index i.
pub fn direction(i: usize, salt: f64) -> DVec3 {
    let t = i as f64 + salt;
    DVec3::new(
        (1.3 * t).sin(),
        (0.7 * t + 1.0).cos(),
        (2.1 * t + 0.5).sin(),
    )
}

/// The forward loss: the solver's run, the probe's terms at every frame.
pub fn forward_loss(model: &Model, start: &State) -> f64 {
    forward_loss_with(model, start, None)
}

/// The forward loss of the run with external forces `controls` (F × N, frame f's held from
/// its step to the next frame's).
pub fn forward_loss_with(model: &Model, start: &State, controls: Option<&[DVec3]>) -> f64 {
    let sim = &model.simulation;
    let n = model.len();
    let probe = Probe::new(n);
    let mut solver = CpuSolver::new(model.clone(), start.clone(), Some(1)).unwrap();
    let controls = controls.map(|u| Controls::new(model, u).unwrap());
    solver.set_controls(controls).unwrap();
    let mut at = 0;
    let mut total = 0.0;
    for f in 0..sim.frame_count() {
        let step = sim.frame_step(f);
        solver.advance(step - at).unwrap();
        at = step;
        total += probe.term(solver.state().unwrap());
    }
    total
}

pub struct Case {
    pub name: &'static str,
    pub toml: String,
    /// Every particle's initial velocity gains this spin about the centre (rad/s).
    pub spin: f64,
    /// Every particle's initial position moves by up to this (m).
    pub strain: f64,
    /// The initial positions are the body's scaled by this about its centre.
    pub stretch: f64,
    /// The direction the initial positions are moved along, by particle and position: at a
    /// resting contact (v·N rounding to zero at every step, the contact force cancelling the
    /// push) the response sits on its kink, and a pseudo-random move of the particles has
    /// one-sided derivatives there that central differences average; the cases in contact
    /// move the body along a symmetry of its terrain instead, which keeps every branch.
    pub x0: fn(usize, DVec3) -> DVec3,
}

pub fn build(case: &Case) -> (Model, State) {
    let scene = Scene::from_toml(&case.toml, Path::new("adjoint.toml")).unwrap();
    let (model, mut state) = Model::build(&scene);
    let c = state.x.iter().sum::<DVec3>() / state.x.len() as f64;
    // Strained (by up to 7 % of the lattice's spacing) and spinning: the springs work.
    for (i, (x, v)) in state.x.iter_mut().zip(&mut state.v).enumerate() {
        *v += case.spin * DVec3::Y.cross(*x - c);
        *x = c + case.stretch * (*x - c) + case.strain * direction(i, 3.0);
    }
    (model, state)
}

/// The directional derivative of the forward loss along a change of the model and state,
/// `apply(model, state, s)` moving them by s·d, by central differences.
pub fn central(
    model: &Model,
    state: &State,
    scale: f64,
    apply: &dyn Fn(&mut Model, &mut State, f64),
) -> f64 {
    let delta = 1e-6 * scale;
    let at = |s: f64| {
        let (mut m, mut x) = (model.clone(), state.clone());
        apply(&mut m, &mut x, s);
        forward_loss(&m, &x)
    };
    (at(delta) - at(-delta)) / (2.0 * delta)
}

pub fn check(what: &str, adjoint: f64, fd: f64, failures: &mut Vec<String>) {
    let scale = adjoint.abs().max(fd.abs()).max(1e-12);
    let rel = (adjoint - fd).abs() / scale;
    if rel > 1e-6 {
        failures.push(format!(
            "{what}: adjoint {adjoint:e}, differences {fd:e} (relative {rel:.1e})"
        ));
    }
}

pub fn dot(a: &[DVec3], i: &dyn Fn(usize) -> DVec3) -> f64 {
    a.iter().enumerate().map(|(k, a)| a.dot(i(k))).sum()
}

pub fn dot1(a: &[f64], i: &dyn Fn(usize) -> f64) -> f64 {
    a.iter().enumerate().map(|(k, a)| a * i(k)).sum()
}

pub fn check_case(integrator: Integrator, case: &Case, failures: &mut Vec<String>) {
    let (model, state) = build(case);
    let mut probe = Probe::new(model.len());
    let back: Backward = gradient(&model, &state, &mut probe, threads(1)).unwrap();
    let name = format!("{integrator:?}, {}", case.name);
    let l = forward_loss(&model, &state);
    check(&format!("{name}: loss"), back.loss, l, failures);
    let g = &back.gradient;
    let dx = |i: usize| (case.x0)(i, state.x[i]);
    let dv = |i: usize| direction(i, 2.0);
    let dm = |i: usize| 1.0 + (0.37 * i as f64).sin();
    let dk = |s: usize| 1.0 + (0.53 * s as f64).cos();
    let dc = |s: usize| 1.0 + (0.91 * s as f64).sin();
    let dg = DVec3::new(0.3, -1.0, 0.2);

    let fd = central(&model, &state, 1.0, &|_, x, s| {
        x.x.iter_mut()
            .enumerate()
            .for_each(|(i, p)| *p += s * dx(i))
    });
    check(&format!("{name}: x0"), dot(&back.x0, &dx), fd, failures);
    let fd = central(&model, &state, 1.0, &|_, x, s| {
        x.v.iter_mut()
            .enumerate()
            .for_each(|(i, p)| *p += s * dv(i))
    });
    check(&format!("{name}: v0"), dot(&back.v0, &dv), fd, failures);
    // A mass m_i moves with 1/m_i: ∂/∂m_i = m̄_i − w̄_i/m_i².
    let fd = central(&model, &state, 1.0, &|m, _, s| {
        for i in 0..m.len() {
            m.mass[i] += s * dm(i);
            if m.inv_mass[i] != 0.0 {
                m.inv_mass[i] = 1.0 / m.mass[i];
            }
        }
    });
    let mass = |i: usize| {
        let w = model.inv_mass[i];
        g.mass[i] - if w == 0.0 { 0.0 } else { g.inv_mass[i] * w * w }
    };
    let adj: f64 = (0..model.len()).map(|i| mass(i) * dm(i)).sum();
    check(&format!("{name}: mass"), adj, fd, failures);
    let fd = central(&model, &state, 1000.0, &|m, _, s| {
        let springs = m.springs_mut();
        for k in 0..springs.len() {
            springs.stiffness[k] += s * dk(k);
        }
    });
    check(
        &format!("{name}: stiffness"),
        dot1(&g.stiffness, &dk),
        fd,
        failures,
    );
    // δ = 1e-5 on dampers of 0.1–2 N·s/m: the differences' rounding, ~1e-16·L/δ, must stay
    // below 1e-6 of gradients as small as the box edge's 3e-3 (at δ = 1e-6 it is 4e-6 of it,
    // at 1e-7 3e-5: rounding, not the adjoint), and the truncation, O(δ²), stays below it.
    let fd = central(&model, &state, 10.0, &|m, _, s| {
        let springs = m.springs_mut();
        for k in 0..springs.len() {
            springs.damping[k] += s * dc(k);
        }
    });
    check(
        &format!("{name}: damping"),
        dot1(&g.damping, &dc),
        fd,
        failures,
    );
    let fd = central(&model, &state, 1000.0, &|m, _, s| {
        m.simulation.gravity += s * dg
    });
    check(
        &format!("{name}: gravity"),
        g.gravity_total().dot(dg),
        fd,
        failures,
    );
    let fd = central(&model, &state, 100.0, &|m, _, s| m.simulation.drag += s);
    check(&format!("{name}: drag"), g.drag_total(), fd, failures);
    for k in 0..model.terrain.len() {
        let fd = central(&model, &state, 1.0, &|m, _, s| m.terrain[k].friction += s);
        check(
            &format!("{name}: terrain[{k}].friction"),
            g.friction_of(k),
            fd,
            failures,
        );
        let fd = central(&model, &state, 1.0, &|m, _, s| {
            m.terrain[k].restitution += s
        });
        check(
            &format!("{name}: terrain[{k}].restitution"),
            g.restitution_of(k),
            fd,
            failures,
        );
    }
    if model.contact.enabled() {
        let fd = central(&model, &state, 1.0, &|m, _, s| m.contact.laws.friction += s);
        check(
            &format!("{name}: body_friction"),
            g.body_friction_total(),
            fd,
            failures,
        );
        let fd = central(&model, &state, 100.0, &|m, _, s| {
            m.contact.laws.restitution += s
        });
        check(
            &format!("{name}: body_restitution"),
            g.body_restitution_total(),
            fd,
            failures,
        );
    }
}
