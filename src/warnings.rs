//! What a valid scene may still get wrong, said before it runs (`softbody check` lists them,
//! `softbody run` prints them before its first step): bodies that start inside the terrain, and
//! a time step above the explicit integrators' stable estimate.

use std::fmt;

use glam::DVec3;
use rayon::prelude::*;
use softbody_cpu::stable_step::stable_dt_estimate;
use softbody_scene::{Integrator, Model, Terrain, TerrainShape};
use softbody_terrain::Surface;

/// Depth below which a particle counts as inside a terrain shape, metres: a body placed
/// exactly on the ground (φ = 0 up to rounding) is not inside it.
const INSIDE: f64 = 1e-9;

/// A warning about a valid scene.
#[derive(Debug, Clone, PartialEq)]
pub enum Warning {
    /// Particles of a body start inside a terrain shape: the contact response pushes them out
    /// in the first steps, which adds energy the scene did not have.
    InsideTerrain {
        /// The body's name.
        body: String,
        /// The terrain shape's index in the scene.
        terrain: usize,
        /// Particles of the body inside it.
        inside: usize,
        /// The body's particles.
        of: u32,
        /// The deepest of them, metres below the surface.
        depth: f64,
        /// Whether the shape is a mesh: one that holds nearly every particle is likely wound
        /// the wrong way round.
        mesh: bool,
    },
    /// An explicit integrator's dt is above the estimate of the largest stable step
    /// ([`stable_dt_estimate`], from the stiffest mode of the springs).
    StepAboveStable {
        /// The scene's dt, seconds.
        dt: f64,
        /// The estimate, seconds.
        stable: f64,
    },
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::InsideTerrain {
                body,
                terrain,
                inside,
                of,
                depth,
                mesh,
            } => {
                write!(
                    f,
                    "body `{body}` starts with {inside} of its {of} particles inside \
                     terrain[{terrain}] (up to {depth:.3e} m deep): contact pushes them out in \
                     the first steps, adding energy the scene did not have"
                )?;
                if *mesh && nearly_all(*inside, *of) {
                    write!(
                        f,
                        "; so many inside a mesh suggest it is wound the wrong way round (its \
                         faces' normals pointing into the solid, so that the free side counts \
                         as solid): reverse the corners of every face (in Blender, Mesh ▸ \
                         Normals ▸ Flip) so that they run counter-clockwise seen from the free \
                         side"
                    )?;
                }
                Ok(())
            }
            Warning::StepAboveStable { dt, stable } => write!(
                f,
                "dt = {dt} s is above the estimated stable step of {stable:.3e} s for the \
                 explicit integrators (the stiffest mode of the springs): this run will likely \
                 become unstable"
            ),
        }
    }
}

/// Whether `inside` of `of` particles is nearly all of them (nine in ten or more).
fn nearly_all(inside: usize, of: u32) -> bool {
    10 * inside as u64 >= 9 * u64::from(of)
}

/// The warnings about running `model` from the positions `x` (its initial state's), bodies
/// before the step.
pub fn warnings(model: &Model, x: &[DVec3]) -> Vec<Warning> {
    warnings_given(model, x, || stable_dt_estimate(model, x))
}

/// [`warnings`], with the stable step's estimate ([`stable_dt_estimate`] at `x`) from
/// `estimate`, called only where the step is above the guaranteed bound: for a caller that
/// needs the estimate anyway (`softbody check` prints it).
pub fn warnings_given(
    model: &Model,
    x: &[DVec3],
    estimate: impl FnOnce() -> Option<f64>,
) -> Vec<Warning> {
    let mut found = inside_terrain(model, x);
    found.extend(step_above_stable(model, estimate));
    found
}

