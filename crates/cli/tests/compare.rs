//! `softbody compare`: JSON with one run per integrator × dt and the documented keys, a PNG plot
//! of the standard size that decodes, and the exit statuses of bad input and unwritable plots.

mod common;

use common::*;
use serde_json::Value;

/// A small cube dropped on the ground: 27 particles, 0.1 s (100 steps at 1e-3 s).
fn cube() -> Cube {
    Cube {
        duration: 0.1,
        frame_rate: 50.0,
        ..Cube::default()
    }
}

const RUN_KEYS: [&str; 17] = [
    "integrator",
    "dt",
    "steps",
    "planned_steps",
    "seconds",
    "steps_per_second",
    "unstable",
    "comparable",
    "not_comparable",
    "max_error",
    "max_error_time",
    "energy_drift",
    "deepest_penetration",
    "final_max_speed",
    "final_kinetic_energy",
    "at_rest",
    "series",
];

#[test]
fn json_has_one_run_per_integrator_and_dt() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &cube().toml());
    let out = sandbox.run(&[
        "compare".as_ref(),
        scene.as_os_str(),
        "--integrators".as_ref(),
        "explicit-euler,rk4,implicit-euler".as_ref(),
        "--dt".as_ref(),
        "1e-3,5e-4".as_ref(),
        "--threads".as_ref(),
        "1".as_ref(),
        "--json".as_ref(),
        "--quiet".as_ref(),
    ]);
    out.expect_status(EXIT_OK);
    assert!(out.stderr.is_empty(), "--quiet: {}", out.stderr);
    let v: Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    for key in [
        "scene",
        "particles",
        "duration",
        "frame_rate",
        "backend",
        "device",
        "energy_scale",
        "rest_speed",
        "reference",
        "runs",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    assert_eq!(v["particles"], 27);
    assert_eq!(v["backend"], "cpu");
    let reference = &v["reference"];
    assert_eq!(reference["integrator"], "rk4");
    assert_eq!(reference["dt"].as_f64(), Some(5e-4 / 16.0));
    assert_eq!(reference["check_dt"].as_f64(), Some(5e-4 / 8.0));
    assert!(reference["error_estimate"].as_f64().unwrap() >= 0.0);
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 6);
    let mut pairs = Vec::new();
    for run in runs {
        for key in RUN_KEYS {
            assert!(run.get(key).is_some(), "run without {key}: {run}");
        }
        pairs.push((
            run["integrator"].as_str().unwrap().to_owned(),
            run["dt"].as_f64().unwrap(),
        ));
        let series = &run["series"];
        let frames = series["time"].as_array().unwrap().len();
        assert_eq!(series["error"].as_array().unwrap().len(), frames);
        assert_eq!(series["energy"].as_array().unwrap().len(), frames);
        if run["unstable"].is_null() {
            assert_eq!(frames, 6, "0.1 s at 50 frames/s");
            assert_eq!(run["steps"], run["planned_steps"]);
        }
        // The cube lands on the ground plane: a penetration figure, never deep.
        assert!(run["deepest_penetration"].as_f64().unwrap() > -0.01);
    }
    let names = ["explicit-euler", "rk4", "implicit-euler"];
    let expected: Vec<(String, f64)> = names
        .iter()
        .flat_map(|n| [(n.to_string(), 1e-3), (n.to_string(), 5e-4)])
        .collect();
    assert_eq!(pairs, expected);
}

#[test]
fn table_lists_every_run_with_units() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &cube().toml());
    let out = sandbox.run(&[
        "compare".as_ref(),
        scene.as_os_str(),
        "--threads".as_ref(),
        "1".as_ref(),
    ]);
    out.expect_status(EXIT_OK);
    let text = out.stdout_text();
    assert!(
        text.contains("reference: rk4 at dt = 6.2500e-5 s"),
        "{text}"
    );
    assert!(
        text.contains("max error [m]") && text.contains("dt [s]"),
        "{text}"
    );
    for name in [
        "explicit-euler",
        "symplectic-euler",
        "midpoint",
        "rk4",
        "implicit-euler",
    ] {
        assert!(
            text.lines().any(|l| l.starts_with(name)),
            "{name} row: {text}"
        );
    }
    // Not a terminal: no bar, but the summary line.
    assert!(out.stderr.contains("5 runs"), "{}", out.stderr);
}

