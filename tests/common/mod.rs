//! Shared scene builders and measurements of the physics tests.
//!
//! Scenes are built in code (and validated exactly as a scene file would be), so each test can
//! state its physical set-up next to the closed form it checks.
#![allow(dead_code)]

use glam::DVec3;
use softbody::scene::{
    Body, BodyShape, Cuboid, ExplicitSpring, FrictionModel, ParticleSet, Simulation, SpringParams,
    Terrain, TerrainShape,
};
use softbody::{CpuSolver, Integrator, Model, Scene, Solver, State};

/// |g|, m/s².
pub const G: f64 = 9.81;

/// Standard gravity along −y.
pub fn gravity() -> DVec3 {
    DVec3::new(0.0, -G, 0.0)
}

/// `[simulation]` with gravity along −y, no drag, ε = 1 mm; one frame per step at most.
pub fn simulation(integrator: Integrator, dt: f64) -> Simulation {
    Simulation {
        integrator,
        dt,
        duration: 1.0,
        frame_rate: 30.0f64.min(1.0 / dt),
        gravity: gravity(),
        drag: 0.0,
        contact_distance: 0.001,
    }
}

/// A spring between particles `a` and `b` whose rest length is their initial distance.
pub fn spring(a: u32, b: u32, stiffness: f64, damping: f64) -> ExplicitSpring {
    ExplicitSpring {
        a,
        b,
        stiffness,
        damping,
        rest: None,
    }
}

/// A `particles` body.
pub fn particles(
    positions: Vec<DVec3>,
    velocities: Vec<DVec3>,
    masses: Vec<f64>,
    springs: Vec<ExplicitSpring>,
) -> Body {
    Body {
        name: "particles".into(),
        shape: BodyShape::Particles(ParticleSet {
            positions,
            velocities,
            masses,
            springs,
        }),
        pinned: Vec::new(),
    }
}

/// One free particle of mass 1 kg.
pub fn particle(x: DVec3, v: DVec3) -> Body {
    particles(vec![x], vec![v], vec![1.0], Vec::new())
}

/// A cuboid body with the same spring parameters for the families given.
pub fn cuboid(
    size: DVec3,
    resolution: [u32; 3],
    center: DVec3,
    mass: f64,
    params: SpringParams,
) -> Cuboid {
    Cuboid {
        size,
        resolution,
        center,
        rotation: DVec3::ZERO,
        velocity: DVec3::ZERO,
        mass,
        structural: Some(params),
        shear: Some(params),
        bending: Some(params),
    }
}

/// A body made of one cuboid.
pub fn cuboid_body(c: Cuboid) -> Body {
    Body {
        name: "cube".into(),
        shape: BodyShape::Cuboid(c),
        pinned: Vec::new(),
    }
}

/// A plane through `point` with outward `normal` (normalised here) and Coulomb friction.
pub fn plane(point: DVec3, normal: DVec3, restitution: f64, friction: f64) -> Terrain {
    Terrain {
        shape: TerrainShape::Plane {
            point,
            normal: normal.normalize(),
        },
        restitution,
        friction,
        friction_model: FrictionModel::Coulomb,
    }
}

/// A validated scene.
pub fn scene(simulation: Simulation, bodies: Vec<Body>, terrain: Vec<Terrain>) -> Scene {
    let scene = Scene {
        simulation,
        bodies,
        terrain,
    };
    scene.validate().expect("the test scene is valid");
    scene
}

/// A CPU solver on one thread (the tiny systems here gain nothing from more).
pub fn solver(scene: &Scene) -> CpuSolver {
    let (model, state) = Model::build(scene);
    CpuSolver::new(model, state, Some(1)).expect("a one-thread pool")
}

/// A CPU solver on `threads` threads starting from a given state.
pub fn solver_from(model: Model, state: State, threads: usize) -> CpuSolver {
    CpuSolver::new(model, state, Some(threads)).expect("a thread pool")
}

/// The state after one more step.
pub fn step(solver: &mut CpuSolver) -> State {
    solver.advance(1).expect("a stable step");
    solver.state().expect("state").clone()
}

/// Σ m_i v_i.
pub fn momentum(model: &Model, state: &State) -> DVec3 {
    model
        .mass
        .iter()
        .zip(&state.v)
        .map(|(&m, &v)| m * v)
        .fold(DVec3::ZERO, |a, b| a + b)
}

/// A small deterministic generator (splitmix64) for "random" but reproducible test data.
pub struct Rng(u64);

impl Rng {
    /// Seeded.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [−1, 1).
    pub fn signed(&mut self) -> f64 {
        2.0 * self.unit() - 1.0
    }

    /// Each coordinate uniform in [−s, s).
    pub fn vec(&mut self, s: f64) -> DVec3 {
        DVec3::new(self.signed(), self.signed(), self.signed()) * s
    }
}

/// Every integrator but implicit Euler (they share the explicit contact model).
pub const EXPLICIT: [Integrator; 4] = [
    Integrator::ExplicitEuler,
    Integrator::SymplecticEuler,
    Integrator::Midpoint,
    Integrator::Rk4,
];

/// Order of accuracy of each integrator.
pub fn order(integrator: Integrator) -> u32 {
    match integrator {
        Integrator::ExplicitEuler | Integrator::SymplecticEuler | Integrator::ImplicitEuler => 1,
        Integrator::Midpoint => 2,
        Integrator::Rk4 => 4,
    }
}
