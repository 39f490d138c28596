//! The stages of a CPU step, one by one, on the standard benchmark cube (`softbody::benchmark`),
//! all cores: the spring pass and the per-particle gather, the contact forces, one step of each
//! integrator, one conjugate-gradient solve of implicit Euler, and the parts of implicit Euler's
//! step on the stiff cube (assembly, a product A p, the multigrid's values and one application).
//! Regressions in one stage show here even when the whole step hides them.
//!
//! `cargo bench --bench stages`; `cargo bench --bench stages -- spring` for one group.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use glam::DVec3;
use softbody::benchmark::{STIFFNESS, cube, dt_max_symplectic};
use softbody::cpu::contact::contact_force;
use softbody::cpu::integrators::implicit_euler::cg::{self, Constraint, Scratch};
use softbody::cpu::integrators::implicit_euler::multigrid::Multigrid;
use softbody::cpu::integrators::implicit_euler::system::System;
use softbody::cpu::spring_forces::{self, Kernel};
use softbody::terrain::Surface;
use softbody::{Backend, Integrator, Model, State};

fn model(n: u32, integrator: Integrator, dt: f64) -> (Model, State) {
    Model::build(&cube(n, STIFFNESS, integrator, dt))
}

/// A state a few hundred steps into the fall, so that the springs are not all at rest.
fn moving(n: u32) -> (Model, State) {
    let dt = 0.5 * dt_max_symplectic(n);
    let scene = cube(n, STIFFNESS, Integrator::SymplecticEuler, dt);
    let mut solver = softbody::open(&scene, Backend::Cpu, None).expect("CPU solver");
    solver.advance(200).expect("stable");
    let state = solver.state().expect("state").clone();
    (Model::build(&scene).0, state)
}

fn springs(c: &mut Criterion) {
    let mut group = c.benchmark_group("spring_forces");
    group.sample_size(20);
    for n in [10u32, 22, 46] {
        let (model, state) = moving(n);
        let kernel = Kernel::new(model.springs());
        let mut out = vec![DVec3::ZERO; model.springs().len()];
        group.throughput(Throughput::Elements(model.springs().len() as u64));
        group.bench_function(BenchmarkId::new("compute", format!("{n}^3")), |b| {
            b.iter(|| kernel.compute(model.springs(), &state.x, &state.v, &mut out))
        });
        let mut sums = vec![DVec3::ZERO; model.len()];
        group.throughput(Throughput::Elements(model.len() as u64));
        group.bench_function(BenchmarkId::new("gather", format!("{n}^3")), |b| {
            b.iter(|| {
                for (k, s) in sums.chunks_mut(64).enumerate() {
                    spring_forces::gather_block(model.adjacency(), &out[..], 64 * k, s);
                }
            })
        });
    }
    group.finish();
}

fn contact(c: &mut Criterion) {
    let mut group = c.benchmark_group("contact");
    group.sample_size(20);
    for n in [22u32, 46] {
        let (model, mut state) = model(n, Integrator::SymplecticEuler, 1e-6);
        // Bottom layer on the ground (φ = 0, pressed by gravity), sliding sideways.
        for (x, v) in state.x.iter_mut().zip(&mut state.v) {
            x.y -= 0.5;
            *v = DVec3::new(0.1, -0.01, 0.0);
        }
        let surfaces: Vec<Surface> = model.terrain.iter().map(Surface::new).collect();
        let sim = &model.simulation;
        group.throughput(Throughput::Elements(model.len() as u64));
        group.bench_function(BenchmarkId::new("contact_force", format!("{n}^3")), |b| {
            b.iter(|| {
                let mut total = DVec3::ZERO;
                for i in 0..model.len() {
                    let m = model.mass[i];
                    total += contact_force(
                        &surfaces,
                        sim.contact_distance,
                        sim.dt,
                        m,
                        state.x[i],
                        state.v[i],
                        m * sim.gravity,
                    );
                }
                total
            })
        });
    }
    group.finish();
}

