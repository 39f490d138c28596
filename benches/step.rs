//! One step of the standard benchmark cube (`softbody::benchmark`) at 10³, 22³ and 46³
//! particles: symplectic Euler at half its largest stable step, and implicit Euler at
//! dt = 1/60 s (its point: a step the explicit methods cannot take), all cores. And one step of
//! the multi-body pile (`benchmark::pile`: 27 cubes of 6³ and of 10³ touching in a bowl), timed
//! once the cubes have landed on each other (0.1 s simulated first), on the CPU and, where an
//! adapter opens, on the GPU (`gpu n^3`: 64 steps per iteration, one submission, as a run
//! submits them). And one step of a mesh body (`mesh body/torus 8 mm`: `scenes/torus.obj` at
//! 8 mm cells, 62,168 particles, falling) on the CPU's lattice stencil and, for comparison,
//! through its spring list (the sweep that stepped mesh bodies before the stencil took them).
//!
//! `cargo bench --bench step`; the figures are recorded in BENCHMARKS.md.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use softbody::benchmark::{STIFFNESS, cube, dt_max_symplectic};
use softbody::scene::{Model, Solver};
use softbody::{Backend, CpuSolver, Integrator};

fn step(c: &mut Criterion) {
    for (integrator, sizes) in [
        (Integrator::SymplecticEuler, [10u32, 22, 46]),
        (Integrator::ImplicitEuler, [10, 22, 46]),
    ] {
        let mut group = c.benchmark_group(format!("step/{integrator}"));
        group.sample_size(10);
        for n in sizes {
            let dt = match integrator {
                Integrator::ImplicitEuler => 1.0 / 60.0,
                _ => 0.5 * dt_max_symplectic(n),
            };
            let scene = cube(n, STIFFNESS, integrator, dt);
            let mut solver = softbody::open(&scene, Backend::Cpu, None).expect("CPU solver");
            // Warm up past the first steps (allocation, the implicit warm start) before timing.
            solver.advance(3).expect("stable");
            group.throughput(Throughput::Elements((n as u64).pow(3)));
            group.bench_function(BenchmarkId::from_parameter(format!("{n}^3")), |b| {
                b.iter(|| solver.advance(1).expect("stable"))
            });
            let stats = solver.statistics();
            eprintln!(
                "  {n}^3 {integrator}, where the time went:\n{}",
                stats.timings
            );
            if stats.cg_solves > 0 {
                eprintln!(
                    "  {n}^3 implicit: {:.1} CG iterations per solve, {:.2} solves per step, worst relative residual {:.1e}",
                    stats.cg_iterations as f64 / stats.cg_solves as f64,
                    stats.cg_solves as f64 / stats.steps as f64,
                    stats.cg_max_residual
                );
            }
        }
        group.finish();
    }
}

fn pile(c: &mut Criterion) {
    let mut group = c.benchmark_group("pile/27 cubes");
    group.sample_size(10);
    for (backend, prefix, steps) in [(Backend::Cpu, "", 1u64), (Backend::Gpu, "gpu ", 64)] {
        for n in [6u32, 10] {
            let scene = softbody::benchmark::pile(n);
            let mut solver = match softbody::open(&scene, backend, None) {
                Ok(solver) => solver,
                Err(e) => {
                    eprintln!(
                        "  27 cubes of {n}^3 on the {}: skipped: {e}",
                        backend.name()
                    );
                    continue;
                }
            };
            let landed = (0.1 / scene.simulation.dt).round() as u64;
            group.throughput(Throughput::Elements(27 * (n as u64).pow(3) * steps));
            group.bench_function(BenchmarkId::from_parameter(format!("{prefix}{n}^3")), |b| {
                // Landed here, only for the sizes the filter selects: on a software adapter the
                // landing of the 10³ pile alone takes minutes.
                if solver.steps_taken() == 0 {
                    solver.advance(landed).expect("stable");
                }
                // The GPU's advance only submits: the clock stops when its steps are done.
                b.iter(|| {
                    solver.advance(steps).expect("stable");
                    solver.sync().expect("stable");
                })
            });
            let stats = solver.statistics();
            if stats.steps == 0 {
                continue;
            }
            eprintln!(
                "  27 cubes of {n}^3 on {} at dt = {:e} s, where the time went:\n{}",
                solver.device(),
                scene.simulation.dt,
                stats.timings
            );
        }
    }
    group.finish();
}

fn mesh_body(c: &mut Criterion) {
    let mut group = c.benchmark_group("mesh body/torus 8 mm");
    group.sample_size(10);
    let text = "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 5e-6\nduration = 1.0\n\
                [[body]]\nname = \"torus\"\nkind = \"mesh\"\nfile = \"torus.obj\"\n\
                cell = 0.008\ncenter = [0.0, 2.0, 0.0]\ndensity = 1000.0\n\
                structural = { stiffness = 640.0, damping = 6.4 }\n\
                shear = { stiffness = 640.0, damping = 6.4 }\n\
                bending = { stiffness = 640.0, damping = 6.4 }\n\
                [[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n";
    let at = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/bench.toml");
    let scene = softbody::scene::Scene::from_toml(text, at.as_ref()).expect("valid scene");
    let (model, state) = Model::build(&scene);
    let mut listed = model.clone();
    listed.springs_mut();
    for (name, model) in [("stencil", model), ("spring list", listed)] {
        let n = model.len() as u64;
        let mut solver = CpuSolver::new(model, state.clone(), None).expect("CPU solver");
        solver.advance(3).expect("stable");
        eprintln!(
            "  torus 8 mm, {name}: kernel {}",
            solver.statistics().kernel
        );
        group.throughput(Throughput::Elements(n));
        group.bench_function(BenchmarkId::from_parameter(name), |b| {
            b.iter(|| solver.advance(1).expect("stable"))
        });
    }
    group.finish();
}

criterion_group!(benches, step, pile, mesh_body);
criterion_main!(benches);
