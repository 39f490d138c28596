//! The scenes the explicit integrators are checked on (implicit Euler's are in `implicit.rs`).

use glam::DVec3;
use softbody_scene::Integrator;

use crate::harness::{Case, direction};

pub fn scattered(i: usize, _: DVec3) -> DVec3 {
    direction(i, 1.0)
}

pub fn cube(center: [f64; 3], velocity: [f64; 3]) -> String {
    format!(
        "[[body]]\nkind = \"cuboid\"\nsize = [0.3, 0.3, 0.3]\nresolution = [3, 3, 3]\n\
         center = [{}, {}, {}]\nrotation = [0.0, 0.0, -20.0]\nmass = 2.7\nvelocity = {velocity:?}\n\
         structural = {{ stiffness = 900.0, damping = 2.0 }}\n\
         shear = {{ stiffness = 700.0, damping = 1.5 }}\n\
         bending = {{ stiffness = 400.0, damping = 1.0 }}\n",
        center[0], center[1], center[2]
    )
}

pub fn cases(integrator: Integrator) -> Vec<Case> {
    // The contact band ε is wide enough that particles pressed onto the terrain stay inside it
    // (the contact force starts at φ = ε: a jump that differences cannot straddle).
    let sim = |duration: f64, band: f64| {
        format!(
            "[simulation]\nintegrator = \"{}\"\ndt = 1e-3\nduration = {duration}\nframe_rate = 100.0\n\
             drag = 0.2\ncontact_distance = {band}\n",
            integrator.name()
        )
    };
    vec![
        Case {
            name: "free flight",
            // Hanging from a pinned corner.
            toml: sim(0.12, 0.01) + &cube([0.0, 1.0, 0.0], [0.4, -0.2, 0.1]) + "pinned = [0]\n",
            spin: 2.0,
            strain: 0.01,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "sliding on a slope",
            // The cube's bottom face 5 mm above the 20° plane, in the contact band, sliding
            // down the slope and across it.
            toml: sim(0.12, 0.03)
                + &cube([0.0530, 0.1457, 0.0], [0.3759, -0.1368, 0.1])
                + "[[terrain]]\nkind = \"plane\"\npoint = [0.0, -0.0, 0.0]\n\
                   normal = [0.36397023426620234, 1.0, 0.0]\nfriction = 0.1\nfriction_model = \"coulomb\"\nrestitution = 0.3\n",
            spin: 0.0,
            strain: 0.001,
            stretch: 1.0,
            // Down the slope, within the plane.
            x0: |_, _| DVec3::new(0.9397, -0.3420, 0.0),
        },
        Case {
            name: "in a bowl",
            toml: sim(0.12, 0.03)
                + &cube([0.35, 0.24, 0.0], [0.4, -0.2, 0.1])
                + "[[terrain]]\nkind = \"bowl\"\ncenter = [0.0, 1.0, 0.0]\nradius = 1.0\n\
                   friction = 0.4\nfriction_model = \"viscous\"\nrestitution = 0.2\n",
            spin: 0.0,
            strain: 0.001,
            stretch: 1.0,
            // A turn about the bowl's vertical axis.
            x0: |_, x| DVec3::Y.cross(x - DVec3::Y),
        },
        Case {
            name: "bouncing",
            toml: sim(0.15, 0.01)
                + "[[body]]\nkind = \"particles\"\npositions = [[0.0, 0.052, 0.0], [0.1, 0.063, 0.02]]\n\
                   masses = [0.5, 0.7]\nvelocities = [[0.3, -1.0, 0.0], [0.2, -1.2, 0.1]]\n\
                   springs = [{ a = 0, b = 1, stiffness = 50.0, damping = 0.1 }]\n\
                   [[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nrestitution = 0.6\n\
                   friction = 0.0\n",
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "round a box's edge",
            // Two particles on a spring 1–1.5 cm past the top edge of a box (the edge along z),
            // in the contact band, sliding along it and down round it: the normal turns with
            // them until they pass onto the side face at ~0.05 s, 2 cm out (inside the band).
            toml: sim(0.06, 0.03)
                + &sliding_pair(
                    [[0.51, 0.51, 0.0], [0.512, 0.508, 0.05]],
                    EDGE_VELOCITIES,
                    "kind = \"box\"\ncenter = [0.0, 0.0, 0.0]\nhalf_extents = [0.5, 0.5, 1.0]\n",
                ),
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "on a tent's peak",
            // Two particles on a spring 1.5–2 cm above the raised vertex of a heightfield (a
            // tent of four 45° slopes), in the contact band, sliding off it: the normal turns
            // round the vertex and its edges.
            toml: sim(0.06, 0.03)
                + &sliding_pair(
                    [[1.0, 1.015, 1.0], [1.01, 1.012, 1.005]],
                    [[0.1, 0.0, 0.05], [0.05, 0.0, 0.1]],
                    "kind = \"heightfield\"\norigin = [0.0, 0.0, 0.0]\ncell_size = [1.0, 1.0]\n\
                     heights = [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]\n",
                ),
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "round a mesh's edge",
            // As round the box's edge, over a triangle mesh (the unit cube's OBJ): the normal
            // turns past the edge its two faces' triangles share.
            toml: sim(0.06, 0.03)
                + &sliding_pair(
                    [[1.01, 1.01, 0.3], [1.012, 1.008, 0.35]],
                    EDGE_VELOCITIES,
                    &format!(
                        "kind = \"mesh\"\npath = {:?}\n",
                        concat!(
                            env!("CARGO_MANIFEST_DIR"),
                            "/../terrain/tests/data/unit_cube.obj"
                        )
                    ),
                ),
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "bodies' impact",
            // Two particles on a spring falling at 3 m/s onto two corners of a cube, 5 and
            // 1.5 mm to their side: both meet their corner in the 11th step, fresh impacts at
            // d = 0.80 R, past the slop's 0.9 R (pushed apart), the tilted normal sliding the
            // first (|u_t|/W 0.14 N·s against μJ 0.078 N·s: kinetic) and not the second (0.045
            // against 0.10: static); they bounce off (the run ends before the cube's springs
            // bring a corner back: by 0.03 s symplectic Euler's comes within 0.13% of R of its
            // particle, a branch within 1e-5 of the moves). Every branch
            // holds by far more than the differences' moves (1e-6 m, 1e-6 m/s): a pair meets
            // its corner 2 mm past R, goes 1 mm past the slop, approaches at 2.3 m/s.
            toml: sim(0.02, 0.01)
                + "body_restitution = 0.5\nbody_friction = 0.2\n"
                + &corners()
                + "[[body]]\nkind = \"particles\"\n\
                   positions = [[-0.025, 0.06624, -0.03], [0.03, 0.06786, -0.0285]]\n\
                   masses = [0.3, 0.4]\nvelocities = [[0.0, -3.0, 0.0], [0.0, -3.0, 0.0]]\n\
                   contact_radius = 0.005\n\
                   springs = [{ a = 0, b = 1, stiffness = 200.0, damping = 0.1 }]\n",
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "bodies pressed, sliding",
            // A particle (on a spring to another) 0.3 mm into a cube's corner at the start,
            // pressing on it at 0.3 m/s and sliding across it at 0.5 m/s: the penalty at every
            // stage, an impulse in the first step that is not a fresh impact (u_n −0.05 to
            // −0.12 m/s, d 0.94–0.96 R: within R and the slop by far) with viscous friction,
            // pressed by it and the penalty, under its cap (k_f J|u_t| 0.002–0.005 N·s against
            // |u_t|/W 0.038 N·s), then the penalty pushing the pair apart; the pair leaves
            // contact moving apart (F = max(0, −c u_n) = 0 there, no jump) as the particle
            // slides off.
            toml: sim(0.03, 0.01)
                + "body_restitution = 0.5\nbody_friction = 0.5\nbody_friction_model = \"viscous\"\n"
                + &corners()
                + "[[body]]\nkind = \"particles\"\n\
                   positions = [[0.0397, 0.03, -0.03], [0.0997, 0.03, -0.03]]\n\
                   masses = [0.3, 0.4]\nvelocities = [[-0.3, 0.0, 0.5], [-0.3, 0.0, 0.5]]\n\
                   contact_radius = 0.005\n\
                   springs = [{ a = 0, b = 1, stiffness = 200.0, damping = 0.1 }]\n",
            spin: 0.0,
            strain: 0.0,
            stretch: 1.0,
            x0: scattered,
        },
        Case {
            name: "held stretched",
            // A 4³ lattice pinned on its faces 20 % out from its centre: the 8 particles
            // inside move, every spring stretched throughout.
            toml: sim(0.12, 0.01)
                + &cube([0.0, 1.0, 0.0], [0.0, 0.0, 0.0]).replace("[3, 3, 3]", "[4, 4, 4]")
                + &format!("pinned = {:?}\n", faces(4)),
            spin: 1.0,
            strain: 0.003,
            stretch: 1.2,
            x0: scattered,
        },
    ]
}

