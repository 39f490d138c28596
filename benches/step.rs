//! One step of the standard benchmark cube (`softbody::benchmark`) at 10³, 22³ and 46³
//! particles: symplectic Euler at half its largest stable step, and implicit Euler at
//! dt = 1/60 s (its point: a step the explicit methods cannot take), all cores. And one step of
//! the multi-body pile (`benchmark::pile`: 27 cubes of 6³ and of 10³ touching in a bowl), timed
//! once the cubes have landed on each other (0.1 s simulated first), on the CPU and, where an
//! adapter opens, on the GPU (`gpu n^3`: 64 steps per iteration, one submission, as a run
//! submits them).
//!
//! `cargo bench --bench step`; the figures are recorded in BENCHMARKS.md.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use softbody::benchmark::{STIFFNESS, cube, dt_max_symplectic};
use softbody::{Backend, Integrator};

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
                b.iter(|| solver.advance(steps).expect("stable"))
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

criterion_group!(benches, step, pile);
criterion_main!(benches);
