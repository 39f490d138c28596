//! `softbody::grad`: each key's derivative, through the scene's own building, against central
//! differences of the run with the key set by `--set` to its value ± δ; the keys refused.
//!
//! The loss is the built-in |c − target|². δ = 1e-6 of the key's scale: the central
//! difference's truncation error (δ²/6·|L'''|) is below 1e-9 of the derivatives here, and its
//! rounding error is ~1e-13·|L|/δ (a run's loss is good to ~1e-13 of itself); the tolerance is
//! 1e-6 relative over that floor (see
//! crates/cpu/tests/adjoint/ for the cases' choice: away from the contact laws' jumps).

use std::path::{Path, PathBuf};

use glam::DVec3;
use softbody::grad::{Derivative, GradRequest, Target, gradient};
use softbody::{CpuSolver, Model, Setting, Solver};

const TARGET: DVec3 = DVec3::new(0.4, 0.3, -0.1);

/// A cube thrown into the air (free flight), or sliding down a 20° slope.
fn scene(dir: &Path, slope: bool) -> PathBuf {
    let terrain = if slope {
        "[[terrain]]\nkind = \"plane\"\nnormal = [0.36397023426620234, 1.0, 0.0]\n\
         friction = 0.1\nrestitution = 0.3\n"
    } else {
        ""
    };
    let (center, velocity) = if slope {
        ("[0.053, 0.1457, 0.0]", "[0.3759, -0.1368, 0.1]")
    } else {
        ("[0.0, 1.0, 0.0]", "[0.4, 1.5, 0.2]")
    };
    let text = format!(
        "[simulation]\nintegrator = \"rk4\"\ndt = 1e-3\nduration = 0.1\nframe_rate = 100.0\n\
         gravity = [0.0, -9.81, 0.0]\ndrag = 0.2\ncontact_distance = 0.03\n\
         [[body]]\nkind = \"cuboid\"\nsize = [0.3, 0.3, 0.3]\nresolution = [3, 3, 3]\n\
         center = {center}\nrotation = [0.0, 0.0, -20.0]\nmass = 2.7\nvelocity = {velocity}\n\
         structural = {{ stiffness = 900.0, damping = 2.0 }}\n\
         shear = {{ stiffness = 700.0, damping = 1.5 }}\n\
         bending = {{ stiffness = 400.0, damping = 1.0 }}\n{terrain}"
    );
    let path = dir.join(if slope { "slope.toml" } else { "flight.toml" });
    std::fs::write(&path, text).unwrap();
    path
}

/// |c − TARGET|² at the last frame of the run with `settings`.
fn loss(path: &Path, settings: &[Setting]) -> f64 {
    let scene = softbody::load_scene(path, settings).unwrap();
    let (model, state) = Model::build(&scene);
    let steps = model
        .simulation
        .frame_step(model.simulation.frame_count() - 1);
    let mass = model.mass.clone();
    let mut solver = CpuSolver::new(model, state, Some(1)).unwrap();
    solver.advance(steps).unwrap();
    let x = &solver.state().unwrap().x;
    let total: f64 = mass.iter().sum();
    let c = x
        .iter()
        .zip(&mass)
        .fold(DVec3::ZERO, |s, (x, m)| s + *m * *x)
        / total;
    (c - TARGET).length_squared()
}

fn value(v: &[f64]) -> toml::Value {
    if v.len() == 1 {
        toml::Value::Float(v[0])
    } else {
        toml::Value::Array(v.iter().map(|&x| toml::Value::Float(x)).collect())
    }
}

/// ∂L/∂key by central differences about `at` (the key's value in the scene), component `k`.
fn central(path: &Path, key: &str, at: &[f64], k: usize) -> f64 {
    let delta = 1e-6 * at[k].abs().max(1.0);
    let with = |s: f64| {
        let mut v = at.to_vec();
        v[k] += s;
        loss(path, &[Setting::new(key, value(&v)).unwrap()])
    };
    (with(delta) - with(-delta)) / (2.0 * delta)
}

