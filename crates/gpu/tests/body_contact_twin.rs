//! Contact between bodies on the GPU against its CPU twin (`softbody_cpu::{broad_phase,
//! body_contact}`) on the same f32-exact input: the pairs of random clouds as sets, the penalty
//! forces, one response, implicit Euler's system with the pairs in it, and the same bits run
//! after run and on every grid width. (What both
//! backends must do on their own — momentum, restitution, stacks, self-contact — is tested once
//! for both in the top-level `tests/body_contact.rs`.)
//!
//! softbody-testkit's harness, as `twins.rs`: without an adapter every test reports itself
//! ignored, unless `SOFTBODY_REQUIRE_GPU=1`. Each prints what it measured (`--nocapture`).
//!
//! # Tolerances
//!
//! The GPU tests d² < R² in f32, the CPU in f64 on the same f32 positions (and f64 radii): a pair
//! whose distance is within f32 rounding of R may be in one set and not in the other. Such pairs
//! are counted and left out (their particles too, below); every other pair must be in both. The
//! clouds plant a few pairs at d = R on purpose, so that the exclusion is exercised and bounded.
//!
//! Forces and responses are sums of a few dozen f32 operations per pair, compared as the stage
//! twins are (`Backend::tolerance`, 1e-5 relative) against the scale of their terms: a penalty
//! force against Σ k R + c (|v_i| + |v_j|) over the particle's pairs; a response's velocity
//! against |v| + Σ (|v_i| + |v_j| + |v_i⁰| + |v_j⁰| + κR/h) (the normal and friction impulses, the
//! penalty's pressure over the step); its position against |x| + Σ R. The penalty's damping makes
//! the force jump at d = R, and a response's fresh-impact test jumps at d_start = R: the
//! particles of pairs within rounding of either are left out of those comparisons.

mod common;

use std::collections::BTreeSet;
use std::process::ExitCode;
use std::sync::Arc;

use common::{inverse_block, product_scale, rhs_scale, step_error};
use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::body_contact::{BodyContact, PairForces};
use softbody_cpu::broad_phase::BroadPhase;
use softbody_gpu::{Gpu, GpuOptions, GpuSolver};
use softbody_scene::{FrictionModel, Integrator, Model, Scene, Solver, State};
use softbody_testkit::scenes::{cuboid, cuboid_body, particles, plane, scene, simulation, spring};
use softbody_testkit::{Backend, Failed, GpuTest, Rng, all, ensure};

fn main() -> ExitCode {
    let tests: &[(&str, GpuTest)] = &[
        ("the_pairs_of_a_random_cloud_are_the_cpus", |gpu| {
            pairs_twin(gpu, 600, 0.5, 1)
        }),
        (
            "the_pairs_of_a_large_cloud_are_the_cpus",
            // 45,189 particles: 131,072 buckets, a prefix sum of three levels.
            |gpu| pairs_twin(gpu, 30_000, 1.75, 2),
        ),
        ("the_penalty_forces_are_the_cpus", pair_forces_twin),
        ("one_response_is_the_cpus_coulomb", |gpu| {
            response_twin(gpu, FrictionModel::Coulomb)
        }),
        ("one_response_is_the_cpus_viscous", |gpu| {
            response_twin(gpu, FrictionModel::Viscous)
        }),
        ("one_step_explicit_euler", |gpu| {
            one_step_twin(gpu, Integrator::ExplicitEuler)
        }),
        ("one_step_symplectic_euler", |gpu| {
            one_step_twin(gpu, Integrator::SymplecticEuler)
        }),
        ("one_step_midpoint", |gpu| {
            one_step_twin(gpu, Integrator::Midpoint)
        }),
        ("one_step_rk4", |gpu| one_step_twin(gpu, Integrator::Rk4)),
        (
            "implicit_eulers_system_with_pairs_is_the_cpus",
            implicit_system_twin,
        ),
        (
            "body_contact_gives_the_same_bits_every_run_and_grid_width",
            same_bits,
        ),
    ];
    softbody_testkit::run_gpu("GPU body contact twin tests", tests.iter().copied())
}

// ---------------------------------------------------------------------------------------------
// The clouds

/// The step of the clouds' model (the penalty's k = κ m_red/h² and the response use it).
const DT: f64 = 1e-4;

/// Contact radii of the two `particles` bodies.
const LOOSE_RADIUS: f64 = 0.02;
const SMALL_RADIUS: f64 = 0.012;