/// [`Warning::StepAboveStable`] when `model`'s integrator is explicit and its dt is above the
/// stable step's estimate, given by `estimate` ([`stable_dt_estimate`] at the initial
/// positions), which is called only where the step is above the guaranteed bound.
pub fn step_above_stable(model: &Model, estimate: impl FnOnce() -> Option<f64>) -> Option<Warning> {
    let sim = &model.simulation;
    // Below the guaranteed bound (never above the estimate: λ and c bounded from above, where
    // the power iteration approaches them from below) the estimate's products are skipped: on
    // large bodies they take seconds.
    if sim.integrator != Integrator::ImplicitEuler
        && model.stable_dt().is_some_and(|bound| sim.dt > bound)
        && let Some(stable) = estimate()
        && sim.dt > stable
    {
        return Some(Warning::StepAboveStable { dt: sim.dt, stable });
    }
    None
}

/// The bodies of `model` that start inside a terrain shape at the positions `x`
/// ([`Warning::InsideTerrain`]), bodies before shapes.
pub fn inside_terrain(model: &Model, x: &[DVec3]) -> Vec<Warning> {
    model
        .bodies
        .iter()
        .flat_map(|body| {
            let range = body.first as usize..(body.first + body.count) as usize;
            body_inside_terrain(&model.terrain, &body.name, &x[range])
        })
        .collect()
}

