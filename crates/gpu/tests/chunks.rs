//! Per-spring arrays split across storage bindings ("spring chunks", see `softbody_gpu::solver`),
//! on small scenes: [`GpuOptions::max_binding_size`] caps the bindings at 64 KiB, which splits
//! the 6,220 springs of an 8×8×8 cube into 4 chunks of 2,048 (the last 76), with chunk
//! boundaries inside particles' spring runs. Chunking changes where the gathers read a
//! per-spring value, not what they add or in which order, so every integrator's run is
//! bit-identical to the unchunked run on the same adapter.

mod common;

use std::process::ExitCode;
use std::sync::Arc;

use common::{BOUNCY_PLANE, SLOPE, step_error};

use softbody_gpu::{Gpu, GpuOptions, GpuSolver};
use softbody_scene::{Energies, Integrator, Model, Scene, Solver, State};
use softbody_testkit::{Failed, GpuTest};

fn main() -> ExitCode {
    let tests: &[(&str, GpuTest)] = &[
        ("chunked_explicit_euler_is_bit_identical", |gpu| {
            chunked_run(gpu, Integrator::ExplicitEuler, 150)
        }),
        ("chunked_symplectic_euler_is_bit_identical", |gpu| {
            chunked_run(gpu, Integrator::SymplecticEuler, 150)
        }),
        ("chunked_midpoint_is_bit_identical", |gpu| {
            chunked_run(gpu, Integrator::Midpoint, 120)
        }),
        ("chunked_rk4_is_bit_identical", |gpu| {
            chunked_run(gpu, Integrator::Rk4, 100)
        }),
        ("chunked_implicit_euler_is_bit_identical", chunked_implicit),
        (
            "chunked_spring_forces_read_back_whole",
            chunked_spring_forces,
        ),
        (
            "chunks_on_two_dimensional_grids_give_the_same_bits",
            chunked_two_dimensional,
        ),
        ("a_binding_too_small_is_refused_with_the_figures", too_small),
        (
            "the_stencil_runs_a_cube_whose_adjacency_exceeds_a_binding",
            stencil_past_the_adjacency,
        ),
    ];
    softbody_testkit::run_gpu("GPU chunk tests", tests.iter().copied())
}

/// Bindings of 64 KiB: 2,048 springs per chunk (20-byte records, 32-byte implicit blocks), and
/// every whole buffer of the 8×8×8 cube still fits (the adjacency, the largest, is 51 KB).
const CAP: u64 = 64 * 1024;

/// An 8×8×8 cube of 30 cm (512 particles, 6,220 springs of all three families), tilted, its
/// lowest corner 7 mm into `terrain` (contacts act from the first step), thrown down at 2 m/s.
fn cube(integrator: Integrator, dt: f64, terrain: &str) -> (Model, State) {
    let text = format!(
        r#"
[simulation]
integrator = "{integrator}"
dt = {dt:e}
duration = 0.1
frame_rate = 20.0
gravity = [0.0, -9.81, 0.0]
drag = 0.1

[[body]]
name = "cube"
kind = "cuboid"
size = [0.3, 0.3, 0.3]
resolution = [8, 8, 8]
center = [0.0, 0.2, 0.0]
rotation = [10.0, 0.0, 15.0]
velocity = [0.5, -2.0, 0.0]
mass = 1.0
structural = {{ stiffness = 400.0, damping = 1.0 }}
shear = {{ stiffness = 400.0, damping = 1.0 }}
bending = {{ stiffness = 200.0, damping = 0.5 }}
{terrain}
"#
    );
    let scene = Scene::from_toml(&text, "test.toml".as_ref()).expect("test scene is valid");
    Model::build(&scene)
}

fn open(
    gpu: &Arc<Gpu>,
    model: &Model,
    state: &State,
    options: GpuOptions,
) -> Result<GpuSolver, Failed> {
    GpuSolver::with_options(gpu, model.clone(), state.clone(), options)
        .map_err(|e| e.to_string().into())
}

/// The springs as a list on the device, which is what is chunked: the explicit integrators
/// through the fused gather (a cuboid's would otherwise take the stencil route, which holds no
/// per-spring array); implicit Euler always has the list.
fn listed() -> GpuOptions {
    GpuOptions {
        gather: true,
        ..GpuOptions::default()
    }
}