/// A random cloud in a cube of `size` m, every particle at a random place with a random
/// velocity (up to 1 m/s; pinned ones at rest), f32-exact: a 5³ cuboid with self-contact (the
/// lattice rule) and two of its particles pinned, a 4³ cuboid without self-contact (both in the
/// corner cube of 0.5 m, so that they touch in any cloud), a `particles` body of `loose`
/// particles with self-contact and one of `loose / 2` without. Half of the loose
/// body's particles come in close pairs (d < R), every other such pair joined by a spring (the
/// spring rule: not admitted), and one in eight pairs planted at d = R (rounding decides).
fn cloud(loose: usize, size: f64, seed: u64) -> (Model, State) {
    let mut rng = Rng::new(seed);
    let inside = |rng: &mut Rng| rng.in_box(DVec3::ZERO, DVec3::splat(size));
    let reach = 2.0 * LOOSE_RADIUS;
    let mut positions: Vec<DVec3> = Vec::with_capacity(loose);
    let mut springs = Vec::new();
    for k in 0..loose {
        let p = match k % 8 {
            1 | 3 | 5 => positions[k - 1] + rng.direction() * rng.range(0.3, 0.95) * reach,
            7 => positions[k - 1] + rng.direction() * reach,
            _ => inside(&mut rng),
        };
        positions.push(p);
        if k % 4 == 1 {
            springs.push(spring(k as u32 - 1, k as u32, 100.0, 0.1));
        }
    }
    let masses = |count: usize, rng: &mut Rng| -> Vec<f64> {
        (0..count).map(|_| rng.range(0.01, 0.1)).collect()
    };
    let loose_masses = masses(loose, &mut rng);
    let small_masses = masses(loose / 2, &mut rng);
    let mut loose_body = particles(positions, vec![DVec3::ZERO; loose], loose_masses, springs);
    loose_body.name = "loose".into();
    loose_body.contact_radius = Some(LOOSE_RADIUS);
    loose_body.self_contact = true;
    let small_positions = (0..loose / 2).map(|_| inside(&mut rng)).collect();
    let mut small = particles(
        small_positions,
        vec![DVec3::ZERO; loose / 2],
        small_masses,
        Vec::new(),
    );
    small.name = "small".into();
    small.contact_radius = Some(SMALL_RADIUS);
    let params = softbody_scene::SpringParams {
        stiffness: 100.0,
        damping: 0.1,
    };
    let mut lattice = cuboid_body(cuboid(
        DVec3::splat(0.2),
        [5, 5, 5],
        DVec3::ZERO,
        1.0,
        params,
    ));
    lattice.self_contact = true;
    lattice.pinned = vec![0, 7];
    let mut other = cuboid_body(cuboid(
        DVec3::splat(0.2),
        [4, 4, 4],
        DVec3::ZERO,
        0.5,
        params,
    ));
    other.name = "other".into();
    other.contact_radius = Some(0.03);
    let mut sim = simulation(Integrator::SymplecticEuler, DT);
    sim.body_contact.restitution = 0.5;
    sim.body_contact.friction = 0.4;
    let scene = scene(sim, vec![lattice, other, loose_body, small], Vec::new());
    let (model, mut state) = Model::build(&scene);
    let cuboids = (model.bodies[2].first) as usize;
    for x in &mut state.x[..cuboids] {
        *x = rng.in_box(DVec3::ZERO, DVec3::splat(0.5));
    }
    for (i, v) in state.v.iter_mut().enumerate() {
        *v = if model.inv_mass[i] > 0.0 {
            rng.vec(1.0)
        } else {
            DVec3::ZERO
        };
    }
    let state = f32_exact(&state);
    (model, state)
}

/// The state rounded through f32, as the GPU holds it.
fn f32_exact(state: &State) -> State {
    let round = |v: &Vec<DVec3>| v.iter().map(|p| p.as_vec3().as_dvec3()).collect();
    State {
        x: round(&state.x),
        v: round(&state.v),
    }
}

fn open(gpu: &Arc<Gpu>, model: &Model, state: &State) -> Result<GpuSolver, Failed> {
    GpuSolver::on(gpu, model.clone(), state.clone()).map_err(|e| e.to_string().into())
}