#[test]
fn plot_writes_a_png_that_decodes() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &cube().toml());
    let out = sandbox.run(&[
        "compare",
        scene.to_str().unwrap(),
        "--integrators",
        "symplectic-euler,midpoint",
        "--threads",
        "1",
        "--quiet",
        "--plot",
        "plot.png",
    ]);
    out.expect_status(EXIT_OK);
    let file = std::fs::File::open(sandbox.path().join("plot.png")).expect("the plot");
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .expect("a PNG");
    let mut pixels = vec![
        0;
        reader
            .output_buffer_size()
            .expect("image size fits in memory")
    ];
    let info = reader.next_frame(&mut pixels).expect("decodes");
    assert_eq!((info.width, info.height), (1200, 900));
    // Not blank: white background with coloured lines and dark text.
    let dark = pixels
        .chunks(3)
        .filter(|p| p.iter().all(|&c| c < 80))
        .count();
    assert!(dark > 1000, "{dark} dark pixels");
}

#[test]
fn bad_input_exits_2() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &cube().toml());
    let scene = scene.to_str().unwrap();
    for (args, message) in [
        (
            vec!["compare", scene, "--integrators", "leapfrog"],
            "unknown integrator",
        ),
        (vec!["compare", scene, "--dt", "0"], "greater than zero"),
        (
            vec!["compare", scene, "--dt", "-0.001"],
            "greater than zero",
        ),
        (vec!["compare", scene, "--dt", "1e-3,abc"], "abc"),
        // 50 frames/s needs dt ≤ 0.02 s: the scene is invalid with this dt.
        (vec!["compare", scene, "--dt", "0.05"], "frame_rate"),
        (vec!["compare", "missing.toml"], "missing.toml"),
    ] {
        let out = sandbox.run(&args);
        out.expect_status(EXIT_BAD_INPUT);
        assert!(
            out.stderr.contains(message),
            "{args:?}: expected `{message}` in {}",
            out.stderr
        );
    }
}

#[test]
fn unwritable_plot_exits_1() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &cube().toml());
    let out = sandbox.run(&[
        "compare",
        scene.to_str().unwrap(),
        "--quiet",
        "--plot",
        "no/such/dir/plot.png",
    ]);
    out.expect_status(EXIT_OUTPUT);
    assert!(
        out.stderr.contains("cannot write the plot"),
        "{}",
        out.stderr
    );
}

/// Two particles on a very stiff spring (k = 10⁶ N/m, ω₀ = 1414 rad/s), no gravity.
const STIFF: &str = r#"
[simulation]
integrator = "rk4"
dt = 0.001
duration = 1.0
frame_rate = 2.0
gravity = [0.0, 0.0, 0.0]
[[body]]
kind = "particles"
positions = [[0.0, 0.0, 0.0], [1.1, 0.0, 0.0]]
masses = [1.0, 1.0]
springs = [{ a = 0, b = 1, stiffness = 1e6, damping = 0.0, rest = 1.0 }]
"#;

/// Runs that diverge are results: exit 0, and `unstable` names the step and time.
#[test]
fn unstable_runs_exit_0_and_are_reported() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("stiff.toml", STIFF);
    let out = sandbox.run(&[
        "compare",
        scene.to_str().unwrap(),
        "--integrators",
        "explicit-euler,implicit-euler",
        "--dt",
        "0.01,0.001",
        "--json",
        "--quiet",
    ]);
    out.expect_status(EXIT_OK);
    let v: Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    // ω₀h = 14 and 1.4: explicit Euler diverges at both; implicit Euler at neither.
    for run in runs {
        let unstable = &run["unstable"];
        if run["integrator"] == "explicit-euler" {
            let step = unstable["step"].as_u64().expect("an unstable step");
            let dt = run["dt"].as_f64().unwrap();
            assert_eq!(unstable["time"].as_f64(), Some(step as f64 * dt));
            assert_eq!(run["steps"].as_u64(), Some(step));
            assert!(run["at_rest"].is_null());
            assert_eq!(run["comparable"], false);
        } else {
            assert!(unstable.is_null(), "{run}");
            assert_eq!(run["comparable"], true);
        }
    }
    // The table does not show an unstable run's error over its frames before the blow-up,
    // which would look better than a stable run's: it says `unstable` instead.
    let out = sandbox.run(&[
        "compare",
        scene.to_str().unwrap(),
        "--integrators",
        "explicit-euler",
        "--dt",
        "0.01",
        "--quiet",
        "--duration",
        "0.5",
    ]);
    out.expect_status(EXIT_OK);
    let table = out.stdout_text();
    let row = table
        .lines()
        .find(|l| l.starts_with("explicit-euler"))
        .unwrap_or_else(|| panic!("{table}"));
    assert_eq!(
        row.matches(" unstable").count(),
        2,
        "error and drift: {row}"
    );
    assert!(table.contains(", 0.5 s at"), "--duration applies: {table}");
}

