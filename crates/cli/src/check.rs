//! `softbody check`: validate a scene and describe it.

use std::path::PathBuf;

use clap::Args;
use glam::DVec3;
use softbody::cpu::stable_step::stable_dt_estimate;
use softbody::warnings::Warning;
use softbody::{Model, Scene};

use crate::args::StepOverrides;
use crate::{Failure, emit, estimate, load_with};

#[derive(Args)]
pub struct CheckArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
    // Last: the heading applies to every option after it.
    #[command(flatten, next_help_heading = "Overrides of the scene (as for run)")]
    overrides: StepOverrides,
}

pub fn check(args: CheckArgs) -> Result<(), Failure> {
    let scene = load_with(&args.scene, &args.overrides.settings())?;
    // Printed in one write at the end, so that a closed pipe (`| head -1`) is one error to
    // handle instead of a panic in `println!`.
    let mut out = String::new();
    macro_rules! line {
        ($($arg:tt)*) => {{
            out.push_str(&format!($($arg)*));
            out.push('\n');
        }};
    }
    // A model of the scene is what a run holds: large cuboids are described from their counts
    // and their stable step found on a piece of their lattice (`estimate::pieces`).
    let pieces = estimate::pieces(&scene);
    let (model, state) = Model::build(pieces.as_ref().unwrap_or(&scene));
    let stable_dt = model.stable_dt();
    let stable_dt_estimate = stable_dt_estimate(&model, &state.x);
    let warnings = if pieces.is_some() {
        let mut found = whole_inside_terrain(&scene, &model, &state.x);
        found.extend(softbody::warnings::step_above_stable(&model, || {
            stable_dt_estimate
        }));
        found
    } else {
        softbody::warnings::warnings_given(&model, &state.x, || stable_dt_estimate)
    };
    let cost = estimate::cost(&scene);
    let counts = scene.spring_counts();
    let bodies = body_ranges(&scene);
    let sim = &scene.simulation;
    let terrain: Vec<&str> = scene
        .terrain
        .iter()
        .map(|t| terrain_kind(&t.shape))
        .collect();
    if args.json {
        let value = serde_json::json!({
            "particles": scene.particle_count(),
            "springs": {
                "structural": counts.structural,
                "shear": counts.shear,
                "bending": counts.bending,
                "total": counts.total(),
            },
            "total_mass": scene.total_mass(),
            "stable_dt": stable_dt,
            "stable_dt_estimate": stable_dt_estimate,
            "bodies": bodies.iter().zip(&scene.bodies).map(|((first, count), body)| {
                let mut v = serde_json::json!({"name": body.name, "first": first, "count": count, "mass": body.mass()});
                if let Some(weighed) = weighed(body) {
                    v["density"] = weighed.density.into();
                    v["volume"] = weighed.volume.into();
                    v["volume_of"] = weighed.of().into();
                }
                v
            }).collect::<Vec<_>>(),
            "terrain": terrain,
            "integrator": sim.integrator.name(),
            "dt": sim.dt,
            "steps": sim.steps(),
            "frames": sim.frame_count(),
            "warnings": warnings.iter().map(ToString::to_string).collect::<Vec<_>>(),
            "estimates": {
                "memory_bytes": cost.memory,
                "memory_available_bytes": cost.available.map(|(bytes, _)| bytes),
                "output_bytes": cost.output,
                "seconds": cost.seconds,
            },
        });
        line!("{value}");
        return emit(&out);
    }
    line!("{}: valid", args.scene.display());
    line!("  particles   {}", scene.particle_count());
    for ((first, count), body) in bodies.iter().zip(&scene.bodies) {
        let how = weighed(body).map_or(String::new(), |w| {
            let of = if w.enclosed {
                "the mesh encloses"
            } else {
                "of its kept cells: the mesh is not closed"
            };
            format!(
                " ({} kg/m³ × {} m³ {of})",
                w.density,
                twelve_digits(w.volume)
            )
        });
        line!(
            "    {:<10} {count} particles from {first}, {} kg{how}",
            body.name,
            twelve_digits(body.mass())
        );
    }
    line!(
        "  springs     {} ({} structural, {} shear, {} bending)",
        counts.total(),
        counts.structural,
        counts.shear,
        counts.bending
    );
    line!("  total mass  {} kg", twelve_digits(scene.total_mass()));
    line!(
        "  terrain     {}",
        if terrain.is_empty() {
            "none".to_owned()
        } else {
            terrain.join(", ")
        }
    );
    line!(
        "  integrator  {}, dt = {} s, {} steps, {} frames",
        sim.integrator,
        sim.dt,
        sim.steps(),
        sim.frame_count()
    );
    match (stable_dt, stable_dt_estimate) {
        (Some(bound), Some(estimate)) => line!(
            "  stable dt   about {estimate:.3e} s for the explicit integrators (the springs' \
             stiffest mode), {bound:.3e} s guaranteed (a conservative bound); implicit-euler: any"
        ),
        _ => line!("  stable dt   unlimited (no springs)"),
    }
    let available = cost.available.map_or(String::new(), |(bytes, what)| {
        format!(" ({} {what})", estimate::human_bytes(bytes))
    });
    line!(
        "  memory      about {} for the CPU solver{available}",
        estimate::human_bytes(cost.memory)
    );
    line!(
        "  output      about {} as JSON Lines ({} frames of {} particles, {} B each)",
        estimate::human_bytes(cost.output),
        sim.frame_count(),
        scene.particle_count(),
        estimate::JSONL_BYTES_PER_PARTICLE
    );
    line!(
        "  run time    about {} of stepping on two CPU cores (an estimate at {:.1e} \
         particle-steps/s, the slow end of BENCHMARKS.md for {}; contacts and small bodies run \
         slower, more cores faster)",
        estimate::human_seconds(cost.seconds),
        estimate::particle_steps_per_second(sim.integrator),
        sim.integrator
    );
    for w in &warnings {
        line!("  warning     {w}");
    }
    emit(&out)
}

