//! The adjoint against central finite differences of the forward solver, for every explicit
//! integrator: free flight, a cube sliding down a slope (contact and kinetic Coulomb friction
//! throughout), a cube in a bowl (viscous friction on a curved surface), bouncing particles
//! (fresh impacts and restitution), particles sliding round a box's edge, off a
//! heightfield's peak and round a mesh's edge (the normal turning past edges and corners), and
//! contact between bodies: particles falling onto a cube's corners (fresh impacts with
//! restitution, pushed apart past the slop, one pair slipping and one sticking, then an impact
//! that is not fresh) and a particle pressed into a corner, sliding across it (the penalty at
//! every stage, viscous friction pressed by the impulse and the penalty).
//!
//! Each group of values θ (initial positions, initial velocities, masses, stiffnesses,
//! dampings, gravity, drag, friction, restitution) is moved along a fixed pseudo-random
//! direction d, and ⟨∇L, d⟩ is compared with (L(θ + δd) − L(θ − δd))/2δ. With δ = 1e-6 of the
//! values' scale the central difference's truncation error, δ²/6·|L'''|, is ~1e-13 of L's scale
//! and its rounding error ~1e-16/δ = 1e-10; the tolerance, 1e-6 of the larger of |⟨∇L, d⟩| and
//! the difference's own size, leaves room for both while a wrong term (a missing factor, a
//! sign) is off by O(1). Gravity and drag move by 1e-3 and 1e-4 absolute: the held cube's
//! loss depends on them by ~1e-4 of its size, where 1e-6 would leave the rounding of L over δ
//! at 1e-6 of their derivatives; L is smooth in both (they enter the forces linearly), so the
//! truncation error stays ~1e-8. Dampings move by 1e-5: the small damping gradients of the
//! sliding pairs (3e-3) leave the rounding at 1e-6 above the tolerance (see `check_case`).

use std::path::Path;

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::adjoint::run::{Backward, FrameBar, Loss, Options, gradient};
use softbody_scene::{Controls, Integrator, Model, Scene, Solver, State};

/// L = Σ_frames Σ_i (c_i·x_i + ½ w |v_i|²): linear in the positions with fixed pseudo-random
/// weights, quadratic in the velocities.
struct Probe {
    weights: Vec<DVec3>,
    w: f64,
    /// The states the loss saw, by frame.
    seen: Vec<(u64, State)>,
}

impl Probe {
    fn new(n: usize) -> Probe {
        Probe {
            weights: (0..n).map(|i| direction(i, 7.0)).collect(),
            w: 0.3,
            seen: Vec::new(),
        }
    }

