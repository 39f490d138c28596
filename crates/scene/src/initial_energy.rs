//! The initial energy of each body, checked before a run: a scene whose energy at frame 0
//! overflows f64 cannot be run (its energies would be written as non-numbers, and the
//! instability guard measures against them), and validation says which body and, where one
//! value alone overflows it, which value, instead of the run refusing the whole scene.
//!
//! The energies are the solvers' (kinetic ½Σm|v|², gravitational −Σm g·x, elastic
//! ½Σk(|d| − r)², `crates/cpu/src/energy.rs`) in closed form where a body's particles share a
//! mass and a velocity: ½·M·|v|² over the particles that move, and −M·g·x̄ with x̄ the
//! particles' mean. The lattices' springs start at their rest lengths, so only a particle
//! set's explicit springs hold elastic energy. The solvers sum in another order, so a total
//! within rounding of f64's largest value can still overflow there: the run refuses it then.

use glam::DVec3;

use crate::error::{Invalid, KeyPath, Num};
use crate::scene::{Body, BodyShape, MeshBody, Scene};

type Check = Result<(), Invalid>;

/// Refuses the first body whose initial energy is not a finite number, then a scene whose
/// bodies' energies add up beyond f64's range.
pub(crate) fn check(scene: &Scene) -> Check {
    let g = scene.simulation.gravity;
    let mut energies = Vec::with_capacity(scene.bodies.len());
    for (i, body) in scene.bodies.iter().enumerate() {
        energies.push(body_energy(i, body, g)?);
    }
    if energies.iter().sum::<f64>().is_finite() {
        return Ok(());
    }
    let each: Vec<String> = (energies.iter().enumerate())
        .map(|(i, e)| format!("{} J (body[{i}])", Num(*e)))
        .collect();
    Err(Invalid::new(
        KeyPath::root(),
        format!(
            "the scene's initial energy is not a finite number: the bodies' energies, {}, add \
             up beyond f64's range",
            each.join(", ")
        ),
    ))
}

/// "… is beyond f64's range", the end of every refusal here.
const BEYOND: &str = "is beyond f64's range";

/// Body `i`'s initial energy, J, or the refusal naming what overflows.
fn body_energy(i: usize, body: &Body, g: DVec3) -> Result<f64, Invalid> {
    let at = KeyPath::root().key("body").index(i);
    let (kinetic, gravitational, elastic) = match &body.shape {
        BodyShape::Particles(p) => {
            let (mut kinetic, mut gravitational, mut elastic) = (0.0, 0.0, 0.0);
            // Validated: every pinned index names a particle.
            let mut pinned = vec![false; p.positions.len()];
            for &k in &body.pinned {
                pinned[k as usize] = true;
            }
            for (k, ((&x, &v), &m)) in (p.positions.iter().zip(&p.velocities))
                .zip(&p.masses)
                .enumerate()
            {
                if !pinned[k] {
                    kinetic += kinetic_of(&at.key("velocities").index(k), &at, m, v)?;
                }
                let particle = (at.key("positions").index(k), "its particle");
                gravitational += gravitational_of(particle, &at, m, x, g, i)?;
            }
            for (k, s) in p.springs.iter().enumerate() {
                let (a, b) = (p.positions[s.a as usize], p.positions[s.b as usize]);
                // The solvers' length, whose square can overflow where the length does not.
                let d = a.distance(b);
                if !d.is_finite() {
                    return Err(Invalid::new(
                        at.key("springs").index(k),
                        format!(
                            "the initial elastic energy is not a finite number: the spring's \
                             length, {} m, squared {BEYOND}",
                            Num(norm(a - b))
                        ),
                    ));
                }
                let stretch = d - s.rest.unwrap_or(d);
                let e = 0.5 * s.stiffness * stretch * stretch;
                if !e.is_finite() {
                    return Err(Invalid::new(
                        at.key("springs").index(k),
                        format!(
                            "the initial elastic energy is not a finite number: ½·k·(|d| − r)² \
                             of a spring of stiffness {} N/m stretched by {} m {BEYOND}",
                            Num(s.stiffness),
                            Num(stretch)
                        ),
                    ));
                }
                elastic += e;
            }
            (kinetic, gravitational, elastic)
        }
        BodyShape::Cuboid(_) | BodyShape::Mesh(_) => {
            let (velocity, mean) = match &body.shape {
                BodyShape::Cuboid(c) => (c.velocity, c.center),
                BodyShape::Mesh(m) => (m.velocity, mesh_mean(m)),
                BodyShape::Particles(_) => unreachable!("matched above"),
            };
            let n = body.particle_count() as f64;
            let moving = (n - body.pinned.len() as f64) / n;
            let mass = body.mass();
            let kinetic = moving * kinetic_of(&at.key("velocity"), &at, mass, velocity)?;
            let centre = (at.key("center"), "its centre of mass");
            let gravitational = gravitational_of(centre, &at, mass, mean, g, i)?;
            (kinetic, gravitational, 0.0)
        }
    };
    let total = kinetic + gravitational + elastic;
    if total.is_finite() {
        Ok(total)
    } else {
        Err(Invalid::new(
            at,
            format!(
                "the initial energy is not a finite number: kinetic {} J, gravitational {} J \
                 and elastic {} J add up beyond f64's range",
                Num(kinetic),
                Num(gravitational),
                Num(elastic)
            ),
        ))
    }
}

