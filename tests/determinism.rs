//! Bitwise determinism, on every backend: the CPU gives the same bits for 1, 2 and 3 threads,
//! the GPU the same bits run after run, for every integrator, contacts included; and a solver
//! restored from another's state and history (what `softbody run --resume` does) goes on with
//! the bits the other would have had.

use std::process::ExitCode;
use std::sync::Arc;

use glam::DVec3;
use softbody::scene::SpringParams;
use softbody::{CpuSolver, Integrator, Model, Scene, Solver, State};
use softbody_testkit::scenes::*;
use softbody_testkit::{Backend, Failed, Kind, Law, ensure};

fn main() -> ExitCode {
    softbody_testkit::run(
        "determinism",
        [
            Law::per_integrator("runs_repeat_bit_for_bit", runs_repeat_bit_for_bit),
            Law::per_integrator(
                "a_restored_solver_goes_on_bit_for_bit",
                a_restored_solver_goes_on_bit_for_bit,
            ),
        ],
    )
}

/// A slightly tilted 12×12×12 cuboid (1728 particles, ~20 000 springs: more than one rayon task of
/// particles (1024) and of springs (4096), more than one reduction chunk (8192) and several GPU
/// workgroups, so the work really is split) falling onto a plane with friction and restitution;
/// its lowest corner starts 2 mm above the plane at 1 m/s down, so contacts begin within the
/// first steps.
fn scene(integrator: Integrator) -> Scene {
    let params = SpringParams {
        stiffness: 100.0,
        damping: 0.05,
    };
    let mut cube = cuboid(DVec3::splat(0.5), [12, 12, 12], DVec3::ZERO, 1.0, params);
    cube.rotation = DVec3::new(3.0, 20.0, 2.0);
    cube.velocity = DVec3::new(0.2, -1.0, 0.1);
    let lowest = softbody::scene::topology::cuboid_positions(&cube)
        .iter()
        .map(|x| x.y)
        .fold(f64::INFINITY, f64::min);
    cube.center.y = 0.002 - lowest;
    softbody_testkit::scenes::scene(
        simulation(integrator, 2e-4),
        vec![cuboid_body(cube)],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.3, 0.4)],
    )
}

/// The state and the energies' bits after `steps` steps of `solver`.
fn run(mut solver: Box<dyn Solver>, steps: u64) -> Result<(State, [u64; 3]), Failed> {
    solver.advance(steps).map_err(|e| e.to_string())?;
    let e = solver.energies().map_err(|e| e.to_string())?;
    let energies = [e.kinetic, e.gravitational, e.elastic].map(f64::to_bits);
    Ok((solver.state().map_err(|e| e.to_string())?.clone(), energies))
}

fn bits(s: &State) -> Vec<u64> {
    s.x.iter()
        .chain(&s.v)
        .flat_map(|p| p.to_array())
        .map(f64::to_bits)
        .collect()
}

/// Each integrator's run, repeated in every configuration the backend has (CPU: pools of 1, 2
/// and 3 threads; GPU: two solvers on the same device), gives the same bits.
fn runs_repeat_bit_for_bit(backend: &Backend, integrator: Integrator) -> Result<(), Failed> {
    let steps = 60;
    let (model, state) = Model::build(&scene(integrator));
    ensure(model.len() > 1024 && model.springs().len() > 8192, || {
        "the cube is too small to split the work".into()
    })?;
    let configurations: Vec<(String, Box<dyn Solver>)> = match backend.kind() {
        Kind::Cpu => [1, 2, 3]
            .into_iter()
            .map(|threads| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("a thread pool");
                let solver = CpuSolver::in_pool(model.clone(), state.clone(), Arc::new(pool));
                (
                    format!("{threads} thread{}", if threads == 1 { "" } else { "s" }),
                    Box::new(solver) as Box<dyn Solver>,
                )
            })
            .collect(),
        Kind::Gpu => vec![
            (
                "run 1".into(),
                backend.solver_from(model.clone(), state.clone())?,
            ),
            (
                "run 2".into(),
                backend.solver_from(model.clone(), state.clone())?,
            ),
        ],
    };
    let mut runs = Vec::new();
    for (name, solver) in configurations {
        runs.push((name, run(solver, steps)?));
    }
    let (first, (one, e1)) = &runs[0];
    // The run did something: contacts happened and the body moved.
    let touching = one.x.iter().filter(|x| x.y < 1e-3).count();
    ensure(touching > 0, || {
        format!("{integrator}: no particle reached the plane")
    })?;
    ensure(one.x.iter().all(|x| x.is_finite()), || {
        format!("{integrator}: not finite")
    })?;
    let reference = bits(one);
    for (name, (other, e)) in &runs[1..] {
        let differ = reference
            .iter()
            .zip(bits(other))
            .filter(|(a, b)| **a != *b)
            .count();
        ensure(differ == 0, || {
            format!(
                "{integrator}: {differ} of {} coordinates differ between {first} and {name}",
                reference.len()
            )
        })?;
        ensure(e1 == e, || {
            format!("{integrator}: energies differ between {first} and {name}")
        })?;
    }
    let names: Vec<&str> = runs.iter().map(|(n, _)| n.as_str()).collect();
    println!("{integrator}: {touching} particles near the plane, identical in {names:?}");
    Ok(())
}

/// Each integrator's run of 60 steps, split in two: a solver that took the first 30 gives its
/// state and history to a fresh one ([`Solver::restore`]), which takes the other 30 and ends
/// with the uninterrupted run's bits. The split falls after the contacts began, so implicit
/// Euler's history (warm start, who touches and sticks) is not empty.
fn a_restored_solver_goes_on_bit_for_bit(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let (steps, split) = (60, 30);
    let (model, state) = Model::build(&scene(integrator));
    let fresh = || backend.solver_from(model.clone(), state.clone());
    let (reference, e_reference) = run(fresh()?, steps)?;
    let mut first = fresh()?;
    first.advance(split).map_err(|e| e.to_string())?;
    let history = first.history().map_err(|e| e.to_string())?;
    let halfway = first.state().map_err(|e| e.to_string())?.clone();
    ensure(halfway.x.iter().any(|x| x.y < 1e-3), || {
        format!("{integrator}: no contact before the split")
    })?;
    let mut second = fresh()?;
    second
        .restore(split, &halfway, &history)
        .map_err(|e| e.to_string())?;
    ensure(second.steps_taken() == split, || {
        format!("{integrator}: restored at step {}", second.steps_taken())
    })?;
    let (resumed, e_resumed) = run(second, steps - split)?;
    let differ = bits(&reference)
        .iter()
        .zip(bits(&resumed))
        .filter(|(a, b)| **a != *b)
        .count();
    ensure(differ == 0 && e_reference == e_resumed, || {
        format!("{integrator}: {differ} coordinates (or the energies) differ after the restore")
    })?;
    let parts: Vec<&str> = history.parts.iter().map(|(n, _)| n.as_str()).collect();
    // A multigrid's values at the split are rebuilt by the restore from the positions and
    // constraints they were computed for (the CPU's implicit Euler on this cuboid).
    let kept = history.parts.iter().find(|(n, _)| n == "multigrid-kept");
    let kept = kept.map(|(_, b)| u32::from_le_bytes(b[..].try_into().unwrap()));
    ensure(kept.is_none_or(|k| k != u32::MAX), || {
        format!("{integrator}: the multigrid had no values at the split")
    })?;
    println!(
        "{integrator}: restored at step {split} with history {parts:?} (multigrid values \
         kept by {kept:?} assemblies), identical at {steps}"
    );
    Ok(())
}
