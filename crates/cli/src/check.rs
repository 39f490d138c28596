//! `softbody check`: validate a scene and describe it.

use std::path::PathBuf;

use clap::Args;
use softbody::Model;
use softbody::cpu::stable_step::stable_dt_estimate;

use crate::args::StepOverrides;
use crate::{Failure, emit, load_with};

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
    let (model, state) = Model::build(&scene);
    let stable_dt = model.stable_dt();
    let stable_dt_estimate = stable_dt_estimate(&model, &state.x);
    let warnings = softbody::warnings::warnings_given(&model, &state.x, || stable_dt_estimate);
    let counts = model.spring_counts;
    let sim = &scene.simulation;
    let terrain: Vec<&str> = scene
        .terrain
        .iter()
        .map(|t| terrain_kind(&t.shape))
        .collect();
    if args.json {
        let value = serde_json::json!({
            "particles": model.len(),
            "springs": {
                "structural": counts.structural,
                "shear": counts.shear,
                "bending": counts.bending,
                "total": counts.total(),
            },
            "total_mass": scene.total_mass(),
            "stable_dt": stable_dt,
            "stable_dt_estimate": stable_dt_estimate,
            "bodies": model.bodies.iter().zip(&scene.bodies).map(|(b, body)| {
                let mut v = serde_json::json!({"name": b.name, "first": b.first, "count": b.count, "mass": body.mass()});
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
        });
        line!("{value}");
        return emit(&out);
    }
    line!("{}: valid", args.scene.display());
    line!("  particles   {}", model.len());
    for (b, body) in model.bodies.iter().zip(&scene.bodies) {
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
            "    {:<10} {} particles from {}, {} kg{how}",
            b.name,
            b.count,
            b.first,
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
    for w in &warnings {
        line!("  warning     {w}");
    }
    emit(&out)
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