fn capped() -> GpuOptions {
    GpuOptions {
        max_binding_size: Some(CAP),
        ..listed()
    }
}

/// Checks that the solver split the springs into at least 3 chunks, each boundary inside some
/// particle's spring run (so that one particle's gather reads two chunks), and says how.
fn check_split(g: &GpuSolver, model: &Model) -> Result<(), Failed> {
    let chunks = g.spring_chunks().to_vec();
    println!("{} springs in chunks {chunks:?}", model.springs().len());
    if chunks.len() < 3 {
        return Err(format!("expected 3+ chunks, got {chunks:?}").into());
    }
    let adj = model.adjacency();
    for &(base, _) in &chunks[1..] {
        let straddles = (0..model.len()).any(|i| {
            let run = &adj.entries[adj.offsets[i] as usize..adj.offsets[i + 1] as usize];
            let below = run.iter().any(|&e| u64::from(e >> 1) < base);
            let above = run.iter().any(|&e| u64::from(e >> 1) >= base);
            below && above
        });
        if !straddles {
            return Err(format!("no spring run straddles the chunk boundary {base}").into());
        }
    }
    Ok(())
}

/// `steps` steps, then the state and the energies.
fn run(g: &mut GpuSolver, steps: u64) -> Result<(State, Energies), Failed> {
    g.advance(steps).map_err(step_error)?;
    let e = g.energies().map_err(step_error)?;
    Ok((g.state().map_err(step_error)?.clone(), e))
}

fn same_bits(what: &str, a: &(State, Energies), b: &(State, Energies)) -> Result<(), Failed> {
    let bits = |s: &State| -> Vec<u64> {
        s.x.iter()
            .chain(&s.v)
            .flat_map(|p| p.to_array())
            .map(f64::to_bits)
            .collect()
    };
    let energies = |e: &Energies| [e.kinetic, e.gravitational, e.elastic].map(f64::to_bits);
    if bits(&a.0) != bits(&b.0) || energies(&a.1) != energies(&b.1) {
        let moved =
            a.0.x
                .iter()
                .zip(&b.0.x)
                .map(|(p, q)| p.distance(*q))
                .fold(0.0f64, f64::max);
        return Err(format!(
            "{what}: the chunked run differs (max position difference {moved:e}; energies {:?} \
             vs {:?})",
            a.1, b.1
        )
        .into());
    }
    Ok(())
}

/// An explicit integrator's run with and without chunks, on the bouncy plane (contacts and
/// collision response act within the steps).
fn chunked_run(gpu: &Arc<Gpu>, integrator: Integrator, steps: u64) -> Result<(), Failed> {
    let (model, state) = cube(integrator, 2e-4, BOUNCY_PLANE);
    let whole = run(&mut open(gpu, &model, &state, listed())?, steps)?;
    let mut g = open(gpu, &model, &state, capped())?;
    check_split(&g, &model)?;
    let chunked = run(&mut g, steps)?;
    let lowest = |s: &State| s.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
    let (before, after) = (lowest(&state), lowest(&chunked.0));
    println!(
        "{integrator}: {steps} steps, lowest particle from {before:.4} m to {after:.4} m, \
         energies {:?}",
        chunked.1
    );
    same_bits(&integrator.to_string(), &whole, &chunked)
}

/// Implicit Euler with and without chunks (blocks and per-spring vectors chunked; the
/// assembly's and the CG products' gathers read every chunk): the same steps, energies and CG
/// iteration counts, bit for bit.
fn chunked_implicit(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cube(Integrator::ImplicitEuler, 2e-3, SLOPE);
    let steps = 10;
    let mut results = Vec::new();
    for options in [listed(), capped()] {
        let mut g = open(gpu, &model, &state, options)?;
        if options.max_binding_size.is_some() {
            check_split(&g, &model)?;
        }
        let r = run(&mut g, steps)?;
        let stats = g.statistics();
        results.push((r, stats.cg_iterations, stats.cg_solves));
    }
    println!(
        "implicit-euler: {steps} steps, {} CG iterations in {} solves, energies {:?}",
        results[1].1, results[1].2, results[1].0.1
    );
    if (results[0].1, results[0].2) != (results[1].1, results[1].2) {
        return Err(format!(
            "CG counts differ: {:?} vs {:?}",
            (results[0].1, results[0].2),
            (results[1].1, results[1].2)
        )
        .into());
    }
    same_bits("implicit-euler", &results[0].0, &results[1].0)
}