/// The shapes of `terrain` that the body `name` starts inside of at its particles' positions
/// `x` ([`Warning::InsideTerrain`]), in the terrain's order: for a caller that has one body's
/// positions without a model of the scene (`softbody check` on large cuboids).
pub fn body_inside_terrain(terrain: &[Terrain], name: &str, x: &[DVec3]) -> Vec<Warning> {
    let mut found = Vec::new();
    for (t, shape) in terrain.iter().enumerate() {
        let surface = Surface::new(shape);
        // Each particle's depth, and the deepest: order-free (max of values), so the parallel
        // sweep gives what the serial one would.
        let (inside, depth) = x
            .par_iter()
            .filter_map(|&x| surface.query(x, -INSIDE))
            .map(|c| (1usize, -c.phi))
            .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1.max(b.1)));
        if inside > 0 {
            found.push(Warning::InsideTerrain {
                body: name.to_owned(),
                terrain: t,
                inside,
                of: x.len() as u32,
                depth,
                mesh: matches!(shape.shape, TerrainShape::Mesh(_)),
            });
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::Scene;

    fn scene(center_y: f64, dt: f64) -> Scene {
        let text = format!(
            "[simulation]\ndt = {dt:?}\nduration = 0.1\n\
             [[body]]\nname = \"cube\"\nkind = \"cuboid\"\nsize = [1.0, 1.0, 1.0]\n\
             resolution = [3, 3, 3]\ncenter = [0.0, {center_y:?}, 0.0]\nmass = 1.0\n\
             structural = {{ stiffness = 100.0, damping = 0.1 }}\n\
             [[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n"
        );
        Scene::from_toml(&text, "t.toml".as_ref()).unwrap()
    }

    #[test]
    fn a_body_on_the_ground_is_fine_and_one_in_it_is_named_with_its_depth() {
        let (model, state) = Model::build(&scene(0.5, 1e-3));
        assert_eq!(
            warnings(&model, &state.x),
            [],
            "resting exactly on the plane"
        );
        // The bottom layer 0.25 m deep, the middle one at the surface: 9 of 27 inside.
        let (model, state) = Model::build(&scene(0.25, 1e-3));
        let found = warnings(&model, &state.x);
        let [
            Warning::InsideTerrain {
                body,
                terrain,
                inside,
                of,
                depth,
                mesh: false,
            },
        ] = &found[..]
        else {
            panic!("{found:?}");
        };
        assert_eq!((body.as_str(), *terrain, *inside, *of), ("cube", 0, 9, 27));
        assert!((depth - 0.25).abs() < 1e-12, "{depth}");
        assert!(found[0].to_string().starts_with(
            "body `cube` starts with 9 of its 27 particles inside terrain[0] (up to 2.500e-1 m deep)"
        ));
    }

    /// A ground patch wound the wrong way (normals down) holds every particle of a cube resting
    /// above it: the warning says the winding is the likely cause and how to fix it. The
    /// same patch wound right holds none.
    #[test]
    fn a_body_inside_a_mesh_wound_the_wrong_way_is_told_the_winding() {
        let mut scene = scene(0.6, 1e-3);
        let corners = [
            [-2.0, 0.0, -2.0],
            [2.0, 0.0, -2.0],
            [2.0, 0.0, 2.0],
            [-2.0, 0.0, 2.0],
        ];
        let patch = |triangles| softbody_scene::TriangleMesh {
            path: "ground.obj".into(),
            vertices: corners.map(DVec3::from).to_vec(),
            triangles,
        };
        // Counter-clockwise seen from above is [0, 3, 2], [0, 2, 1].
        scene.terrain[0].shape = TerrainShape::Mesh(patch(vec![[0, 1, 2], [0, 2, 3]]));
        let (model, state) = Model::build(&scene);
        let found = inside_terrain(&model, &state.x);
        assert!(
            matches!(
                found[..],
                [Warning::InsideTerrain {
                    inside: 27,
                    of: 27,
                    mesh: true,
                    ..
                }]
            ),
            "{found:?}"
        );
        let said = found[0].to_string();
        assert!(
            said.starts_with("body `cube` starts with 27 of its 27 particles inside terrain[0]"),
            "{said}"
        );
        assert!(
            said.ends_with(
                "; so many inside a mesh suggest it is wound the wrong way round (its faces' \
                 normals pointing into the solid, so that the free side counts as solid): \
                 reverse the corners of every face (in Blender, Mesh ▸ Normals ▸ Flip) so that \
                 they run counter-clockwise seen from the free side"
            ),
            "{said}"
        );
        scene.terrain[0].shape = TerrainShape::Mesh(patch(vec![[0, 3, 2], [0, 2, 1]]));
        let (model, state) = Model::build(&scene);
        assert_eq!(inside_terrain(&model, &state.x), []);
    }

    #[test]
    fn a_step_above_the_stable_estimate_is_named() {
        let (model, state) = Model::build(&scene(2.0, 1e-3));
        let stable = stable_dt_estimate(&model, &state.x).unwrap();
        let (model, state) = {
            let (mut m, s) = (model, state);
            m.simulation.dt = 2.0 * stable;
            (m, s)
        };
        assert_eq!(
            warnings(&model, &state.x),
            [Warning::StepAboveStable {
                dt: 2.0 * stable,
                stable
            }]
        );
    }

    /// The estimate is where the damped jelly cube of `scenes/jelly-on-ground.toml` stops being
    /// stable: its 3 s run under symplectic Euler is clean at 0.95 times it and diverges at 1.05
    /// times it, where the conservative bound (`Model::stable_dt`) is four times lower.
    #[test]
    fn the_stable_step_estimate_separates_stable_from_unstable_runs() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/jelly-on-ground.toml");
        let scene = Scene::from_file(path).unwrap();
        let (model, state) = Model::build(&scene);
        let estimate = stable_dt_estimate(&model, &state.x).unwrap();
        let bound = model.stable_dt().unwrap();
        assert!(estimate > 3.5 * bound, "{estimate} vs {bound}");
        let run = |dt: f64| {
            let mut scene = scene.clone();
            scene.simulation.dt = dt;
            scene.simulation.frame_rate = 30.0;
            let mut solver = crate::open(&scene, crate::Backend::Cpu, Some(1)).unwrap();
            let mut sink =
                crate::output::sink(crate::output::Format::Csv, Box::new(std::io::sink())).unwrap();
            crate::run::run(solver.as_mut(), None, sink.as_mut(), &mut |_, _| {})
        };
        assert!(run(0.95 * estimate).is_ok(), "unstable below the estimate");
        assert!(
            matches!(run(1.05 * estimate), Err(crate::run::RunError::Unstable(_))),
            "stable above the estimate"
        );
    }
}