/// The penalty's stiffness k = κ m_red/h² and critical damping c = 2√(k m_red) of the pair
/// (i, j) at step h (docs/physics.md, "Contact between bodies"); `None` when both are pinned.
fn penalty_coefficients(
    model: &Model,
    kappa: f64,
    h: f64,
    i: usize,
    j: usize,
) -> Option<(f64, f64)> {
    let w = model.inv_mass[i] + model.inv_mass[j];
    if w == 0.0 {
        return None;
    }
    let m_red = 1.0 / w;
    let k = kappa * m_red / (h * h);
    Some((k, 2.0 * (k * m_red).sqrt()))
}

/// R = r_i + r_j of a pair, in f64.
fn reach(model: &Model, [i, j]: [u32; 2]) -> f64 {
    model.contact.radius[i as usize] + model.contact.radius[j as usize]
}

/// Whether `d` is within f32 rounding of `r` (a few units of f32 roundoff of R, with a margin).
fn borderline(d: f64, r: f64) -> bool {
    (d - r).abs() <= 1e-6 * r
}

/// The CPU's pairs of `x` (with its model's radii and admit rule).
fn cpu_pairs(model: &Model, x: &[DVec3]) -> Vec<[u32; 2]> {
    let c = &model.contact;
    BroadPhase::new()
        .pairs(x, &c.radius, |i, j| model.admits(i, j))
        .to_vec()
}

/// Pairs (i, j), i < j.
type Pairs = BTreeSet<[u32; 2]>;

/// The pairs in both sets, and those in one only whose distance is within rounding of R; an
/// error naming the others if there are any.
fn agreeing_pairs(
    model: &Model,
    x: &[DVec3],
    gpu: &[[u32; 2]],
    cpu: &[[u32; 2]],
) -> Result<(Pairs, Vec<[u32; 2]>), Failed> {
    let (g, c): (Pairs, Pairs) = (gpu.iter().copied().collect(), cpu.iter().copied().collect());
    let (mut near, mut wrong) = (Vec::new(), Vec::new());
    for &p in g.symmetric_difference(&c) {
        let d = x[p[0] as usize].distance(x[p[1] as usize]);
        if borderline(d, reach(model, p)) {
            near.push(p);
        } else {
            wrong.push(format!(
                "{p:?} (d = {d}, R = {}, {})",
                reach(model, p),
                if g.contains(&p) {
                    "GPU only"
                } else {
                    "CPU only"
                }
            ));
        }
    }
    ensure(wrong.is_empty(), || {
        format!(
            "{} pairs differ beyond rounding, e.g. {:?}",
            wrong.len(),
            &wrong[..wrong.len().min(5)]
        )
    })?;
    Ok((g.intersection(&c).copied().collect(), near))
}

/// The particles of the pairs within rounding of R at `x`: those of `near` and every pair of
/// `pairs` within rounding at `x`.
fn doubtful(model: &Model, x: &[DVec3], pairs: &Pairs, near: &[[u32; 2]]) -> BTreeSet<u32> {
    let close = pairs
        .iter()
        .filter(|&&p| borderline(x[p[0] as usize].distance(x[p[1] as usize]), reach(model, p)));
    near.iter().chain(close).flatten().copied().collect()
}

// ---------------------------------------------------------------------------------------------
// The tests

/// The GPU's pairs of a cloud (`loose` particles of the loose body, in a cube of `size`) are the
/// CPU's, but for a few within rounding of R; every rule of admission is exercised.
fn pairs_twin(gpu: &Arc<Gpu>, loose: usize, size: f64, seed: u64) -> Result<(), Failed> {
    let (model, state) = cloud(loose, size, seed);
    let mut g = open(gpu, &model, &state)?;
    let got = g.debug_contact_pairs().map_err(step_error)?;
    let want = cpu_pairs(&model, &state.x);
    let (same, near) = agreeing_pairs(&model, &state.x, &got, &want)?;
    let c = &model.contact;
    let body = |p: u32| c.body[p as usize];
    let between = want.iter().filter(|p| body(p[0]) != body(p[1])).count();
    let lattice_self = want
        .iter()
        .filter(|p| body(p[0]) == 0 && body(p[1]) == 0)
        .count();
    let loose_self = want
        .iter()
        .filter(|p| body(p[0]) == 2 && body(p[1]) == 2)
        .count();
    // Close pairs of the loose body joined by a spring: in reach, not admitted.
    let first = model.bodies[2].first as usize;
    let joined = (0..loose)
        .step_by(4)
        .filter(|k| {
            let (a, b) = (first + k, first + k + 1);
            state.x[a].distance(state.x[b]) < c.radius[a] + c.radius[b]
        })
        .count();
    println!(
        "{} particles: CPU {} pairs, GPU {}, {} in both; {} within rounding of R (left out); \
         {} between bodies, {} within the self-contact cuboid, {} within the loose body; {} \
         joined pairs in reach not admitted",
        model.len(),
        want.len(),
        got.len(),
        same.len(),
        near.len(),
        between,
        lattice_self,
        loose_self,
        joined
    );
    let planted = loose / 8;
    let mut failures = Vec::new();
    if near.len() > planted {
        failures.push(format!(
            "{} pairs within rounding of R, more than the {planted} planted",
            near.len()
        ));
    }
    if want.len() < loose {
        failures.push(format!(
            "only {} pairs: the cloud is too sparse",
            want.len()
        ));
    }
    if [between, lattice_self, loose_self, joined].contains(&0) {
        failures.push("a rule of admission is not exercised".to_owned());
    }
    all(failures)
}