/// |v|, finite for every finite v (where |v|² is not: a speed of 1e200 m/s is said as such).
fn norm(v: DVec3) -> f64 {
    let largest = v.abs().max_element();
    if largest > 0.0 {
        largest * (v / largest).length()
    } else {
        0.0
    }
}

/// The particles' mean position of a mesh body, metres.
fn mesh_mean(m: &MeshBody) -> DVec3 {
    let v = &m.voxels;
    let n = v.particle_count().max(1) as f64;
    let local: DVec3 = v.points().iter().map(|&p| v.local(p) / n).sum();
    m.center + crate::scene::rotation_from_degrees(m.rotation) * local
}

/// ½·m·|v|², the kinetic energy of mass `m` at `v`: the velocity at `velocity` blamed when its
/// square alone overflows, else the body at `body`.
fn kinetic_of(velocity: &KeyPath, body: &KeyPath, m: f64, v: DVec3) -> Result<f64, Invalid> {
    let v2 = v.length_squared();
    if !v2.is_finite() {
        return Err(Invalid::new(
            velocity.clone(),
            format!(
                "the initial kinetic energy is not a finite number: the speed {} m/s squared \
                 {BEYOND}",
                Num(norm(v))
            ),
        ));
    }
    let e = 0.5 * m * v2;
    if e.is_finite() {
        Ok(e)
    } else {
        Err(Invalid::new(
            body.clone(),
            format!(
                "the initial kinetic energy ½·m·|v|² is not a finite number: {} kg at {} m/s \
                 {BEYOND}",
                Num(m),
                Num(norm(v))
            ),
        ))
    }
}

/// −m·g·x of mass `m` at `x` under `g` (of body `i`): the larger of gravity and the position
/// (the key of `position`, and what it is) blamed when g·x alone overflows, else the body at
/// `body`.
fn gravitational_of(
    (position, what): (KeyPath, &str),
    body: &KeyPath,
    m: f64,
    x: DVec3,
    g: DVec3,
    i: usize,
) -> Result<f64, Invalid> {
    let gx = g.dot(x);
    let (g_len, x_len) = (norm(g), norm(x));
    if !gx.is_finite() {
        return Err(if g_len >= x_len {
            Invalid::new(
                KeyPath::root().key("simulation").key("gravity"),
                format!(
                    "the initial gravitational energy of body[{i}] is not a finite number: \
                     |g| = {} m/s² times {what}, {} m from the origin, {BEYOND}",
                    Num(g_len),
                    Num(x_len)
                ),
            )
        } else {
            Invalid::new(
                position,
                format!(
                    "the initial gravitational energy is not a finite number: {what}, {} m \
                     from the origin, times |g| = {} m/s² {BEYOND}",
                    Num(x_len),
                    Num(g_len)
                ),
            )
        });
    }
    let e = -m * gx;
    if e.is_finite() {
        Ok(e)
    } else {
        Err(Invalid::new(
            body.clone(),
            format!(
                "the initial gravitational energy −m·g·x is not a finite number: {} kg at g·x = \
                 {} J/kg {BEYOND}",
                Num(m),
                Num(gx)
            ),
        ))
    }
}
