//! Build a scene in code, without a file: a pendulum of three particles hanging from a pinned
//! one, swinging under gravity, stepped with RK4.
//!
//! `cargo run --release --example build_in_code`

use softbody::scene::{Body, BodyShape, ExplicitSpring, ParticleSet, Simulation};
use softbody::{Backend, Integrator, Scene};

use glam::DVec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let positions: Vec<DVec3> = (0..4)
        .map(|i| DVec3::new(0.5 * i as f64, 2.0, 0.0))
        .collect();
    let springs = (0..3)
        .map(|i| ExplicitSpring {
            a: i,
            b: i + 1,
            stiffness: 500.0,
            damping: 0.5,
            rest: None, // the initial distance
        })
        .collect();
    let scene = Scene {
        simulation: Simulation {
            integrator: Integrator::Rk4,
            dt: 1e-3,
            duration: 2.0,
            frame_rate: 30.0,
            gravity: DVec3::new(0.0, -9.81, 0.0),
            drag: 0.0,
            contact_distance: 1e-3,
            body_contact: Default::default(),
            preconditioner: Default::default(),
            cg_tolerance: softbody::scene::implicit::CG_TOLERANCE,
        },
        bodies: vec![Body {
            name: "pendulum".into(),
            shape: BodyShape::Particles(ParticleSet {
                velocities: vec![DVec3::ZERO; positions.len()],
                masses: vec![0.1; positions.len()],
                positions,
                springs,
            }),
            pinned: vec![0],
            contact_radius: None,
            self_contact: false,
        }],
        terrain: Vec::new(),
    };
    // The same checks a scene file gets; the error names the key a file would use.
    scene
        .validate()
        .map_err(|e| format!("{}: {}", e.key, e.message))?;

    let mut solver = softbody::open(&scene, Backend::Cpu, Some(1))?;
    solver.advance(scene.simulation.steps())?;
    let state = solver.state()?;
    assert_eq!(
        state.x[0],
        DVec3::new(0.0, 2.0, 0.0),
        "the pinned particle never moves"
    );
    let tip = state.x[3];
    println!(
        "after {} s the tip is at ({:.3}, {:.3}, {:.3})",
        scene.simulation.duration, tip.x, tip.y, tip.z
    );
    Ok(())
}