/// The penalty forces of a cloud's pairs in contact, at the same state: the GPU's
/// `pair_forces` against the CPU's `Partners::force`.
fn pair_forces_twin(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cloud(600, 0.5, 3);
    let mut g = open(gpu, &model, &state)?;
    let got = g.debug_pair_forces().map_err(step_error)?;
    let gpu_pairs = g.debug_contact_pairs().map_err(step_error)?;
    let cpu_pairs = cpu_pairs(&model, &state.x);
    let (pairs, near) = agreeing_pairs(&model, &state.x, &gpu_pairs, &cpu_pairs)?;
    let left_out = doubtful(&model, &state.x, &pairs, &near);
    let mut contact = BodyContact::new();
    contact.prepare(&model, &state);
    let kappa = softbody_cpu::body_contact::PENALTY;
    let mut scale = vec![0.0f64; model.len()];
    for &[i, j] in &pairs {
        let (i, j) = (i as usize, j as usize);
        let Some((k, c)) = penalty_coefficients(&model, kappa, DT, i, j) else {
            continue;
        };
        let term = k * reach(&model, [i as u32, j as u32])
            + c * (state.v[i].length() + state.v[j].length());
        scale[i] += term;
        scale[j] += term;
    }
    let tolerance = Backend::gpu(gpu.clone()).tolerance();
    let (mut worst, mut pushed, mut failures) = (0.0f64, 0, Vec::new());
    for i in 0..model.len() {
        if left_out.contains(&(i as u32)) {
            continue;
        }
        let want = contact.partners().force(&model, i, &state.x, &state.v);
        let error = (got[i].as_dvec3() - want).length();
        if want != DVec3::ZERO {
            pushed += 1;
        }
        if scale[i] > 0.0 {
            worst = worst.max(error / scale[i]);
        }
        if !tolerance.allows(error, scale[i]) {
            failures.push(format!(
                "particle {i}: GPU {} N, CPU {want} N (scale {} N)",
                got[i], scale[i]
            ));
        }
    }
    println!(
        "{} pairs, {pushed} particles pushed, {} left out; largest error {worst:.2e} of the \
         scale (bound {:e})",
        pairs.len(),
        left_out.len(),
        tolerance.rel
    );
    if pushed < 100 {
        failures.push(format!("only {pushed} particles feel a penalty force"));
    }
    all(failures)
}