/// The velocities of the pairs round an edge: along it, and a little off it.
pub const EDGE_VELOCITIES: [[f64; 3]; 2] = [[0.05, -0.02, 0.3], [0.02, 0.0, 0.25]];

/// Two particles on a spring at `positions` with `velocities`, over the terrain `shape` (its
/// `[[terrain]]` keys) with Coulomb friction and restitution: the cases whose normal turns.
pub fn sliding_pair(positions: [[f64; 3]; 2], velocities: [[f64; 3]; 2], shape: &str) -> String {
    format!(
        "[[body]]\nkind = \"particles\"\npositions = {positions:?}\nmasses = [0.5, 0.7]\n\
         velocities = {velocities:?}\n\
         springs = [{{ a = 0, b = 1, stiffness = 50.0, damping = 0.1 }}]\n\
         [[terrain]]\n{shape}friction = 0.2\nfriction_model = \"coulomb\"\nrestitution = 0.3\n"
    )
}

/// A 6 cm cube of 2³ particles at the origin, at rest, whose particles touch others' within
/// 5 mm: the other body of the cases of contact between bodies.
pub fn corners() -> String {
    "[[body]]\nkind = \"cuboid\"\nsize = [0.06, 0.06, 0.06]\nresolution = [2, 2, 2]\n\
     center = [0.0, 0.0, 0.0]\nmass = 0.8\ncontact_radius = 0.005\n\
     structural = { stiffness = 900.0, damping = 2.0 }\n\
     shear = { stiffness = 700.0, damping = 1.5 }\n\
     bending = { stiffness = 400.0, damping = 1.0 }\n"
        .to_owned()
}

/// The particles on the faces of an n³ lattice.
pub fn faces(n: usize) -> Vec<usize> {
    let edge = |c: usize| c == 0 || c == n - 1;
    (0..n * n * n)
        .filter(|&p| edge(p % n) || edge(p / n % n) || edge(p / (n * n)))
        .collect()
}
