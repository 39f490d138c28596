//! `softbody grad`: its JSON, its losses against frames a run wrote (JSON Lines and NPZ alike),
//! and its refusals with their exit statuses.

mod common;

use common::{Cube, EXIT_BAD_INPUT, EXIT_OK, EXIT_UNSTABLE, Sandbox};
use serde_json::Value;

fn flight() -> Cube {
    Cube {
        duration: 0.1,
        ground: false,
        ..Cube::default()
    }
}

fn json(out: &common::Outcome) -> Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {}", out.stdout_text()))
}

#[test]
fn json_carries_the_loss_the_gradient_by_key_the_steps_memory_and_times() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &flight().toml());
    let out = sandbox.run(&[
        "grad".as_ref(),
        scene.as_os_str(),
        "--wrt".as_ref(),
        "body[0].structural.stiffness".as_ref(),
        "--wrt".as_ref(),
        "body[0].velocity".as_ref(),
        "--target-com".as_ref(),
        "1,0.5,0".as_ref(),
        "--json".as_ref(),
    ]);
    out.expect_status(EXIT_OK);
    let v = json(&out);
    assert_eq!(v["steps"], 100);
    assert!(v["loss"].as_f64().unwrap() > 0.0);
    assert!(v["gradient"]["body[0].structural.stiffness"].is_f64());
    let velocity = v["gradient"]["body[0].velocity"].as_array().unwrap();
    assert_eq!(velocity.len(), 3);
    assert!(v["peak_memory_bytes"].as_u64().unwrap() > 0);
    assert!(v["forward_seconds"].as_f64().unwrap() >= 0.0);
    assert!(v["backward_seconds"].as_f64().unwrap() >= 0.0);
    // In free flight symplectic Euler moves the centre as c_k = c₀ + k h v₀ − g h² k(k+1)/2
    // (the computed trajectory, not ½gt²): ∂|c − target|²/∂v₀ = 2(c − target)·kh at k = 100,
    // and the springs do not matter.
    let (t, fall) = (0.1, 9.81 * 1e-6 * 100.0 * 101.0 / 2.0);
    let c = [0.5 * t, 1.0 - fall, -0.25 * t];
    let expected = [
        2.0 * (c[0] - 1.0) * t,
        2.0 * (c[1] - 0.5) * t,
        2.0 * c[2] * t,
    ];
    for k in 0..3 {
        let got = velocity[k].as_f64().unwrap();
        assert!(
            (got - expected[k]).abs() < 1e-9,
            "{k}: {got} {}",
            expected[k]
        );
    }
    let stiffness = v["gradient"]["body[0].structural.stiffness"]
        .as_f64()
        .unwrap();
    assert!(stiffness.abs() < 1e-12, "{stiffness}");
}

#[test]
fn the_frames_loss_reads_the_frames_run_wrote_in_either_format() {
    let sandbox = Sandbox::new();
    let cube = Cube {
        duration: 0.1,
        ..Cube::default()
    };
    let scene = sandbox.write("cube.toml", &cube.toml());
    for out in ["frames.jsonl", "frames.npz"] {
        sandbox
            .run(&["run", scene.to_str().unwrap(), "--out", out, "--quiet"])
            .expect_status(EXIT_OK);
    }
    let grad = |frames: &str, set: &str| {
        let out = sandbox.run(&[
            "grad",
            scene.to_str().unwrap(),
            "--wrt",
            "body[0].structural.stiffness",
            "--target-frames",
            frames,
            "--set",
            set,
            "--json",
        ]);
        out.expect_status(EXIT_OK);
        json(&out)
    };
    // Against its own frames: the loss and its gradient are zero.
    let same = grad("frames.jsonl", "body[0].structural.stiffness=200.0");
    assert_eq!(same["loss"], 0.0);
    assert_eq!(same["gradient"]["body[0].structural.stiffness"], 0.0);
    // Against a stiffer jelly's: not zero, and the same from either file (the numbers read
    // back to the bit).
    let jsonl = grad("frames.jsonl", "body[0].structural.stiffness=300.0");
    let npz = grad("frames.npz", "body[0].structural.stiffness=300.0");
    assert!(jsonl["loss"].as_f64().unwrap() > 0.0);
    assert_eq!(jsonl["loss"], npz["loss"]);
    assert_eq!(jsonl["gradient"], npz["gradient"]);
}