/// One response of the cloud's pairs at the end of a step: the GPU's `body_contact_response`
/// against the CPU's `BodyContact::respond`, from the same start and end states.
fn response_twin(gpu: &Arc<Gpu>, friction_model: FrictionModel) -> Result<(), Failed> {
    let (mut model, start) = cloud(600, 0.5, 4);
    model.contact.laws.friction_model = friction_model;
    // The end: every particle moved by up to 1 cm and its velocity changed by up to 0.3 m/s,
    // so that some pairs met within the step (fresh impacts) and others were already touching.
    let mut rng = Rng::new(5);
    let end = f32_exact(&State {
        x: start.x.iter().map(|&x| x + rng.vec(0.01)).collect(),
        v: start
            .v
            .iter()
            .zip(&model.inv_mass)
            .map(|(&v, &w)| if w > 0.0 { v + rng.vec(0.3) } else { v })
            .collect(),
    });
    let mut g = open(gpu, &model, &start)?;
    g.set_state(&end).map_err(step_error)?;
    let gpu_pairs = g.debug_contact_pairs().map_err(step_error)?;
    g.debug_body_contact_response(&start).map_err(step_error)?;
    let got = g.state().map_err(step_error)?.clone();
    let mut want = end.clone();
    BodyContact::new().respond(&model, &start, &mut want);

    let cpu_pairs = cpu_pairs(&model, &end.x);
    let (pairs, near) = agreeing_pairs(&model, &end.x, &gpu_pairs, &cpu_pairs)?;
    let mut left_out = doubtful(&model, &end.x, &pairs, &near);
    left_out.extend(doubtful(&model, &start.x, &pairs, &[]));
    let kappa = softbody_cpu::body_contact::PENALTY;
    let mut scale_x: Vec<f64> = end.x.iter().map(|x| x.length()).collect();
    let mut scale_v: Vec<f64> = end.v.iter().map(|v| v.length()).collect();
    let mut fresh = 0;
    for &[i, j] in &pairs {
        let (i, j) = (i as usize, j as usize);
        let r = reach(&model, [i as u32, j as u32]);
        let term = end.v[i].length()
            + end.v[j].length()
            + start.v[i].length()
            + start.v[j].length()
            + kappa * r / DT;
        for p in [i, j] {
            scale_x[p] += r;
            scale_v[p] += term;
        }
        if start.x[i].distance(start.x[j]) >= r {
            fresh += 1;
        }
    }
    let tolerance = Backend::gpu(gpu.clone()).tolerance();
    let (mut worst_x, mut worst_v, mut moved, mut failures) = (0.0f64, 0.0f64, 0, Vec::new());
    for i in 0..model.len() {
        if left_out.contains(&(i as u32)) {
            continue;
        }
        let ex = got.x[i].distance(want.x[i]);
        let ev = got.v[i].distance(want.v[i]);
        worst_x = worst_x.max(ex / scale_x[i]);
        worst_v = worst_v.max(ev / scale_v[i]);
        if want.v[i] != end.v[i] {
            moved += 1;
        }
        if !tolerance.allows(ex, scale_x[i]) || !tolerance.allows(ev, scale_v[i]) {
            failures.push(format!(
                "particle {i}: GPU ({}, {}), CPU ({}, {}) (scales {} m, {} m/s)",
                got.x[i], got.v[i], want.x[i], want.v[i], scale_x[i], scale_v[i]
            ));
        }
    }
    println!(
        "{friction_model:?}: {} pairs ({fresh} apart at the start), {moved} particles changed, {} \
         left out; largest errors {worst_x:.2e} (x) and {worst_v:.2e} (v) of the scales (bound \
         {:e})",
        pairs.len(),
        left_out.len(),
        tolerance.rel
    );
    if moved < 100 || fresh == 0 {
        failures.push(format!(
            "the response changed only {moved} particles, {fresh} pairs apart at the start"
        ));
    }
    all(failures)
}

/// Two 4³ cubes 6 cm apart thrown at each other at 1 m/s each over a plane, one in
/// self-contact, and a springy `particles` body in self-contact between them: the cubes meet
/// after about 100 steps of 1e-4 s.
fn meeting(integrator: Integrator) -> Scene {
    let params = softbody_scene::SpringParams {
        stiffness: 500.0,
        damping: 1.0,
    };
    let mut a = cuboid(
        DVec3::splat(0.1),
        [4, 4, 4],
        DVec3::new(-0.08, 0.07, 0.0),
        1.0,
        params,
    );
    a.velocity = DVec3::X;
    let mut b = a.clone();
    b.center = DVec3::new(0.08, 0.08, 0.01);
    b.velocity = -DVec3::X;
    let mut b = cuboid_body(b);
    b.name = "b".into();
    b.self_contact = true;
    let mut rng = Rng::new(7);
    let positions: Vec<DVec3> = (0..40)
        .map(|_| {
            rng.in_box(
                DVec3::new(-0.005, 0.02, -0.06),
                DVec3::new(0.005, 0.15, 0.06),
            )
        })
        .collect();
    let springs = (1..40)
        .step_by(2)
        .map(|k| spring(k - 1, k, 50.0, 0.1))
        .collect();
    let mut loose = particles(positions, vec![DVec3::ZERO; 40], vec![0.01; 40], springs);
    loose.contact_radius = Some(0.01);
    loose.self_contact = true;
    let mut sim = simulation(integrator, DT);
    sim.body_contact.restitution = 0.3;
    sim.body_contact.friction = 0.4;
    let floor = plane(DVec3::ZERO, DVec3::Y, 0.2, 0.5);
    scene(sim, vec![cuboid_body(a), b, loose], vec![floor])
}