    fn term(&self, state: &State) -> f64 {
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
fn threads(n: usize) -> Options<'static> {
    Options {
        threads: Some(n),
        ..Options::default()
    }
}

/// A fixed pseudo-random unit-ish vector for index i.
fn direction(i: usize, salt: f64) -> DVec3 {
    let t = i as f64 + salt;
    DVec3::new(
        (1.3 * t).sin(),
        (0.7 * t + 1.0).cos(),
        (2.1 * t + 0.5).sin(),
    )
}

/// The forward loss: the solver's run, the probe's terms at every frame.
fn forward_loss(model: &Model, start: &State) -> f64 {
    forward_loss_with(model, start, None)
}

/// The forward loss of the run with external forces `controls` (F × N, frame f's held from
/// its step to the next frame's).
fn forward_loss_with(model: &Model, start: &State, controls: Option<&[DVec3]>) -> f64 {
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

struct Case {
    name: &'static str,
    toml: String,
    /// Every particle's initial velocity gains this spin about the centre (rad/s).
    spin: f64,
    /// Every particle's initial position moves by up to this (m).
    strain: f64,
    /// The initial positions are the body's scaled by this about its centre.
    stretch: f64,
    /// The direction the initial positions are moved along, by particle and position: at a
    /// resting contact (v·N rounding to zero at every step, the contact force cancelling the
    /// push) the response sits on its kink, and a pseudo-random move of the particles has
    /// one-sided derivatives there that central differences average; the cases in contact
    /// move the body along a symmetry of its terrain instead, which keeps every branch.
    x0: fn(usize, DVec3) -> DVec3,
}

fn scattered(i: usize, _: DVec3) -> DVec3 {
    direction(i, 1.0)
}

fn cube(center: [f64; 3], velocity: [f64; 3]) -> String {
    format!(
        "[[body]]\nkind = \"cuboid\"\nsize = [0.3, 0.3, 0.3]\nresolution = [3, 3, 3]\n\
         center = [{}, {}, {}]\nrotation = [0.0, 0.0, -20.0]\nmass = 2.7\nvelocity = {velocity:?}\n\
         structural = {{ stiffness = 900.0, damping = 2.0 }}\n\
         shear = {{ stiffness = 700.0, damping = 1.5 }}\n\
         bending = {{ stiffness = 400.0, damping = 1.0 }}\n",
        center[0], center[1], center[2]
    )
}

fn cases(integrator: Integrator) -> Vec<Case> {
    // The contact band ε is wide enough that particles pressed onto the terrain stay inside it
    // (the contact force starts at φ = ε: a jump that differences cannot straddle).
    let sim = |duration: f64, band: f64| {
        format!(
            "[simulation]\nintegrator = \"{}\"\ndt = 1e-3\nduration = {duration}\nframe_rate = 100.0\n\
             drag = 0.2\ncontact_distance = {band}\n",
            integrator.name()
        )
    };
    vec![
        Case {
            name: "free flight",
            // Hanging from a pinned corner.
            toml: sim(0.12, 0.01) + &cube([0.0, 1.0, 0.0], [0.4, -0.2, 0.1]) + "pinned = [0]\n",
            spin: 2.0,
            strain: 0.01,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "sliding on a slope",
            // The cube's bottom face 5 mm above the 20° plane, in the contact band, sliding
            // down the slope and across it.
            toml: sim(0.12, 0.03)
                + &cube([0.0530, 0.1457, 0.0], [0.3759, -0.1368, 0.1])
                + "[[terrain]]\nkind = \"plane\"\npoint = [0.0, -0.0, 0.0]\n\
                   normal = [0.36397023426620234, 1.0, 0.0]\nfriction = 0.1\nfriction_model = \"coulomb\"\nrestitution = 0.3\n",
            spin: 0.0,
            strain: 0.001,
            stretch: 1.0,
            // Down the slope, within the plane.
            x0: |_, _| DVec3::new(0.9397, -0.3420, 0.0),
        },
        Case {
            name: "in a bowl",
            toml: sim(0.12, 0.03)
                + &cube([0.35, 0.24, 0.0], [0.4, -0.2, 0.1])
                + "[[terrain]]\nkind = \"bowl\"\ncenter = [0.0, 1.0, 0.0]\nradius = 1.0\n\
                   friction = 0.4\nfriction_model = \"viscous\"\nrestitution = 0.2\n",
            spin: 0.0,
            strain: 0.001,
            stretch: 1.0,
            // A turn about the bowl's vertical axis.
            x0: |_, x| DVec3::Y.cross(x - DVec3::Y),
        },
        Case {
            name: "bouncing",
            toml: sim(0.15, 0.01)
                + "[[body]]\nkind = \"particles\"\npositions = [[0.0, 0.052, 0.0], [0.1, 0.063, 0.02]]\n\
                   masses = [0.5, 0.7]\nvelocities = [[0.3, -1.0, 0.0], [0.2, -1.2, 0.1]]\n\
                   springs = [{ a = 0, b = 1, stiffness = 50.0, damping = 0.1 }]\n\
                   [[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nrestitution = 0.6\n\
                   friction = 0.0\n",
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "round a box's edge",
            // Two particles on a spring 1–1.5 cm past the top edge of a box (the edge along z),
            // in the contact band, sliding along it and down round it: the normal turns with
            // them until they pass onto the side face at ~0.05 s, 2 cm out (inside the band).
            toml: sim(0.06, 0.03)
                + &sliding_pair(
                    [[0.51, 0.51, 0.0], [0.512, 0.508, 0.05]],
                    EDGE_VELOCITIES,
                    "kind = \"box\"\ncenter = [0.0, 0.0, 0.0]\nhalf_extents = [0.5, 0.5, 1.0]\n",
                ),
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "on a tent's peak",
            // Two particles on a spring 1.5–2 cm above the raised vertex of a heightfield (a
            // tent of four 45° slopes), in the contact band, sliding off it: the normal turns
            // round the vertex and its edges.
            toml: sim(0.06, 0.03)
                + &sliding_pair(
                    [[1.0, 1.015, 1.0], [1.01, 1.012, 1.005]],
                    [[0.1, 0.0, 0.05], [0.05, 0.0, 0.1]],
                    "kind = \"heightfield\"\norigin = [0.0, 0.0, 0.0]\ncell_size = [1.0, 1.0]\n\
                     heights = [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]\n",
                ),
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "round a mesh's edge",
            // As round the box's edge, over a triangle mesh (the unit cube's OBJ): the normal
            // turns past the edge its two faces' triangles share.
            toml: sim(0.06, 0.03)
                + &sliding_pair(
                    [[1.01, 1.01, 0.3], [1.012, 1.008, 0.35]],
                    EDGE_VELOCITIES,
                    &format!(
                        "kind = \"mesh\"\npath = {:?}\n",
                        concat!(
                            env!("CARGO_MANIFEST_DIR"),
                            "/../terrain/tests/data/unit_cube.obj"
                        )
                    ),
                ),
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "bodies' impact",
            // Two particles on a spring falling at 3 m/s onto two corners of a cube, 5 and
            // 1.5 mm to their side: both meet their corner in the 11th step, fresh impacts at
            // d = 0.80 R, past the slop's 0.9 R (pushed apart), the tilted normal sliding the
            // first (|u_t|/W 0.14 N·s against μJ 0.078 N·s: kinetic) and not the second (0.045
            // against 0.10: static); they bounce off (the run ends before the cube's springs
            // bring a corner back: by 0.03 s symplectic Euler's comes within 0.13% of R of its
            // particle, a branch within 1e-5 of the moves). Every branch
            // holds by far more than the differences' moves (1e-6 m, 1e-6 m/s): a pair meets
            // its corner 2 mm past R, goes 1 mm past the slop, approaches at 2.3 m/s.
            toml: sim(0.02, 0.01)
                + "body_restitution = 0.5\nbody_friction = 0.2\n"
                + &corners()
                + "[[body]]\nkind = \"particles\"\n\
                   positions = [[-0.025, 0.06624, -0.03], [0.03, 0.06786, -0.0285]]\n\
                   masses = [0.3, 0.4]\nvelocities = [[0.0, -3.0, 0.0], [0.0, -3.0, 0.0]]\n\
                   contact_radius = 0.005\n\
                   springs = [{ a = 0, b = 1, stiffness = 200.0, damping = 0.1 }]\n",
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "bodies pressed, sliding",
            // A particle (on a spring to another) 0.3 mm into a cube's corner at the start,
            // pressing on it at 0.3 m/s and sliding across it at 0.5 m/s: the penalty at every
            // stage, an impulse in the first step that is not a fresh impact (u_n −0.05 to
            // −0.12 m/s, d 0.94–0.96 R: within R and the slop by far) with viscous friction,
            // pressed by it and the penalty, under its cap (k_f J|u_t| 0.002–0.005 N·s against
            // |u_t|/W 0.038 N·s), then the penalty pushing the pair apart; the pair leaves
            // contact moving apart (F = max(0, −c u_n) = 0 there, no jump) as the particle
            // slides off.
            toml: sim(0.03, 0.01)
                + "body_restitution = 0.5\nbody_friction = 0.5\nbody_friction_model = \"viscous\"\n"
                + &corners()
                + "[[body]]\nkind = \"particles\"\n\
                   positions = [[0.0397, 0.03, -0.03], [0.0997, 0.03, -0.03]]\n\
                   masses = [0.3, 0.4]\nvelocities = [[-0.3, 0.0, 0.5], [-0.3, 0.0, 0.5]]\n\
                   contact_radius = 0.005\n\
                   springs = [{ a = 0, b = 1, stiffness = 200.0, damping = 0.1 }]\n",
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "held stretched",
            // A 4³ lattice pinned on its faces 20 % out from its centre: the 8 particles
            // inside move, every spring stretched throughout.
            toml: sim(0.12, 0.01)
                + &cube([0.0, 1.0, 0.0], [0.0, 0.0, 0.0]).replace("[3, 3, 3]", "[4, 4, 4]")
                + &format!("pinned = {:?}\n", faces(4)),
            spin: 1.0,
            strain: 0.003,
            stretch: 1.2,
            x0: scattered,
        },
    ]
}

/// The velocities of the pairs round an edge: along it, and a little off it.
const EDGE_VELOCITIES: [[f64; 3]; 2] = [[0.05, -0.02, 0.3], [0.02, 0.0, 0.25]];

/// Two particles on a spring at `positions` with `velocities`, over the terrain `shape` (its
/// `[[terrain]]` keys) with Coulomb friction and restitution: the cases whose normal turns.
fn sliding_pair(positions: [[f64; 3]; 2], velocities: [[f64; 3]; 2], shape: &str) -> String {
    format!(
        "[[body]]\nkind = \"particles\"\npositions = {positions:?}\nmasses = [0.5, 0.7]\n\
         velocities = {velocities:?}\n\
         springs = [{{ a = 0, b = 1, stiffness = 50.0, damping = 0.1 }}]\n\
         [[terrain]]\n{shape}friction = 0.2\nfriction_model = \"coulomb\"\nrestitution = 0.3\n"
    )
}

/// A 6 cm cube of 2³ particles at the origin, at rest, whose particles touch others' within
/// 5 mm: the other body of the cases of contact between bodies.
fn corners() -> String {
    "[[body]]\nkind = \"cuboid\"\nsize = [0.06, 0.06, 0.06]\nresolution = [2, 2, 2]\n\
     center = [0.0, 0.0, 0.0]\nmass = 0.8\ncontact_radius = 0.005\n\
     structural = { stiffness = 900.0, damping = 2.0 }\n\
     shear = { stiffness = 700.0, damping = 1.5 }\n\
     bending = { stiffness = 400.0, damping = 1.0 }\n"
        .to_owned()
}

/// The particles on the faces of an n³ lattice.
fn faces(n: usize) -> Vec<usize> {
    let edge = |c: usize| c == 0 || c == n - 1;
    (0..n * n * n)
        .filter(|&p| edge(p % n) || edge(p / n % n) || edge(p / (n * n)))
        .collect()
}

fn build(case: &Case) -> (Model, State) {
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
fn central(
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

fn check(what: &str, adjoint: f64, fd: f64, failures: &mut Vec<String>) {
    let scale = adjoint.abs().max(fd.abs()).max(1e-12);
    let rel = (adjoint - fd).abs() / scale;
    if rel > 1e-6 {
        failures.push(format!(
            "{what}: adjoint {adjoint:e}, differences {fd:e} (relative {rel:.1e})"
        ));
    }
}

fn dot(a: &[DVec3], i: &dyn Fn(usize) -> DVec3) -> f64 {
    a.iter().enumerate().map(|(k, a)| a.dot(i(k))).sum()
}

fn dot1(a: &[f64], i: &dyn Fn(usize) -> f64) -> f64 {
    a.iter().enumerate().map(|(k, a)| a * i(k)).sum()
}

fn check_case(integrator: Integrator, case: &Case, failures: &mut Vec<String>) {
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
        let fd = central(&model, &state, 1.0, &|m, _, s| {
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
/// the explicit integrators' own. Steps in contact are refused.
#[test]
fn the_implicit_adjoint_is_the_derivative_of_the_computed_run() {
    let integrator = Integrator::ImplicitEuler;
    let case = cases(integrator)
        .into_iter()
        .find(|c| c.name == "held stretched")
        .unwrap();
    let (model, state) = build(&case);
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
fn implicit_contact_cases() -> Vec<Case> {
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

/// Implicit Euler's steps through contact between bodies have no adjoint yet: a scene whose
/// bodies can touch is refused before the run, saying so.
#[test]
fn implicit_euler_through_contact_between_bodies_is_refused() {
    let case = cases(Integrator::ImplicitEuler)
        .into_iter()
        .find(|c| c.name == "bodies' impact")
        .unwrap();
    let (model, state) = build(&case);
    let e = gradient(&model, &state, &mut Probe::new(model.len()), threads(1)).unwrap_err();
    let message = "gradients of implicit-euler through contact between bodies are not built yet";
    assert!(e.to_string().contains(message), "{e}");
}

const EXPLICIT: [Integrator; 4] = [
    Integrator::ExplicitEuler,
    Integrator::SymplecticEuler,
    Integrator::Midpoint,
    Integrator::Rk4,
];

#[test]
fn the_adjoint_is_the_derivative_of_the_computed_run() {
    let mut failures = Vec::new();
    for integrator in EXPLICIT {
        for case in cases(integrator) {
            check_case(integrator, &case, &mut failures);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The gradient of external forces held over each frame's steps (a control input) against
/// central differences of the run, as the other groups' (δ = 1e-6 N on forces of 0.05 N):
/// free flight, the slope and the pressed pair between bodies for every explicit integrator
/// (on the slope, forces and their change along it, which keep every contact's branch; between
/// bodies the forces beside the penalty), implicit Euler held stretched.
#[test]
fn the_controls_gradient_is_the_derivative_of_the_computed_run() {
    let slope = DVec3::new(0.9397, -0.3420, 0.0);
    let mut failures = Vec::new();
    let runs = EXPLICIT
        .iter()
        .flat_map(|&i| {
            [
                (i, "free flight"),
                (i, "sliding on a slope"),
                (i, "bodies pressed, sliding"),
            ]
        })
        .chain([(Integrator::ImplicitEuler, "held stretched")]);
    for (integrator, name) in runs {
        let case = cases(integrator)
            .into_iter()
            .find(|c| c.name == name)
            .unwrap();
        let (model, state) = build(&case);
        let n = model.len();
        let count = model.simulation.frame_count() as usize * n;
        let along = |k: usize, salt: f64| match name {
            "sliding on a slope" => direction(k, salt).x * slope,
            _ => direction(k, salt),
        };
        let u: Vec<DVec3> = (0..count).map(|k| 0.05 * along(k, 5.0)).collect();
        let d: Vec<DVec3> = (0..count).map(|k| along(k, 9.0)).collect();
        let controls = Controls::new(&model, u.as_slice()).unwrap();
        let options = Options {
            threads: Some(1),
            controls: Some(&controls),
            ..Options::default()
        };
        let back = gradient(&model, &state, &mut Probe::new(n), options).unwrap();
        let what = format!("{integrator:?}, {name}");
        check(
            &format!("{what}: loss"),
            back.loss,
            forward_loss_with(&model, &state, Some(&u)),
            &mut failures,
        );
        let delta = 1e-6;
        let at = |s: f64| {
            let moved: Vec<DVec3> = u.iter().zip(&d).map(|(u, d)| *u + s * *d).collect();
            forward_loss_with(&model, &state, Some(&moved))
        };
        let fd = (at(delta) - at(-delta)) / (2.0 * delta);
        check(
            &format!("{what}: controls"),
            dot(&back.controls, &|k| d[k]),
            fd,
            &mut failures,
        );
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The cases touch what they are meant to: the slope's and the bowl's particles press on the
/// terrain, the bouncing ones make fresh impacts (their restitution's gradient is not zero),
/// the bodies' pairs slide and the falling ones bounce off the cube.
#[test]
fn the_cases_reach_their_laws() {
    for case in cases(Integrator::SymplecticEuler) {
        let (model, state) = build(&case);
        let back = gradient(&model, &state, &mut Probe::new(model.len()), threads(1)).unwrap();
        let g = &back.gradient;
        match case.name {
            "sliding on a slope"
            | "in a bowl"
            | "round a box's edge"
            | "on a tent's peak"
            | "round a mesh's edge" => {
                assert!(g.friction_of(0) != 0.0, "{}", case.name)
            }
            "bouncing" => assert!(g.restitution_of(0) != 0.0),
            "bodies' impact" => {
                assert!(g.body_restitution_total() != 0.0);
                assert!(g.body_friction_total() != 0.0);
            }
            "bodies pressed, sliding" => assert!(g.body_friction_total() != 0.0),
            _ => assert!(model.terrain.is_empty()),
        }
    }
}

/// The gradient's bits do not depend on the thread count (RK4 in contact with the terrain and
/// between bodies, implicit Euler held stretched and sliding on a slope); the states the
/// backward pass recomputes are the forward run's (the loss sees the bits a plain run has at
/// each frame).
#[test]
fn the_same_bits_on_any_thread_count_and_recomputed_states_are_the_forward_ones() {
    for (integrator, name) in [
        (Integrator::Rk4, "sliding on a slope"),
        (Integrator::Rk4, "bodies' impact"),
        (Integrator::ImplicitEuler, "held stretched"),
    ] {
        let case = cases(integrator)
            .into_iter()
            .find(|c| c.name == name)
            .unwrap();
        same_bits_on_any_thread_count(&case);
    }
    same_bits_on_any_thread_count(&implicit_contact_cases()[0]);
}

fn same_bits_on_any_thread_count(case: &Case) {
    let (model, state) = build(case);
    let bits = |b: &Backward| {
        let mut out: Vec<u64> =
            b.x0.iter()
                .chain(&b.v0)
                .flat_map(|p| p.to_array())
                .map(f64::to_bits)
                .collect();
        out.extend(
            b.gradient
                .stiffness
                .iter()
                .chain(&b.gradient.mass)
                .chain(&b.gradient.inv_mass)
                .map(|x| x.to_bits()),
        );
        out.push(b.gradient.friction_of(0).to_bits());
        out.push(b.gradient.body_friction_total().to_bits());
        out.push(b.gradient.body_restitution_total().to_bits());
        out.push(b.loss.to_bits());
        out
    };
    let mut probe = Probe::new(model.len());
    let one = gradient(&model, &state, &mut probe, threads(1)).unwrap();
    for n in [2, 3] {
        let other = gradient(&model, &state, &mut Probe::new(model.len()), threads(n)).unwrap();
        assert_eq!(bits(&one), bits(&other), "{n} threads");
    }
    let sim = &model.simulation;
    let mut solver = CpuSolver::new(model.clone(), state.clone(), Some(1)).unwrap();
    let mut at = 0;
    probe.seen.sort_by_key(|(f, _)| *f);
    assert_eq!(probe.seen.len() as u64, sim.frame_count());
    for (f, seen) in &probe.seen {
        let step = sim.frame_step(*f);
        solver.advance(step - at).unwrap();
        at = step;
        assert_eq!(solver.state().unwrap(), seen, "frame {f}");
    }
}

/// Checkpoints every ⌈√T⌉ steps: over T = 10⁴ steps at most 2√T + 2 states are held.
#[test]
fn memory_grows_as_the_square_root_of_the_steps() {
    let toml = "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 1e-4\nduration = 1.0\nframe_rate = 10.0\n\
                [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0], [0.1, 1.0, 0.0]]\n\
                masses = [1.0, 1.0]\nsprings = [{ a = 0, b = 1, stiffness = 10.0 }]\n";
    let scene = Scene::from_toml(toml, Path::new("long.toml")).unwrap();
    let (model, state) = Model::build(&scene);
    let back = gradient(&model, &state, &mut Probe::new(2), threads(1)).unwrap();
    assert_eq!(back.steps, 10_000);
    assert_eq!(back.interval, 100);
    assert!(back.peak_states <= 2 * 100 + 2, "{}", back.peak_states);
}
