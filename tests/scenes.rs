//! Every scene shipped in `scenes/` loads, builds and steps, on every backend: each is run for
//! its first 0.5 s of simulated time (every jelly has landed by then) and must stay finite, keep
//! every particle out of the terrain (deeper than the contact distance, measured with the CPU's
//! exact queries; on the GPU, mesh terrain is a signed-distance grid whose error near edges is
//! up to h·√3/2, h its cell: that is allowed on top), not gain energy, and, for the explicit
//! integrators, use a step within `softbody check`'s stable-step estimate.
//!
//! One trial per scene and backend (`gpu::every_scene_loads_builds_and_steps::pile-in-bowl`);
//! the pile's GPU trial is heavy. A scene added to `scenes/` is picked up automatically; the
//! scenes the README lists must exist.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use softbody::scene::TerrainShape;
use softbody::terrain::Surface;
use softbody::terrain::sdf::SdfGrid;
use softbody::{Integrator, Model, Scene};
use softbody_testkit::{Backend, Failed, Kind, Law, all};

fn main() -> ExitCode {
    let names = scene_files()
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    softbody_testkit::run(
        "scenes",
        [
            Law::new("the_documented_scenes_exist", the_documented_scenes_exist).only_on(Kind::Cpu),
            Law::per_case(
                "every_scene_loads_builds_and_steps",
                names,
                the_scene_loads_builds_and_steps,
            )
            // 5,000 steps of six cubes in contact: most of a minute of lavapipe.
            .heavy_case(Kind::Gpu, "pile-in-bowl"),
        ],
    )
}

/// Simulated time each scene is stepped for, seconds.
const SIMULATED: f64 = 0.5;

/// The scenes the README's table lists.
const DOCUMENTED: [&str; 13] = [
    "jelly-on-ground",
    "jelly-on-slope",
    "jelly-on-slope-sticky",
    "jelly-in-bowl",
    "jelly-on-stairs",
    "jelly-on-heightfield",
    "jelly-on-mesh",
    "stiff-cube-implicit",
    "two-cubes-head-on",
    "pile-in-bowl",
    "bar-folding",
    "torus-on-stairs",
    "star-on-heightfield",
];

fn scene_files() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot list {}: {e}", dir.display()))
        .map(|entry| entry.expect("directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
}

/// Runs one scene for [`SIMULATED`] seconds; the error says what went wrong.
/// How far inside the terrain the backend may leave a particle beyond the contact distance: its
/// mesh terrain's grid error on the GPU (none on the CPU, whose queries are exact).
fn terrain_allowance(backend: &Backend, scene: &Scene) -> f64 {
    if !backend.is_gpu() {
        return 0.0;
    }
    scene
        .terrain
        .iter()
        .filter_map(|t| match &t.shape {
            TerrainShape::Mesh(mesh) => {
                let grid = SdfGrid::for_vertices(&mesh.vertices);
                Some(grid.cell * 3f64.sqrt() / 2.0)
            }
            _ => None,
        })
        .fold(0.0, f64::max)
}

fn check(backend: &Backend, path: &Path) -> Result<String, String> {
    let scene = Scene::from_file(path).map_err(|e| format!("does not load: {e}"))?;
    let sim = scene.simulation;
    let (model, _) = Model::build(&scene);
    let explicit = sim.integrator != Integrator::ImplicitEuler;
    if let Some(limit) = model
        .stable_dt()
        .filter(|&limit| explicit && sim.dt > limit)
    {
        return Err(format!(
            "dt = {} s is above the stable estimate {limit:.3e} s of `softbody check`",
            sim.dt
        ));
    }
    let surfaces: Vec<Surface> = scene.terrain.iter().map(Surface::new).collect();
    let eps = sim.contact_distance;

    let mut solver = backend
        .solver(&scene)
        .map_err(|e| e.message().unwrap_or("cannot open a solver").to_owned())?;
    let e0 = solver.energies().map_err(|e| e.to_string())?;
    let steps = ((SIMULATED / sim.dt).round() as u64).clamp(1, sim.steps().max(1));
    solver
        .advance(steps)
        .map_err(|e| format!("step failed: {e}"))?;
    let e = solver.energies().map_err(|e| e.to_string())?;
    let state = solver.state().map_err(|e| e.to_string())?;

    if let Some(i) =
        (0..state.x.len()).find(|&i| !state.x[i].is_finite() || !state.v[i].is_finite())
    {
        return Err(format!("particle {i} is not finite after {steps} steps"));
    }
    let mut deepest = f64::INFINITY;
    for x in &state.x {
        for s in &surfaces {
            if let Some(c) = s.query(*x, 0.0) {
                deepest = deepest.min(c.phi);
            }
        }
    }
    let allowed = eps + terrain_allowance(backend, &scene);
    if deepest < -allowed {
        return Err(format!(
            "a particle is {:.3e} m inside the terrain, deeper than {allowed} m",
            -deepest
        ));
    }
    let (before, after) = (e0.total(), e.total());
    if !after.is_finite() || after > before + 0.01 * before.abs().max(1.0) {
        return Err(format!(
            "total energy went from {before:.6e} J to {after:.6e} J"
        ));
    }
    let depth = if deepest < 0.0 {
        format!("deepest particle {:.2e} m inside", -deepest)
    } else {
        "no particle inside the terrain".to_owned()
    };
    Ok(format!(
        "{steps} steps of {}, {depth}, E {before:.3} → {after:.3} J",
        sim.integrator
    ))
}

fn the_documented_scenes_exist(_: &Backend) -> Result<(), Failed> {
    let names: Vec<String> = scene_files()
        .iter()
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    let missing: Vec<String> = DOCUMENTED
        .iter()
        .filter(|want| !names.iter().any(|n| n == *want))
        .map(|want| format!("scenes/{want}.toml is missing (found {names:?})"))
        .collect();
    all(missing)
}

fn the_scene_loads_builds_and_steps(backend: &Backend, name: &str) -> Result<(), Failed> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
    let summary = check(backend, &path).map_err(|why| format!("{}: {why}", path.display()))?;
    println!("{} on {}: {summary}", path.display(), backend.name());
    Ok(())
}