/// One step of `integrator` from the meeting's state after 250 steps (the cubes and the loose
/// body pressed together): the GPU's step against the CPU's, forces, penalties, update, terrain
/// and body responses together, from the same f32-exact state. The particles of pairs within
/// rounding of R at the step's start or end are left out (see the module doc).
fn one_step_twin(gpu: &Arc<Gpu>, integrator: Integrator) -> Result<(), Failed> {
    let (model, state) = Model::build(&meeting(integrator));
    let mut cpu = CpuSolver::new(model.clone(), state, Some(1)).map_err(|e| e.to_string())?;
    cpu.advance(250).map_err(step_error)?;
    let start = f32_exact(cpu.state().map_err(step_error)?);
    cpu.set_state(&start).map_err(step_error)?;
    cpu.advance(1).map_err(step_error)?;
    let want = cpu.state().map_err(step_error)?.clone();
    let mut g = open(gpu, &model, &start)?;
    g.advance(1).map_err(step_error)?;
    let got = g.state().map_err(step_error)?.clone();
    let mut left_out = BTreeSet::new();
    let mut partners = vec![0.0f64; model.len()];
    for x in [&start.x, &want.x] {
        let pairs: Pairs = cpu_pairs(&model, x).into_iter().collect();
        left_out.extend(doubtful(&model, x, &pairs, &[]));
        for &[i, j] in &pairs {
            let r = reach(&model, [i, j]);
            partners[i as usize] += r;
            partners[j as usize] += r;
        }
    }
    // Scales: x against |x| + h·|v|max + the pushes' reach; v against |v| plus h times the
    // acceleration's terms (gravity, the springs' k_s(r + 5 cm) + 2 k_d per unit mass, the
    // penalties' κ R/h² at most per unit mass).
    let h = DT;
    let kappa = softbody_cpu::body_contact::PENALTY;
    let (mut worst_x, mut worst_v, mut failures) = (0.0f64, 0.0f64, Vec::new());
    let tolerance = Backend::gpu(gpu.clone()).tolerance();
    for (i, &reached) in partners.iter().enumerate() {
        if left_out.contains(&(i as u32)) {
            continue;
        }
        let springs: f64 = model
            .adjacency()
            .of(i)
            .iter()
            .map(|&e| {
                let (s, sp) = ((e >> 1) as usize, model.springs());
                sp.stiffness[s] * (sp.rest[s] + 0.05) + 2.0 * sp.damping[s]
            })
            .sum();
        let scale_x = start.x[i].length() + h * 10.0 + reached;
        let scale_v =
            start.v[i].length() + h * (9.81 + springs / model.mass[i]) + kappa * reached / h;
        let (ex, ev) = (got.x[i].distance(want.x[i]), got.v[i].distance(want.v[i]));
        worst_x = worst_x.max(ex / scale_x);
        worst_v = worst_v.max(ev / scale_v);
        if !tolerance.allows(ex, scale_x) || !tolerance.allows(ev, scale_v) {
            failures.push(format!(
                "particle {i}: GPU ({}, {}), CPU ({}, {})",
                got.x[i], got.v[i], want.x[i], want.v[i]
            ));
        }
    }
    let touching = partners.iter().filter(|&&r| r > 0.0).count();
    println!(
        "{integrator}: {touching} particles touching, {} left out; largest errors {worst_x:.2e} \
         (x) and {worst_v:.2e} (v) of the scales (bound {:e})",
        left_out.len(),
        tolerance.rel
    );
    if touching < 10 {
        failures.push(format!("only {touching} particles touch"));
    }
    all(failures)
}

