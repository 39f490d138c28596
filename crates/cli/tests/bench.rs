//! `softbody bench`: the JSON keys, finite figures, the table, and bad arguments.

mod common;

use common::*;
use serde_json::Value;

fn json_lines(out: &Outcome) -> Vec<Value> {
    out.stdout_text()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

fn positive_number(v: &Value, key: &str) -> f64 {
    let x = v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("`{key}` is not a number in {v}"));
    assert!(x.is_finite() && x > 0.0, "`{key}` = {x} in {v}");
    x
}

#[test]
fn json_has_one_line_per_size_with_the_documented_keys() {
    let sandbox = Sandbox::new();
    let out = sandbox.run(&["bench", "--sizes", "3,5", "--steps", "20", "--json"]);
    out.expect_status(EXIT_OK);
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 2);
    for (v, n) in lines.iter().zip([3u64, 5]) {
        assert_eq!(v["particles"].as_u64(), Some(n * n * n));
        assert_eq!(v["steps"].as_u64(), Some(20));
        let springs = v["springs"].as_u64().unwrap();
        // structural 3n²(n−1), shear 6n(n−1)² + 4(n−1)³, bending 3n²(n−2)
        let m = n - 1;
        assert_eq!(
            springs,
            3 * n * n * m + 6 * n * m * m + 4 * m * m * m + 3 * n * n * (n - 2)
        );
        let seconds = positive_number(v, "seconds");
        let p = positive_number(v, "particle_steps_per_s");
        let s = positive_number(v, "spring_steps_per_s");
        let bytes = positive_number(v, "bytes_per_particle");
        assert!((p * seconds / (20 * n * n * n) as f64 - 1.0).abs() < 1e-9);
        assert!((s / p - springs as f64 / (n * n * n) as f64).abs() < 1e-9);
        // At least what the lean model holds per particle (a cuboid's springs are a stencil,
        // no list): the model and both states of symplectic Euler.
        let lean = softbody::scene::model::lean_bytes_per_particle(
            softbody::scene::Integrator::SymplecticEuler,
        );
        assert!(bytes >= lean as f64, "{bytes} B");
        assert!(v.get("cg_iterations_per_step").is_none());
        assert_eq!(v["integrator"], "symplectic-euler");
        assert_eq!(v["backend"], "cpu");
    }
}

/// Implicit Euler on the stiff 4³ cube (k_s = 1e4 N/m, dt = 1/60 s), one thread, JSON.
const STIFF_CUBE: &[&str] = &[
    "bench",
    "--integrator",
    "implicit-euler",
    "--sizes",
    "4",
    "--stiffness",
    "1e4",
    "--dt",
    "1/60",
    "--threads",
    "1",
    "--json",
];

#[test]
fn implicit_reports_cg_iterations_and_takes_dt_and_stiffness() {
    let sandbox = Sandbox::new();
    let out = sandbox.run(&[STIFF_CUBE, &["--steps", "5"]].concat());
    out.expect_status(EXIT_OK);
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 1);
    let v = &lines[0];
    assert_eq!(v["dt"].as_f64(), Some(1.0 / 60.0));
    assert_eq!(v["stiffness"].as_f64(), Some(1e4));
    assert_eq!(v["device"], "CPU, 1 thread");
    assert_eq!(v["preconditioner"], "multigrid");
    // Its timed steps are at rest after the warm-up, where the warm start is the solution to
    // CG's tolerance: no iteration is a right answer, but every step solves at least once.
    // Both figures are counts over the timed steps divided by their number: whole counts.
    let steps = positive_number(v, "steps");
    let iterations = v["cg_iterations_per_step"].as_f64().expect("a number") * steps;
    let solves = positive_number(v, "cg_solves_per_step") * steps;
    assert!(
        iterations >= 0.0 && (iterations - iterations.round()).abs() < 1e-9,
        "{v}"
    );
    assert!(
        solves >= steps && (solves - solves.round()).abs() < 1e-9,
        "{v}"
    );
    positive_number(v, "particle_steps_per_s");
    positive_number(v, "bytes_per_particle");
}

#[test]
fn warmup_steps_fix_the_stretch_of_motion_that_is_timed() {
    // Implicit Euler's iterations per step depend on where the cube is in its fall: with the
    // warm-up and the timed steps both given, two runs time the same steps and count the same
    // iterations, bit for bit; another warm-up times another stretch.
    let sandbox = Sandbox::new();
    let run = |warmup: &str| {
        let out = sandbox.run(&[STIFF_CUBE, &["--steps", "12", "--warmup-steps", warmup]].concat());
        out.expect_status(EXIT_OK);
        let v = json_lines(&out).remove(0);
        assert_eq!(v["warmup_steps"].as_u64(), Some(warmup.parse().unwrap()));
        assert_eq!(v["steps"].as_u64(), Some(12));
        let figure = |key: &str| v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"));
        (
            figure("cg_iterations_per_step"),
            figure("cg_solves_per_step"),
        )
    };
    let falling = run("0");
    assert_eq!(run("0"), falling);
    let resting = run("300");
    assert_eq!(run("300"), resting);
    // The first steps fall from rest onto the ground: more iterations than at rest.
    assert!(falling.0 > resting.0, "{falling:?} {resting:?}");
}