fn request(path: &Path, wrt: &[&str]) -> GradRequest {
    GradRequest {
        scene: path.to_owned(),
        settings: Vec::new(),
        wrt: wrt.iter().map(|k| k.to_string()).collect(),
        target: Target::Com(TARGET),
        threads: Some(1),
        ..GradRequest::default()
    }
}

fn check_keys(path: &Path, keys: &[(&str, &[f64])]) {
    let names: Vec<&str> = keys.iter().map(|(k, _)| *k).collect();
    let report = gradient(&request(path, &names)).unwrap();
    assert!((report.loss - loss(path, &[])).abs() <= 1e-12 * report.loss);
    let mut failures = Vec::new();
    for ((key, at), (name, d)) in keys.iter().zip(&report.gradient) {
        assert_eq!(key, name);
        let adjoint: Vec<f64> = match d {
            Derivative::Scalar(x) => vec![*x],
            Derivative::Vector(v) => v.to_array().to_vec(),
        };
        assert_eq!(adjoint.len(), at.len(), "{key}");
        for k in 0..at.len() {
            let fd = central(path, key, at, k);
            // 1e-6 relative, over the differences' rounding floor: the loss of a 100-step run
            // is good to ~1e-13 of itself, divided by δ.
            let floor = 1e-13 * report.loss / (1e-6 * at[k].abs().max(1.0));
            if (adjoint[k] - fd).abs() > 1e-6 * adjoint[k].abs().max(fd.abs()) + floor {
                failures.push(format!(
                    "{key}[{k}]: adjoint {:e}, differences {fd:e}",
                    adjoint[k]
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn every_key_in_free_flight_is_the_derivative_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = scene(dir.path(), false);
    check_keys(
        &path,
        &[
            ("body[0].mass", &[2.7]),
            ("body[0].structural.stiffness", &[900.0]),
            ("body[0].structural.damping", &[2.0]),
            ("body[0].shear.stiffness", &[700.0]),
            ("body[0].shear.damping", &[1.5]),
            ("body[0].bending.stiffness", &[400.0]),
            ("body[0].bending.damping", &[1.0]),
            ("body[0].center", &[0.0, 1.0, 0.0]),
            ("body[0].velocity", &[0.4, 1.5, 0.2]),
            ("simulation.gravity", &[0.0, -9.81, 0.0]),
            ("simulation.drag", &[0.2]),
        ],
    );
}

/// Two particles falling at 3 m/s onto the top corners of a cube held by its bottom ones
/// (the impact between bodies of crates/cpu/tests/adjoint/): fresh impacts with restitution and
/// friction, whose impulses reach the loss through the pinned particles (between free bodies
/// they would leave the centre of mass where it is).
#[test]
fn the_body_contact_keys_are_the_derivative_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("impact.toml");
    let text = "[simulation]\nintegrator = \"rk4\"\ndt = 1e-3\nduration = 0.03\n\
                frame_rate = 100.0\ndrag = 0.2\nbody_restitution = 0.5\nbody_friction = 0.2\n\
                [[body]]\nkind = \"cuboid\"\nsize = [0.06, 0.06, 0.06]\nresolution = [2, 2, 2]\n\
                center = [0.0, 0.0, 0.0]\nmass = 0.8\ncontact_radius = 0.005\n\
                pinned = [0, 1, 4, 5]\nstructural = { stiffness = 900.0, damping = 2.0 }\n\
                [[body]]\nkind = \"particles\"\n\
                positions = [[-0.025, 0.06624, -0.03], [0.03, 0.06786, -0.0285]]\n\
                masses = [0.3, 0.4]\nvelocities = [[0.0, -3.0, 0.0], [0.0, -3.0, 0.0]]\n\
                contact_radius = 0.005\n\
                springs = [{ a = 0, b = 1, stiffness = 200.0, damping = 0.1 }]\n";
    std::fs::write(&path, text).unwrap();
    check_keys(
        &path,
        &[
            ("simulation.body_friction", &[0.2]),
            ("simulation.body_restitution", &[0.5]),
            ("body[0].mass", &[0.8]),
            ("body[0].structural.stiffness", &[900.0]),
        ],
    );
}

#[test]
fn the_terrain_keys_on_a_slope_are_the_derivative_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = scene(dir.path(), true);
    check_keys(
        &path,
        &[
            ("terrain[0].friction", &[0.1]),
            ("terrain[0].restitution", &[0.3]),
            ("body[0].structural.stiffness", &[900.0]),
            ("simulation.gravity", &[0.0, -9.81, 0.0]),
        ],
    );
    // Without contact between bodies, their laws change nothing: exactly zero.
    let report = gradient(&request(&path, &["simulation.body_friction"])).unwrap();
    assert_eq!(report.gradient[0].1, Derivative::Scalar(0.0));
}

#[test]
fn other_keys_and_scenes_are_refused_as_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let path = scene(dir.path(), false);
    for key in [
        "body[0].size",
        "simulation.dt",
        "body[00].mass",
        "body0.mass",
        "mass",
    ] {
        let e = gradient(&request(&path, &[key])).unwrap_err();
        assert_eq!(e.status(), 2, "{key}: {e}");
        assert!(
            e.to_string().contains("body[N].structural.stiffness"),
            "{e}"
        );
    }
    let e = gradient(&request(&path, &["body[1].mass"])).unwrap_err();
    assert!(e.to_string().contains("the scene has 1 bodies"), "{e}");
}

/// A mesh body weighed by its density, hanging from a pinned particle (in free flight the
/// centre's path would not depend on the mass): ∂L/∂ρ is the run's derivative (central
/// differences),
/// and V·∂L/∂m of the same body weighed by its mass M = ρV (the chain rule through M = ρV; the
/// two models differ by the rounding of M, so the two agree to ~1e-15).
#[test]
fn a_mesh_bodys_density_is_its_mass_over_its_volume() {
    let dir = tempfile::tempdir().unwrap();
    let star = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/star.obj");
    let write = |name: &str, weight: &str| {
        let text = format!(
            "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 1e-3\nduration = 0.1\n\
             frame_rate = 100.0\n[[body]]\nkind = \"mesh\"\nfile = \"{star}\"\n\
             resolution = 4\ncenter = [0.0, 1.0, 0.0]\nvelocity = [0.4, 0.0, 0.2]\npinned = [0]\n\
             {weight}\n\
             structural = {{ stiffness = 375.0, damping = 3.75 }}\n"
        );
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let by_density = write("density.toml", "density = 400.0");
    check_keys(&by_density, &[("body[0].density", &[400.0])]);
    let scene = softbody::load_scene(&by_density, &[]).unwrap();
    let mass: f64 = Model::build(&scene).0.mass.iter().sum();
    let by_mass = write("mass.toml", &format!("mass = {mass:?}"));
    let d = |path: &Path, key: &str| match gradient(&request(path, &[key])).unwrap().gradient[0].1 {
        Derivative::Scalar(x) => x,
        Derivative::Vector(_) => unreachable!("a scalar key"),
    };
    let (by_rho, by_m) = (
        d(&by_density, "body[0].density"),
        d(&by_mass, "body[0].mass"),
    );
    let volume = mass / 400.0;
    // Not a derivative lost in the differences' rounding floor (check_keys's, 1e-13·L/δ): the
    // hanging body's sag depends on its mass.
    let loss = gradient(&request(&by_density, &["body[0].density"]))
        .unwrap()
        .loss;
    assert!(
        by_rho.abs() > 1e3 * 1e-13 * loss / (1e-6 * 400.0),
        "∂L/∂ρ = {by_rho:e}, L = {loss:e}"
    );
    assert!(
        (by_rho - volume * by_m).abs() <= 1e-12 * by_rho.abs(),
        "∂L/∂ρ = {by_rho:e}, V ∂L/∂m = {:e}",
        volume * by_m
    );
}