/// Two 10 cm cubes of 4³ particles pressed into each other (2 kg and 1 kg, contact radius 1.67
/// cm), the upper one turned by 45° and its lowest layer 60% of R above the lower one's top,
/// positions perturbed by up to 2 mm and velocities by up to 2 m/s (so that some pairs in
/// contact pull apart: F ≤ 0, left out of the system), one particle of the lower cube pinned,
/// drag 0.2, implicit Euler at h = 1/60 s; f32-exact.
fn pressed_cubes() -> (Model, State) {
    let params = softbody_scene::SpringParams {
        stiffness: 800.0,
        damping: 2.0,
    };
    let lower = cuboid(DVec3::splat(0.1), [4, 4, 4], DVec3::ZERO, 2.0, params);
    let reach = 0.1 / 3.0;
    let mut upper = cuboid(
        DVec3::splat(0.1),
        [4, 4, 4],
        DVec3::new(0.01, 0.1 + 0.6 * reach, -0.005),
        1.0,
        params,
    );
    upper.rotation = DVec3::new(0.0, 45.0, 0.0);
    let mut lower = cuboid_body(lower);
    lower.pinned = vec![3];
    let mut upper = cuboid_body(upper);
    upper.name = "upper".into();
    let mut sim = simulation(Integrator::ImplicitEuler, 1.0 / 60.0);
    sim.drag = 0.2;
    let (model, mut state) = Model::build(&scene(sim, vec![lower, upper], Vec::new()));
    let mut rng = Rng::new(11);
    for i in 0..model.len() {
        state.x[i] += rng.vec(0.002);
        if model.inv_mass[i] > 0.0 {
            state.v[i] += rng.vec(2.0);
        }
    }
    (model, f32_exact(&state))
}

