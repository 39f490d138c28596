//! Scene builders and measurements of the physics tests.
//!
//! Scenes are built in code (and validated exactly as a scene file would be), so each test can
//! state its physical set-up next to the closed form it checks.

use glam::DVec3;
use softbody_scene::{
    Body, BodyShape, Cuboid, ExplicitSpring, FrictionModel, Integrator, Model, ParticleSet, Scene,
    Simulation, Solver, SpringParams, State, Terrain, TerrainShape,
};

use crate::Failed;

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
        body_contact: Default::default(),
        preconditioner: Default::default(),
        cg_tolerance: softbody_scene::implicit::CG_TOLERANCE,
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
        contact_radius: None,
        self_contact: false,
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
        contact_radius: None,
        self_contact: false,
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

/// The state after one more step.
pub fn step(solver: &mut dyn Solver) -> Result<State, Failed> {
    solver.advance(1).map_err(|e| e.to_string())?;
    Ok(solver.state().map_err(|e| e.to_string())?.clone())
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

/// Σ m_i |v_i|: the scale momentum errors are measured against.
pub fn momentum_scale(model: &Model, state: &State) -> f64 {
    model
        .mass
        .iter()
        .zip(&state.v)
        .map(|(m, v)| m * v.length())
        .sum()
}

/// A free 3×3×3 cube (30 cm, 1 kg, k_s = 50 N/m, k_d = 0.1 N·s/m) without gravity or terrain,
/// its positions perturbed by up to 3 cm (springs stretched and compressed) and its velocities
/// (0.3, −0.2, 0.1) m/s plus up to 0.5 m/s each, stepped by `integrator` at a quarter of the
/// stable estimate: only its springs act, so its momentum must not change.
pub fn tumbling_cube(integrator: Integrator) -> (Model, State) {
    let mut sim = simulation(integrator, 1e-3);
    sim.gravity = DVec3::ZERO;
    let params = SpringParams {
        stiffness: 50.0,
        damping: 0.1,
    };
    let cube = cuboid(DVec3::splat(0.3), [3, 3, 3], DVec3::ZERO, 1.0, params);
    let (mut model, mut state) = Model::build(&scene(sim, vec![cuboid_body(cube)], vec![]));
    model.simulation.dt = 0.25 * model.stable_dt().expect("the cube has springs");
    let mut rng = crate::Rng::new(7);
    for (x, v) in state.x.iter_mut().zip(&mut state.v) {
        *x += rng.vec(0.03);
        *v = DVec3::new(0.3, -0.2, 0.1) + rng.vec(0.5);
    }
    (model, state)
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