/// Each body's first particle and count, in file order (particles are numbered body by body).
fn body_ranges(scene: &Scene) -> Vec<(u64, u64)> {
    let mut first = 0;
    scene
        .bodies
        .iter()
        .map(|body| {
            let range = (first, body.particle_count());
            first += range.1;
            range
        })
        .collect()
}

/// The bodies of `scene` that start inside its terrain, where `model` (at positions `x`) is a
/// model of its pieces: the cuboids cut to a piece are placed whole, one at a time, and the
/// other bodies are the model's own.
fn whole_inside_terrain(scene: &Scene, model: &Model, x: &[DVec3]) -> Vec<Warning> {
    use softbody::scene::BodyShape;
    let mut found = Vec::new();
    for (body, range) in scene.bodies.iter().zip(&model.bodies) {
        let own = &x[range.first as usize..(range.first + range.count) as usize];
        let placed = match &body.shape {
            BodyShape::Cuboid(c) if u64::from(range.count) != body.particle_count() => {
                std::borrow::Cow::Owned(softbody::scene::topology::cuboid_positions(c))
            }
            _ => std::borrow::Cow::Borrowed(own),
        };
        found.extend(softbody::warnings::body_inside_terrain(
            &scene.terrain,
            &body.name,
            &placed,
        ));
    }
    found
}

/// A mesh body's mass given as a density: the density and the volume it weighed, the one the
/// mesh encloses or, for a mesh that is not closed, its kept cells'.
struct Weighed {
    density: f64,
    volume: f64,
    enclosed: bool,
}

impl Weighed {
    /// The JSON's name for what the volume is of.
    fn of(&self) -> &'static str {
        if self.enclosed { "mesh" } else { "cells" }
    }
}

fn weighed(body: &softbody::scene::Body) -> Option<Weighed> {
    use softbody::scene::{BodyShape, MeshMass};
    match &body.shape {
        BodyShape::Mesh(m) => match m.mass {
            MeshMass::Density(density) => Some(Weighed {
                density,
                volume: m.solid_volume(),
                enclosed: m.voxels.enclosed_volume().is_some(),
            }),
            MeshMass::Mass(_) => None,
        },
        _ => None,
    }
}

/// `x` to twelve significant digits, shortest: a sum of the particles' masses shows the mass
/// the scene gave (37.888), not its rounding (37.888000000000005).
fn twelve_digits(x: f64) -> f64 {
    format!("{x:.11e}").parse().unwrap_or(x)
}

fn terrain_kind(shape: &softbody::scene::TerrainShape) -> &'static str {
    use softbody::scene::TerrainShape::*;
    match shape {
        Plane { .. } => "plane",
        Box { .. } => "box",
        Sphere { .. } => "sphere",
        Bowl { .. } => "bowl",
        Heightfield(_) => "heightfield",
        Mesh(_) => "mesh",
    }
}

#[cfg(test)]
mod tests {
    use super::twelve_digits;

    #[test]
    fn twelve_digits_drop_the_rounding_of_a_sum() {
        // `check`'s sum over the 936 particles of a 37.888 kg torus.
        let torus = 37.888000000000005;
        assert_ne!(torus, 37.888);
        assert_eq!(twelve_digits(torus).to_string(), "37.888");
        assert_eq!(twelve_digits(0.1 + 0.2).to_string(), "0.3");
        assert_eq!(twelve_digits(3e-30 + 1e-45), 3e-30);
        assert_eq!(twelve_digits(123_456_789_012_345.0), 123_456_789_012_000.0);
        assert_eq!(twelve_digits(0.0), 0.0);
    }
}
