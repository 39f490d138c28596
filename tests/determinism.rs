//! Bitwise determinism across thread counts: the same scene stepped on 1, 2 and 3 threads gives
//! the same bits, for every integrator, contacts included.

mod common;

use common::*;
use glam::DVec3;
use softbody::scene::SpringParams;
use softbody::{Integrator, Model, Scene, Solver, State};

/// A slightly tilted 12×12×12 cuboid (1728 particles, ~20 000 springs: more than one rayon task of
/// particles (1024) and of springs (4096) and more than one reduction chunk (8192), so the work
/// really is split differently per thread count) falling onto a plane with friction and
/// restitution; its lowest corner starts 2 mm above the plane at 1 m/s down, so contacts begin
/// within the first steps.
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
    common::scene(
        simulation(integrator, 2e-4),
        vec![cuboid_body(cube)],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.3, 0.4)],
    )
}

fn run(model: &Model, state: &State, threads: usize, steps: u64) -> (State, [u64; 3]) {
    let mut solver = solver_from(model.clone(), state.clone(), threads);
    solver.advance(steps).unwrap();
    let e = solver.energies().unwrap();
    let energies = [e.kinetic, e.gravitational, e.elastic].map(f64::to_bits);
    (solver.state().unwrap().clone(), energies)
}

fn bits(s: &State) -> Vec<u64> {
    s.x.iter()
        .chain(&s.v)
        .flat_map(|p| p.to_array())
        .map(f64::to_bits)
        .collect()
}

#[test]
fn thread_count_does_not_change_a_single_bit() {
    let steps = 60;
    for integrator in Integrator::ALL {
        let (model, state) = Model::build(&scene(integrator));
        assert!(model.len() > 1024 && model.springs.len() > 8192);
        let (one, e1) = run(&model, &state, 1, steps);
        // The run did something: contacts happened and the body moved.
        let touching = one.x.iter().filter(|x| x.y < 1e-3).count();
        assert!(touching > 0, "{integrator}: no particle reached the plane");
        assert!(one.x.iter().all(|x| x.is_finite()));
        let reference = bits(&one);
        for threads in [2, 3] {
            let (other, e) = run(&model, &state, threads, steps);
            let differ = reference
                .iter()
                .zip(bits(&other))
                .filter(|(a, b)| **a != *b)
                .count();
            assert_eq!(
                differ,
                0,
                "{integrator}: {differ} of {} coordinates differ between 1 and {threads} threads",
                reference.len()
            );
            assert_eq!(e1, e, "{integrator}: energies differ on {threads} threads");
        }
        println!("{integrator}: {touching} particles near the plane, identical on 1, 2, 3 threads");
    }
}
