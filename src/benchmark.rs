//! The standard benchmark cube, as `../shared/peers/mass_spring_peer.py` defines it, so that
//! `softbody` and its peers (Warp, Taichi, NumPy) time the same problem.
//!
//! n³ particles on a unit grid (spacing 1/(n−1)) whose bottom face starts at y = 0.5, total
//! mass 1, structural, shear and bending springs with k_s = 2000 and k_d = 5, gravity, a ground
//! plane y = 0 with restitution 0.5 and no friction.

use glam::DVec3;
use softbody_scene::{
    Body, BodyShape, Cuboid, FrictionModel, Integrator, Scene, Simulation, SpringParams, Terrain,
    TerrainShape,
};

/// Spring stiffness of the benchmark cube, N/m.
pub const STIFFNESS: f64 = 2000.0;
/// Spring damping of the benchmark cube, N·s/m.
pub const DAMPING: f64 = 5.0;
/// Bound on the largest eigenvalue of the lattice's unit spring operator (the peer script's
/// `MU_MAX`, measured there with an eigensolver).
const MU_MAX: f64 = 18.0;

/// Largest stable symplectic-Euler step of the linearised n³ cube (the peer's
/// `dt_max_symplectic`): the stiffest mode λ = k_s μ n³, c = 2 k_d μ n³ is stable iff
/// h²λ + hc ≤ 4.
pub fn dt_max_symplectic(n: u32) -> f64 {
    let n3 = (n as f64).powi(3);
    let a = STIFFNESS * MU_MAX * n3;
    let b = 2.0 * DAMPING * MU_MAX * n3;
    (-b + (b * b + 16.0 * a).sqrt()) / (2.0 * a)
}

/// The benchmark cube of n³ particles with `stiffness` on every spring, stepped by
/// `integrator` at `dt`.
pub fn cube(n: u32, stiffness: f64, integrator: Integrator, dt: f64) -> Scene {
    let springs = Some(SpringParams {
        stiffness,
        damping: DAMPING,
    });
    Scene {
        simulation: Simulation {
            integrator,
            dt,
            duration: 1.0,
            frame_rate: 1.0 / dt.max(1.0 / 30.0),
            gravity: DVec3::new(0.0, -9.81, 0.0),
            drag: 0.0,
            contact_distance: 0.0,
        },
        bodies: vec![Body {
            name: "cube".into(),
            shape: BodyShape::Cuboid(Cuboid {
                size: DVec3::ONE,
                resolution: [n; 3],
                center: DVec3::new(0.5, 1.0, 0.5),
                rotation: DVec3::ZERO,
                velocity: DVec3::ZERO,
                mass: 1.0,
                structural: springs,
                shear: springs,
                bending: springs,
            }),
            pinned: Vec::new(),
        }],
        terrain: vec![Terrain {
            shape: TerrainShape::Plane {
                point: DVec3::ZERO,
                normal: DVec3::Y,
            },
            restitution: 0.5,
            friction: 0.0,
            friction_model: FrictionModel::Coulomb,
        }],
    }
}