/// Implicit Euler's system at the pressed cubes' state with the pairs in contact there: the
/// GPU's assembly (b, block-Jacobi inverse) and product A p (`pair_system`, `pair_products`
/// and the `…_with_pairs` particle kernels) against the CPU's `System` with the `Partners` of
/// the same state, on the same f32-exact input and p.
///
/// Both compute each pair's penalty from the same f32 positions: the GPU in f32, where
/// d = |x_i − x_j| has an absolute error of a few ulp(R), so F = k(R − d) − c (u·n) one of
/// k·R·u (u = 2⁻²⁴) plus c|u_ij|·u. The errors are compared as the stage twins' (`tolerance()`,
/// 1e-5 relative, about 170 u) against the scale of their terms: b against
/// h(m|g| + drag·m|v| + Σ|g_s|) + h Σ_pairs (k R + (c + h k)|v_i − v_j|), A p against
/// m(1 + h·drag)|p_i| + Σ_springs (β + γ)(|p_a| + |p_b|) + Σ_pairs β (|p_i| + |p_j|), each
/// inverse block against its largest entry. A pair whose d is within rounding of R, or whose F
/// at the start is within 1e-4 of its scale of 0 (in the system on one side only), would leave
/// its particles out; the scene has none (checked), and at least 20 pairs push and some pull.
/// Measured on lavapipe: 29 pairs (26 push, 3 pull), largest errors 1.7e-7 (b), 1.2e-7 (A p)
/// and 4.2e-7 (inverse blocks) of the scales.
fn implicit_system_twin(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    use softbody_cpu::integrators::implicit_euler::system::System;
    let (model, state) = pressed_cubes();
    let n = model.len();
    let mut rng = Rng::new(12);
    let p: Vec<DVec3> = (0..n).map(|_| rng.vec(1.0).as_vec3().as_dvec3()).collect();
    let mut g = open(gpu, &model, &state)?;
    let (gb, gdiag, gap) = g.debug_implicit_system(&p).map_err(step_error)?;
    let gpu_pairs = g.debug_contact_pairs().map_err(step_error)?;

    let mut contact = BodyContact::new();
    contact.prepare(&model, &state);
    let mut sys = System::new(&model);
    let mut b = vec![DVec3::ZERO; n];
    sys.assemble(
        &model,
        (Some(contact.partners()), None),
        &state.x,
        &state.v,
        &mut b,
    );
    let mut ap = vec![DVec3::ZERO; n];
    sys.apply(&model, &p, &mut ap);

    let cpu_pairs = contact.partners().pairs().to_vec();
    let (pairs, near) = agreeing_pairs(&model, &state.x, &gpu_pairs, &cpu_pairs)?;
    let mut doubtful = doubtful(&model, &state.x, &pairs, &near);
    let sim = &model.simulation;
    let (h, kappa) = (sim.dt, softbody_scene::model::penalty(sim.integrator));
    let blocks = sys.pairs.as_ref().ok_or("the CPU's system has no pairs")?;
    let mut b_scale = rhs_scale(&model, &state.x, &state.v);
    let mut ap_scale = product_scale(&model, &p);
    let (mut pushing, mut pulling) = (0, 0);
    for (k, &[i, j]) in blocks.ends.iter().enumerate() {
        let (i, j) = (i as usize, j as usize);
        let Some((stiffness, damping)) = penalty_coefficients(&model, kappa, h, i, j) else {
            continue;
        };
        let r = reach(&model, [i as u32, j as u32]);
        let offset = state.x[i] - state.x[j];
        let u = state.v[i] - state.v[j];
        let force = stiffness * (r - offset.length()) - damping * u.dot(offset.normalize());
        let scale = stiffness * r + damping * u.length();
        if force.abs() <= 1e-4 * scale {
            doubtful.extend([i as u32, j as u32]);
        }
        if blocks.beta[k] > 0.0 {
            pushing += 1;
        } else {
            pulling += 1;
        }
        for (a, other) in [(i, j), (j, i)] {
            b_scale[a] += h * (scale + h * stiffness * u.length());
            ap_scale[a] += blocks.beta[k] * (p[a].length() + p[other].length());
        }
    }
    let tolerance = Backend::gpu(gpu.clone()).tolerance();
    let (mut worst_b, mut worst_ap, mut worst_inv, mut failures) =
        (0.0f64, 0.0f64, 0.0f64, Vec::new());
    for i in 0..n {
        let eb = (gb[i].as_dvec3() - b[i]).length();
        let eap = (gap[i].as_dvec3() - ap[i]).length();
        let inv = inverse_block(gdiag[i]);
        let want = sys.inv_diag[i].to_cols_array();
        let largest = want.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        let einv = (inv - sys.inv_diag[i])
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, x| a.max(x.abs()));
        worst_b = worst_b.max(eb / b_scale[i]);
        worst_ap = worst_ap.max(eap / ap_scale[i]);
        worst_inv = worst_inv.max(einv / largest);
        if !tolerance.allows(eb, b_scale[i])
            || !tolerance.allows(eap, ap_scale[i])
            || !tolerance.allows(einv, largest)
        {
            failures.push(format!(
                "particle {i}: b GPU {} CPU {} (scale {:e}), A p GPU {} CPU {} (scale {:e}), \
                 inverse block error {einv:e} of {largest:e}",
                gb[i], b[i], b_scale[i], gap[i], ap[i], ap_scale[i]
            ));
        }
    }
    println!(
        "{n} particles, {} pairs in contact ({pushing} pushing, {pulling} pulling: left out); \
         largest errors of the scales: b {worst_b:.2e}, A p {worst_ap:.2e}, inverse blocks \
         {worst_inv:.2e} (bound {:e})",
        pairs.len(),
        tolerance.rel
    );
    if !doubtful.is_empty() {
        failures.push(format!(
            "particles {doubtful:?} have a pair within rounding of R or of F = 0: move the scene"
        ));
    }
    if pushing < 20 || pulling == 0 {
        failures.push(format!(
            "{pushing} pairs push and {pulling} pull: the system's pairs are not exercised"
        ));
    }
    all(failures)
}

/// The meeting, 300 RK4 steps: twice on 1-D grids and on grids one and two workgroups wide, the
/// same states and energies bit for bit.
fn same_bits(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = Model::build(&meeting(Integrator::Rk4));
    let mut runs = Vec::new();
    for width in [None, None, Some(1), Some(2)] {
        let options = GpuOptions {
            grid_width: width,
            ..Default::default()
        };
        let mut g = GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
            .map_err(|e| e.to_string())?;
        g.advance(300).map_err(step_error)?;
        let energies = g.energies().map_err(step_error)?;
        let pairs = g.debug_contact_pairs().map_err(step_error)?.len();
        runs.push((g.state().map_err(step_error)?.clone(), energies, pairs));
    }
    println!(
        "{} particles; {} pairs in contact at the end; energies {:?}",
        model.len(),
        runs[0].2,
        runs[0].1
    );
    ensure(runs[0].2 > 10, || {
        format!(
            "only {} pairs in contact: the bodies did not meet",
            runs[0].2
        )
    })?;
    ensure(runs.iter().all(|r| *r == runs[0]), || {
        "the runs (twice 1-D, then 2-D grids) give different bits".to_owned()
    })
}
