//! Many runs of one scene, sharing resources: variants of a scene (here, four stiffnesses)
//! stepped on one GPU device when an adapter is there, and in one CPU thread pool either way.
//! Opening a device costs far more than a small run; a batch opens it once.
//!
//! `cargo run --release --example batch [SCENE]` (default: scenes/jelly-on-ground.toml).

use std::sync::Arc;

use softbody::gpu::Gpu;
use softbody::scene::BodyShape;
use softbody::{CpuSolver, GpuSolver, Model, Scene, Solver};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "scenes/jelly-on-ground.toml".into());
    let mut scene = Scene::from_file(&path)?;
    scene.simulation.duration = 0.5;
    let variants: Vec<Scene> = [500.0, 1000.0, 2000.0, 4000.0]
        .into_iter()
        .map(|stiffness| {
            let mut s = scene.clone();
            for body in &mut s.bodies {
                if let BodyShape::Cuboid(c) = &mut body.shape {
                    let families = [&mut c.structural, &mut c.shear, &mut c.bending];
                    for p in families.into_iter().flatten() {
                        p.stiffness = stiffness;
                    }
                }
            }
            s
        })
        .collect();

    // The CPU: every solver steps in the same pool of two threads.
    let pool = Arc::new(rayon::ThreadPoolBuilder::new().num_threads(2).build()?);
    let mut cpu: Vec<Box<dyn Solver>> = Vec::new();
    for s in &variants {
        s.validate()?;
        let (model, state) = Model::build(s);
        cpu.push(Box::new(CpuSolver::in_pool(model, state, pool.clone())));
    }
    report("cpu", &mut cpu, scene.simulation.steps())?;

    // The GPU: one device for the whole batch.
    match Gpu::open() {
        Ok(gpu) => {
            let mut solvers: Vec<Box<dyn Solver>> = Vec::new();
            for s in &variants {
                let (model, state) = Model::build(s);
                solvers.push(Box::new(GpuSolver::on(&gpu, model, state)?));
            }
            report("gpu", &mut solvers, scene.simulation.steps())?;
        }
        Err(e) => eprintln!("no GPU batch: {e}"),
    }
    Ok(())
}

/// Advances every solver of the batch, then prints each one's lowest point and energy. The GPU
/// solvers queue their steps on the shared device; `sync` waits for each.
fn report(
    backend: &str,
    solvers: &mut [Box<dyn Solver>],
    steps: u64,
) -> Result<(), Box<dyn std::error::Error>> {
    for solver in solvers.iter_mut() {
        solver.advance(steps)?;
    }
    for solver in solvers.iter_mut() {
        solver.sync()?;
        let k = solver.model().springs().stiffness[0];
        let lowest = solver
            .state()?
            .x
            .iter()
            .map(|x| x.y)
            .fold(f64::INFINITY, f64::min);
        let e = solver.energies()?;
        println!(
            "{backend} k_s = {k:>6} N/m: {} steps, lowest point {lowest:.4} m, elastic energy {:.4} J, {} KiB",
            solver.steps_taken(),
            e.elastic,
            solver.memory_bytes() / 1024
        );
    }
    Ok(())
}