#[test]
fn table_names_the_columns_and_each_size() {
    let sandbox = Sandbox::new();
    let out = sandbox.run(&["bench", "--sizes", "3,4", "--steps", "10"]);
    out.expect_status(EXIT_OK);
    let text = out.stdout_text();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 4, "{text}");
    assert!(lines[0].starts_with("symplectic-euler on cpu"), "{text}");
    assert!(lines[1].contains("particles") && lines[1].contains("Mparticle-st/s"));
    assert!(
        lines[2].split_whitespace().take(2).eq(["3", "27"]),
        "{text}"
    );
    assert!(
        lines[3].split_whitespace().take(2).eq(["4", "64"]),
        "{text}"
    );
}

#[test]
fn bad_arguments_are_bad_input() {
    let sandbox = Sandbox::new();
    for args in [
        &["bench", "--sizes", "1"][..],
        &["bench", "--sizes", "3,x"],
        &["bench", "--dt", "0"],
        &["bench", "--dt", "1/0"],
        &["bench", "--stiffness", "-5"],
        &["bench", "--steps", "0"],
        &["bench", "--warmup-steps", "-1"],
        &["bench", "--warmup-steps", "many"],
        &["bench", "--integrator", "leapfrog"],
        &["bench", "--gpu-route", "gather"],
        &["bench", "--backend", "gpu", "--gpu-route", "csr"],
    ] {
        let out = sandbox.run(args);
        out.expect_status(EXIT_BAD_INPUT);
        assert!(out.stdout.is_empty(), "{args:?}");
    }
}

#[test]
fn an_unstable_step_is_exit_status_3() {
    // Explicit Euler at a step a hundred times the stable one blows up within the timed steps.
    let sandbox = Sandbox::new();
    let out = sandbox.run(&[
        "bench",
        "--integrator",
        "explicit-euler",
        "--sizes",
        "4",
        "--dt",
        "0.05",
        "--steps",
        "2000",
    ]);
    out.expect_status(EXIT_UNSTABLE);
    assert!(out.stderr.contains("4³ cube"), "{}", out.stderr);
}

/// `--contact` times each size without and then with self-contact; the run with it holds the
/// broad phase's buffers too.
#[test]
fn contact_times_each_size_without_and_with_self_contact() {
    let sandbox = Sandbox::new();
    let out = sandbox.run(&[
        "bench",
        "--sizes",
        "4",
        "--steps",
        "10",
        "--contact",
        "--json",
    ]);
    out.expect_status(EXIT_OK);
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0]["self_contact"], false);
    assert_eq!(lines[1]["self_contact"], true);
    let bytes = |v: &Value| positive_number(v, "bytes_per_particle");
    assert!(bytes(&lines[1]) > bytes(&lines[0]), "{lines:?}");
    let table = sandbox.run(&["bench", "--sizes", "4", "--steps", "10", "--contact"]);
    table.expect_status(EXIT_OK);
    let text = table.stdout_text();
    assert!(text.contains("% time"), "{text}");
}

#[test]
fn block_jacobi_is_selectable_and_reported() {
    let sandbox = Sandbox::new();
    let out = sandbox.run(&[
        "bench",
        "--integrator",
        "implicit-euler",
        "--preconditioner",
        "block-jacobi",
        "--sizes",
        "4",
        "--steps",
        "3",
        "--threads",
        "1",
    ]);
    out.expect_status(EXIT_OK);
    let text = out.stdout_text();
    assert!(
        text.starts_with("implicit-euler (block-jacobi preconditioner) on cpu"),
        "{text}"
    );
    let out = sandbox.run(&["bench", "--preconditioner", "amg", "--sizes", "4"]);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        out.stderr.contains("unknown preconditioner `amg`"),
        "{}",
        out.stderr
    );
}

/// `--gpu-route` times each of the GPU's designs of a symplectic step on one adapter and says
/// which ran: the fused stencil and the fused gather take one dispatch a step, the per-spring
/// path five (forces, gather, and the update's three per-particle kernels), and their traffic
/// per particle-step grows in that order (records on the lattice; the spring list and the
/// adjacency; per-spring forces written and gathered).
#[test]
fn the_gpu_routes_are_timed_and_named() {
    let sandbox = Sandbox::new();
    let mut bytes = Vec::new();
    for (route, kernel, dispatches) in [
        ("auto", "fused stencil", 1.0),
        ("gather", "fused gather", 1.0),
        ("per-spring", "per-spring + gather", 5.0),
    ] {
        let args = [
            "bench",
            "--backend",
            "gpu",
            "--gpu-route",
            route,
            "--sizes",
            "6",
            "--steps",
            "10",
            "--json",
        ];
        let out = sandbox.run(&args);
        out.expect_status(EXIT_OK);
        let lines = json_lines(&out);
        assert_eq!(lines.len(), 1);
        let v = &lines[0];
        assert_eq!(v["gpu_route"], route);
        assert_eq!(v["kernel"], kernel);
        assert_eq!(positive_number(v, "dispatches_per_step"), dispatches, "{v}");
        bytes.push(positive_number(v, "bytes_per_particle_step"));
    }
    assert!(bytes[0] < bytes[1] && bytes[1] < bytes[2], "{bytes:?}");
}