#[test]
fn refusals_are_located_with_their_exit_statuses() {
    let sandbox = Sandbox::new();
    let scene = sandbox.write("cube.toml", &flight().toml());
    let scene = scene.to_str().unwrap();
    let args = |extra: &[&'static str]| -> Vec<String> {
        let mut a = vec!["grad".to_owned(), scene.to_owned()];
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let out = sandbox.run(&args(&["--wrt", "body[0].size", "--target-com", "0,0,0"]));
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        out.stderr.contains("--wrt body[0].size") && out.stderr.contains("terrain[N].friction"),
        "{}",
        out.stderr
    );

    let out = sandbox.run(&args(&[
        "--wrt",
        "body[0].mass",
        "--target-com",
        "0,0,0",
        "--backend",
        "gpu",
    ]));
    out.expect_status(EXIT_BAD_INPUT);
    assert!(out.stderr.contains("--backend gpu"), "{}", out.stderr);

    // Frames of other particles.
    let other = sandbox.write(
        "other.toml",
        &Cube {
            resolution: [2, 2, 2],
            ..flight()
        }
        .toml(),
    );
    sandbox
        .run(&[
            "run",
            other.to_str().unwrap(),
            "--out",
            "other.jsonl",
            "--quiet",
        ])
        .expect_status(EXIT_OK);
    let out = sandbox.run(&args(&[
        "--wrt",
        "body[0].mass",
        "--target-frames",
        "other.jsonl",
    ]));
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        out.stderr.contains("other.jsonl") && out.stderr.contains("particles"),
        "{}",
        out.stderr
    );

    // A run that blows up: exit 3, as for `run`.
    let out = sandbox.run(&args(&[
        "--wrt",
        "body[0].mass",
        "--target-com",
        "0,0,0",
        "--set",
        "body[0].structural.stiffness=1e9",
        "--set",
        "simulation.integrator=\"explicit-euler\"",
    ]));
    out.expect_status(EXIT_UNSTABLE);
    assert!(out.stderr.contains("unstable"), "{}", out.stderr);
}

/// `fit` recovers a jelly's stiffness and damping from a run it is not told them of, from a
/// start 3× off, to 1e-6 relative in at most 30 iterations, for symplectic Euler and RK4; the
/// fitted scene is the input with the values written in.
#[test]
fn fit_recovers_stiffness_and_damping_from_a_recorded_run() {
    let sandbox = Sandbox::new();
    let cube = Cube {
        duration: 0.3,
        center: [0.0, 0.55, 0.0],
        size: 0.3,
        mass: 2.7,
        stiffness: 900.0,
        damping: 2.0,
        ..Cube::default()
    };
    let scene = sandbox.write("cube.toml", &cube.toml());
    let scene = scene.to_str().unwrap();
    for integrator in ["symplectic-euler", "rk4"] {
        let frames = format!("{integrator}.jsonl");
        let fitted = format!("{integrator}-fitted.toml");
        let with = format!("simulation.integrator=\"{integrator}\"");
        sandbox
            .run(&["run", scene, "--set", &with, "--out", &frames, "--quiet"])
            .expect_status(EXIT_OK);
        let out = sandbox.run(&[
            "fit",
            scene,
            "--to",
            &frames,
            "--param",
            "body[0].structural.stiffness",
            "--param",
            "body[0].structural.damping",
            "--set",
            &with,
            "--set",
            "body[0].structural.stiffness=2700.0",
            "--set",
            "body[0].structural.damping=6.0",
            "--out",
            &fitted,
        ]);
        out.expect_status(EXIT_OK);
        let text = out.stdout_text();
        let iterations: u64 = text
            .split(" after ")
            .nth(1)
            .and_then(|t| t.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{text}"));
        assert!(iterations <= 30, "{integrator}: {text}");
        let doc: softbody::toml::Table = std::fs::read_to_string(sandbox.path().join(&fitted))
            .unwrap()
            .parse()
            .unwrap();
        let body = &doc["body"][0];
        let k = body["structural"]["stiffness"].as_float().unwrap();
        let c = body["structural"]["damping"].as_float().unwrap();
        assert!((k / 900.0 - 1.0).abs() < 1e-6, "{integrator}: {k}\n{text}");
        assert!((c / 2.0 - 1.0).abs() < 1e-6, "{integrator}: {c}\n{text}");
        // The rest is the input's (with the --set integrator written in).
        assert_eq!(body["shear"]["stiffness"].as_float(), Some(900.0));
        assert_eq!(body["mass"].as_float(), Some(2.7));
        assert_eq!(doc["simulation"]["integrator"].as_str(), Some(integrator));
    }
}