fn steps(c: &mut Criterion) {
    let mut group = c.benchmark_group("step");
    group.sample_size(10);
    let n = 22u32;
    for integrator in Integrator::ALL {
        let dt = match integrator {
            Integrator::ImplicitEuler => 1.0 / 60.0,
            _ => 0.5 * dt_max_symplectic(n),
        };
        let scene = cube(n, STIFFNESS, integrator, dt);
        let mut solver = softbody::open(&scene, Backend::Cpu, None).expect("CPU solver");
        solver.advance(3).expect("stable");
        group.throughput(Throughput::Elements((n as u64).pow(3)));
        group.bench_function(BenchmarkId::new(integrator.name(), format!("{n}^3")), |b| {
            b.iter(|| solver.advance(1).expect("stable"))
        });
    }
    group.finish();
}

fn cg_solve(c: &mut Criterion) {
    let mut group = c.benchmark_group("cg");
    group.sample_size(10);
    // The stiff implicit case: 22³, k_s = 1e4, dt = 1/60 s, no contact; from a zero start.
    let n = 22u32;
    let (model, state) = Model::build(&cube(n, 1e4, Integrator::ImplicitEuler, 1.0 / 60.0));
    let mut system = System::new(&model);
    let mut b = vec![DVec3::ZERO; model.len()];
    system.assemble(&model, (None, None), &state.x, &state.v, &mut b);
    let constraints = vec![Constraint::Free; model.len()];
    let z = vec![DVec3::ZERO; model.len()];
    let mut scratch = Scratch::new(model.len());
    let mut dv = vec![DVec3::ZERO; model.len()];
    let mut solve = |dv: &mut [DVec3], scratch: &mut Scratch| {
        cg::CgProblem {
            tolerance: 1e-8,
            max_iterations: 2000,
            ..cg::CgProblem::new(&mut system, &model, &constraints, &b, &z)
        }
        .solve(dv, scratch)
    };
    let outcome = solve(&mut dv, &mut scratch);
    eprintln!(
        "  cg {n}^3: {} iterations from a zero start, relative residual {:.1e}",
        outcome.iterations, outcome.relative_residual
    );
    group.bench_function(BenchmarkId::new("solve", format!("{n}^3")), |bench| {
        bench.iter(|| {
            dv.fill(DVec3::ZERO);
            solve(&mut dv, &mut scratch)
        })
    });
    group.finish();
}

/// Implicit Euler's parts on the stiff cube (k_s = 1e4, dt = 1/60 s) a few steps into
/// its fall, 22³ and 46³: the assembly of the step's system, one product A p, the multigrid's
/// values (`prepare`, every entry, as at a step's first solve) and one multigrid application.
fn implicit_parts(c: &mut Criterion) {
    let mut group = c.benchmark_group("implicit");
    group.sample_size(20);
    for n in [22u32, 46] {
        let scene = cube(n, 1e4, Integrator::ImplicitEuler, 1.0 / 60.0);
        let mut solver = softbody::open(&scene, Backend::Cpu, None).expect("CPU solver");
        solver.advance(5).expect("stable");
        let state = solver.state().expect("state").clone();
        let model = Model::build(&scene).0;
        let size = format!("{n}^3");
        group.throughput(Throughput::Elements(model.len() as u64));
        let mut system = System::new(&model);
        let mut b = vec![DVec3::ZERO; model.len()];
        group.bench_function(BenchmarkId::new("assemble", &size), |bench| {
            bench.iter(|| system.assemble(&model, (None, None), &state.x, &state.v, &mut b))
        });
        let p = state.v.clone();
        let mut out = vec![DVec3::ZERO; model.len()];
        group.bench_function(BenchmarkId::new("product", &size), |bench| {
            bench.iter(|| system.apply(&model, &p, &mut out))
        });
        let constraints = vec![Constraint::Free; model.len()];
        let mut mg = Multigrid::new(&model, &system).expect("a lattice");
        group.bench_function(BenchmarkId::new("multigrid-prepare", &size), |bench| {
            // A fresh hierarchy each time: a prepared one skips what did not change.
            bench.iter_batched_ref(
                || Multigrid::new(&model, &system).expect("a lattice"),
                |mg| mg.prepare(&system, &model, &constraints),
                criterion::BatchSize::LargeInput,
            )
        });
        mg.prepare(&system, &model, &constraints);
        group.bench_function(BenchmarkId::new("multigrid-apply", &size), |bench| {
            bench.iter(|| mg.apply(&constraints, &b, &mut out))
        });
    }
    group.finish();
}

criterion_group!(benches, springs, contact, steps, cg_solve, implicit_parts);
criterion_main!(benches);