/// A reference that diverges leaves nothing to measure against: exit 3, saying so.
#[test]
fn unstable_reference_exits_3() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("stiff.toml", STIFF);
    let out = sandbox.run(&[
        "compare",
        scene.to_str().unwrap(),
        "--dt",
        "0.5",
        "--refinement",
        "2",
        "--quiet",
    ]);
    out.expect_status(EXIT_UNSTABLE);
    assert!(
        out.stderr
            .contains("the reference (rk4 at dt = 2.5e-1 s) became unstable"),
        "{}",
        out.stderr
    );
}

/// A reference whose check step is past the stable estimate is no reference: on the stiff pair
/// (ω₀ = 1414 rad/s, stable estimate ≈ 2/ω₀ = 1.41e-3 s), steps of 3.6 ms with refinement 4
/// put the reference at 0.9 ms (ω₀h = 1.27) and its check at 1.8 ms (ω₀h = 2.55, inside RK4's
/// stability interval ω₀h < 2√2, so nothing diverges). The study still reports, every run is
/// marked not comparable, the reference says why and what to try, and the exit status is 5.
#[test]
fn an_unconverged_reference_marks_every_run_and_exits_5() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("stiff.toml", STIFF);
    let args = |extra: &[&str]| {
        let mut a = vec![
            "compare",
            scene.to_str().unwrap(),
            "--integrators",
            "symplectic-euler,implicit-euler",
            "--dt",
            "0.0036",
            "--refinement",
            "4",
            "--duration",
            "0.5",
            "--quiet",
        ];
        a.extend_from_slice(extra);
        a.into_iter().map(str::to_owned).collect::<Vec<_>>()
    };
    let json = args(&["--json"]);
    let out = sandbox.run(&json.iter().map(String::as_str).collect::<Vec<_>>());
    out.expect_status(5);
    let v: Value = serde_json::from_slice(&out.stdout).expect("the report all the same");
    let reference = &v["reference"];
    assert_eq!(reference["converged"], false);
    let stable = reference["stable_dt_estimate"].as_f64().unwrap();
    assert!(
        (stable - 2.0 / 1e6f64.sqrt() / 2f64.sqrt()).abs() < 0.02 * stable,
        "{stable}"
    );
    let because = reference["not_converged_because"].as_array().unwrap();
    assert!(
        because[0]
            .as_str()
            .unwrap()
            .contains("past the stable step estimate"),
        "{because:?}"
    );
    // 2 · 3.6 ms / 1.41 ms = 5.1: refinement 6 clears it, but at least twice 4.
    assert_eq!(reference["suggested_refinement"], 8);
    for run in v["runs"].as_array().unwrap() {
        assert_eq!(run["comparable"], false, "{run}");
        if run["unstable"].is_null() {
            assert_eq!(run["not_comparable"], "reference-not-converged", "{run}");
        }
    }
    assert!(out.stderr.contains("try --refinement 8"), "{}", out.stderr);
    let table = args(&[]);
    let out = sandbox.run(&table.iter().map(String::as_str).collect::<Vec<_>>());
    out.expect_status(5);
    assert!(
        out.stdout_text().contains("reference NOT converged"),
        "{}",
        out.stdout_text()
    );

    // A finer reference converges: at refinement 32 (ω₀h = 0.16) RK4's phase error over the
    // 0.5 s is 8⁴ times smaller than at 4 (bound 3e-2 m at refinement 8, so ~1e-4 m here,
    // below 1 % of the pair's 1.1 m); exit 0.
    let fine = args(&["--json"]);
    let fine: Vec<&str> = fine
        .iter()
        .map(|a| if a == "4" { "32" } else { a.as_str() })
        .collect();
    let out = sandbox.run(&fine);
    out.expect_status(EXIT_OK);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["reference"]["converged"], true, "{}", v["reference"]);
    let implicit = &v["runs"][1];
    assert_eq!(implicit["integrator"], "implicit-euler");
    assert_eq!(implicit["comparable"], true, "{implicit}");
    assert!(implicit["not_comparable"].is_null());
}