/// The per-spring forces of every chunk, read back and concatenated, are the unchunked ones.
fn chunked_spring_forces(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cube(Integrator::SymplecticEuler, 5e-4, "");
    // The read-back is the per-spring kernels' output: only their route keeps it.
    let per_spring = |options: GpuOptions| GpuOptions {
        per_spring: true,
        ..options
    };
    let whole = open(gpu, &model, &state, per_spring(listed()))?
        .debug_spring_forces()
        .map_err(step_error)?;
    let chunked = open(gpu, &model, &state, per_spring(capped()))?
        .debug_spring_forces()
        .map_err(step_error)?;
    if chunked.len() != model.springs().len() || chunked != whole {
        return Err("chunked spring forces differ from the unchunked ones".into());
    }
    Ok(())
}

/// Chunks dispatched on 2-D grids (grids forced one workgroup wide: each chunk of 2,048 springs
/// is 1 × 8 workgroups, the last 1 × 1): the same bits as one chunk on 1-D grids.
fn chunked_two_dimensional(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cube(Integrator::SymplecticEuler, 2e-4, BOUNCY_PLANE);
    let whole = run(&mut open(gpu, &model, &state, listed())?, 40)?;
    let options = GpuOptions {
        grid_width: Some(1),
        ..capped()
    };
    let narrow = run(&mut open(gpu, &model, &state, options)?, 40)?;
    same_bits("2-D chunked", &whole, &narrow)
}

/// Bindings too small for a workgroup's springs: refused, naming the limit and the figures.
fn too_small(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cube(Integrator::SymplecticEuler, 5e-4, "");
    let options = GpuOptions {
        max_binding_size: Some(4096),
        ..listed()
    };
    let e = match GpuSolver::with_options(gpu, model, state, options) {
        Ok(_) => return Err("a 4 KiB binding was accepted".into()),
        Err(e) => e.to_string(),
    };
    println!("{e}");
    for part in [
        "max_storage_buffer_binding_size",
        "allows 4096 bytes",
        "--backend cpu",
    ] {
        if !e.contains(part) {
            return Err(format!("the refusal does not say `{part}`: {e}").into());
        }
    }
    Ok(())
}

/// The 300³ cube on a 2 GiB binding in miniature: with 16 KiB bindings the 8×8×8 cube's
/// per-particle arrays fit (8 KiB of positions) but its adjacency (51 KB) does not. The spring
/// list is refused naming the adjacency; the stencil route, which holds none, runs, with the
/// bits of the uncapped run.
fn stencil_past_the_adjacency(gpu: &Arc<Gpu>) -> Result<(), Failed> {
    let (model, state) = cube(Integrator::SymplecticEuler, 2e-4, BOUNCY_PLANE);
    let cap = GpuOptions {
        max_binding_size: Some(16 * 1024),
        ..GpuOptions::default()
    };
    let listed = GpuOptions {
        gather: true,
        ..cap
    };
    let e = match GpuSolver::with_options(gpu, model.clone(), state.clone(), listed) {
        Ok(_) => return Err("the spring list was accepted past a binding".into()),
        Err(e) => e.to_string(),
    };
    println!("{e}");
    // The gather binds more storage buffers than GL's 16 a stage: an adapter with fewer than it
    // needs refuses the route on that count first, which is as right a refusal.
    let storage = gpu.limits.max_storage_buffers_per_shader_stage;
    let adjacency = e.contains("the adjacency buffer") && e.contains("allows 16384 bytes");
    let buffers = e.contains("storage buffers") && e.contains(&format!("allows {storage}"));
    if !adjacency && !buffers {
        return Err(format!(
            "the refusal names neither the adjacency nor the adapter's {storage} storage \
             buffers a stage: {e}"
        )
        .into());
    }
    let mut g = open(gpu, &model, &state, cap)?;
    if g.statistics().kernel != "fused stencil" {
        return Err(format!("capped: kernel {}", g.statistics().kernel).into());
    }
    let capped = run(&mut g, 150)?;
    let whole = run(&mut open(gpu, &model, &state, GpuOptions::default())?, 150)?;
    same_bits("the capped stencil", &whole, &capped)
}
