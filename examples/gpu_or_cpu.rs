//! Run a scene on the GPU when an adapter is there, and on the CPU otherwise: the stepping API
//! is the same for both.
//!
//! `cargo run --release --example gpu_or_cpu [SCENE]` (default: scenes/jelly-on-ground.toml).

use softbody::{Backend, OpenError, Scene, Solver};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "scenes/jelly-on-ground.toml".into());
    let mut scene = Scene::from_file(&path)?;
    scene.simulation.duration = 0.5;
    let mut solver: Box<dyn Solver> = match softbody::open(&scene, Backend::Gpu, None) {
        Ok(solver) => solver,
        Err(OpenError::Gpu(e)) => {
            eprintln!("no GPU run ({e}); using the CPU");
            softbody::open(&scene, Backend::Cpu, None)?
        }
        Err(e) => return Err(e.into()),
    };
    solver.advance(scene.simulation.steps())?;
    let e = solver.energies()?;
    println!(
        "{} on {}: {} steps, total energy {:.4} J",
        solver.backend(),
        solver.device(),
        solver.steps_taken(),
        e.total()
    );
    Ok(())
}
