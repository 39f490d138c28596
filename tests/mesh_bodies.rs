//! A mesh body (a torus voxelised into a lattice) in free fall, on every backend and with every
//! integrator: until it reaches the ground its springs are internal forces, so its centre of
//! mass follows each method's exact free-fall recurrence and its momentum grows by exactly
//! M g t; after contact it leaves both.

use std::process::ExitCode;
use std::sync::Arc;

use glam::DVec3;
use softbody::cpu::integrators::implicit_euler::system::System;
use softbody::scene::SpringParams;
use softbody::scene::voxel::{LatticeSize, Voxels};
use softbody::scene::{Body, BodyShape, MeshBody, MeshMass, SurfaceKind, TriangleMesh};
use softbody::{Integrator, Model, State};
use softbody_testkit::scenes::*;
use softbody_testkit::{Backend, Failed, Law, Rng, cg_momentum_bound, ensure};

fn main() -> ExitCode {
    softbody_testkit::run(
        "mesh_bodies",
        [Law::per_integrator(
            "falling_mesh_body_follows_free_fall_until_contact",
            falling_mesh_body_follows_free_fall_until_contact,
        )],
    )
}

/// A torus (R = 0.3 m, r = 0.12 m, 24 × 12 quads) at 6 cm cells, 2 kg, k_s = 1 N/m,
/// k_d = 0.01 N·s/m, tilted, its lowest point about 0.75 m above the ground plane y = 0; its
/// velocities (0.5, 0, 0) m/s plus up to 0.3 m/s each, so that the springs work from the start.
/// Soft springs: explicit Euler and midpoint gain energy on any spring, and at h = 1 ms stiffer
/// ones (ω h ≈ 1 at 100 N/m) blow up before the ground is reached.
fn falling_torus(integrator: Integrator) -> (Model, State) {
    let voxels = Voxels::new(
        TriangleMesh::torus(0.3, 0.12, 24, 12),
        DVec3::ONE,
        LatticeSize::Cell(0.06),
    )
    .expect("the torus voxelises");
    let params = SpringParams {
        stiffness: 1.0,
        damping: 0.01,
    };
    let body = Body {
        name: "torus".into(),
        shape: BodyShape::Mesh(MeshBody {
            voxels: Arc::new(voxels),
            center: DVec3::new(0.0, 1.0, 0.0),
            rotation: DVec3::new(20.0, 0.0, 10.0),
            velocity: DVec3::new(0.5, 0.0, 0.0),
            mass: MeshMass::Mass(2.0),
            structural: Some(params),
            shear: Some(params),
            bending: Some(params),
            surface: SurfaceKind::Mesh,
        }),
        pinned: vec![],
        contact_radius: None,
        self_contact: false,
    };
    let ground = plane(DVec3::ZERO, DVec3::Y, 0.0, 0.5);
    let (model, mut state) = Model::build(&scene(
        simulation(integrator, 1e-3),
        vec![body],
        vec![ground],
    ));
    let mut rng = Rng::new(11);
    for v in &mut state.v {
        *v += rng.vec(0.3);
    }
    (model, state)
}

fn centre_of_mass(model: &Model, state: &State) -> DVec3 {
    let m: f64 = model.mass.iter().sum();
    model
        .mass
        .iter()
        .zip(&state.x)
        .map(|(&mi, &x)| mi * x)
        .fold(DVec3::ZERO, |a, b| a + b)
        / m
}

/// Steps checked against free fall: every step whose end state has every particle more than
/// 5 cm above the ground (contact acts within ε = 1 mm, and no particle moves 5 cm in a step).
/// The recurrences are those of `integrators.rs`'s single particle, for the centre of mass
/// x_c and the momentum P = M v_c: v_c,n = v_c,0 + n h g for every method, and x_c,n =
/// x_c,0 + n h v_c,0 + q_n g with q_n = h²n(n−1)/2 (explicit Euler), h²n(n+1)/2 (symplectic
/// and implicit Euler), (nh)²/2 (midpoint, RK4). Bounds: 1e-12 of the scale plus the backend's
/// rounding; for implicit Euler plus what CG's tolerance leaves in the momentum
/// (√n·tol·√κ·|b| per step, summed, as in `integrators.rs`) and h times that per step in x_c.
/// Then 150 more steps: the ground must have pushed the centre of mass off free fall by more
/// than 1 cm.
fn falling_mesh_body_follows_free_fall_until_contact(
    backend: &Backend,
    integrator: Integrator,
) -> Result<(), Failed> {
    let g = gravity();
    let (model, state) = falling_torus(integrator);
    let h = model.simulation.dt;
    let n_particles = model.len();
    let mass: f64 = model.mass.iter().sum();
    let (x0, p0) = (centre_of_mass(&model, &state), momentum(&model, &state));
    let v0 = p0 / mass;
    let scale = momentum_scale(&model, &state);
    let mut system = System::new(&model);
    let mut solver = backend.solver_from(model.clone(), state)?;
    let (mut cg_p, mut cg_x) = (0.0, 0.0);
    let mut checked = 0u64;
    let mut worst = (0.0f64, 0.0f64);
    let exact = |n: u64| {
        let nf = n as f64;
        let t = nf * h;
        let quad = match integrator {
            Integrator::ExplicitEuler => h * h * nf * (nf - 1.0) / 2.0,
            Integrator::SymplecticEuler | Integrator::ImplicitEuler => {
                h * h * nf * (nf + 1.0) / 2.0
            }
            Integrator::Midpoint | Integrator::Rk4 => t * t / 2.0,
        };
        (x0 + t * v0 + quad * g, p0 + mass * t * g, t, quad)
    };
    let mut n = 0u64;
    loop {
        if integrator == Integrator::ImplicitEuler {
            let st = solver.state().map_err(|e| e.to_string())?;
            let step = cg_momentum_bound(backend, &mut system, &model, &st.x, &st.v);
            cg_p += step;
            cg_x += h * cg_p / mass;
        }
        let st = step(solver.as_mut())?;
        n += 1;
        if st.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min) <= 0.05 {
            break;
        }
        let (x, p, t, quad) = exact(n);
        let x_scale = x0.length() + t * v0.length() + quad * G;
        let p_scale = scale + mass * t * G;
        let ex = (centre_of_mass(&model, &st) - x).length();
        let ep = (momentum(&model, &st) - p).length();
        let bx = 1e-12 * x_scale + backend.roundoff(x_scale, n) + cg_x;
        let bp = 1e-12 * p_scale + backend.roundoff(p_scale, n) + cg_p;
        worst = (worst.0.max(ex / bx), worst.1.max(ep / bp));
        ensure(ex <= bx && ep <= bp, || {
            format!(
                "{integrator} step {n}: centre of mass off free fall by {ex:e} m (bound \
                 {bx:e}), momentum by {ep:e} kg·m/s (bound {bp:e})"
            )
        })?;
        checked += 1;
    }
    ensure(checked >= 300, || {
        format!("{integrator}: only {checked} steps before contact")
    })?;
    solver.advance(150).map_err(|e| e.to_string())?;
    let end = solver.state().map_err(|e| e.to_string())?;
    let off = (centre_of_mass(&model, end) - exact(n + 150).0).length();
    println!(
        "{integrator}: {n_particles} particles, {checked} steps of free fall (largest error \
         / bound: centre of mass {:.2}, momentum {:.2}); 150 steps after contact {off:.3} m \
         off free fall",
        worst.0, worst.1
    );
    ensure(off > 0.01, || {
        format!("{integrator}: the ground did not stop the fall ({off:e} m)")
    })?;
    Ok(())
}
