//! Load a scene file, step it, and read positions and energies.
//!
//! `cargo run --release --example step_a_scene [SCENE]` (default: scenes/jelly-on-ground.toml).

use softbody::{Backend, Scene};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "scenes/jelly-on-ground.toml".into());
    let scene = Scene::from_file(&path)?;
    let mut solver = softbody::open(&scene, Backend::Cpu, None)?;
    let steps_per_frame =
        (1.0 / (scene.simulation.frame_rate * scene.simulation.dt)).round() as u64;
    for frame in 0..=10 {
        if frame > 0 {
            solver.advance(steps_per_frame)?;
        }
        let e = solver.energies()?;
        let lowest = solver
            .state()?
            .x
            .iter()
            .map(|x| x.y)
            .fold(f64::INFINITY, f64::min);
        println!(
            "t = {:.3} s: lowest particle at y = {lowest:.4} m, energy {:.4} J (kinetic {:.4} J)",
            solver.steps_taken() as f64 * scene.simulation.dt,
            e.total(),
            e.kinetic
        );
    }
    Ok(())
}
