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

    // An NPZ whose times disagree with its positions, and one whose times are no frame of
    // this run (every time past its end).
    sandbox
        .run(&["run", scene, "--out", "frames.npz", "--quiet"])
        .expect_status(EXIT_OK);
    let frames = (flight().duration * flight().frame_rate).round() as usize + 1;
    for (name, times) in [
        ("cut.npz", vec![0.0; frames - 1]),
        (
            "later.npz",
            (0..frames).map(|f| 10.0 + f as f64 / 100.0).collect(),
        ),
    ] {
        rewrite_time(
            &sandbox.path().join("frames.npz"),
            &sandbox.path().join(name),
            &times,
        );
        let out = sandbox.run(&args(&["--wrt", "body[0].mass", "--target-frames", name]));
        out.expect_status(EXIT_BAD_INPUT);
        let why = match name {
            "cut.npz" => format!(
                "time has {} entries for {frames} frames of positions",
                frames - 1
            ),
            _ => "none of its frames is a frame of this run".to_owned(),
        };
        assert!(
            out.stderr.contains(name) && out.stderr.contains(&why),
            "{name}: {}",
            out.stderr
        );
    }

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
/// start 3× off, to 1e-6 relative in at most 30 iterations: for symplectic Euler and RK4 a
/// cube landing on the ground, for implicit Euler (whose gradient has no steps in contact
/// yet) one swinging from a pinned corner, its CG tolerance at 1e-12 in the recorded run and
/// the fit alike (at the default 1e-8, the solves' error leaves the loss a floor at ~1e-16,
/// where the fit stops 2e-6 short); the fitted scene is the input with the values written
/// in.
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
    let landing = sandbox.write("cube.toml", &cube.toml());
    let hanging = Cube {
        ground: false,
        ..cube
    };
    let hanging = sandbox.write("hanging.toml", &(hanging.toml() + "pinned = [0]\n"));
    for (integrator, scene, tolerance) in [
        ("symplectic-euler", &landing, 1e-8),
        ("rk4", &landing, 1e-8),
        ("implicit-euler", &hanging, 1e-12),
    ] {
        let scene = scene.to_str().unwrap();
        let frames = format!("{integrator}.jsonl");
        let fitted = format!("{integrator}-fitted.toml");
        let with = format!("simulation.integrator=\"{integrator}\"");
        let tolerance = format!("simulation.cg_tolerance={tolerance:e}");
        sandbox
            .run(&[
                "run", scene, "--set", &with, "--set", &tolerance, "--out", &frames, "--quiet",
            ])
            .expect_status(EXIT_OK);
        let out = sandbox.run(&[
            "fit",
            "--set",
            &tolerance,
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

/// Copies the NPZ `from` to `to` with its `time` array replaced by `times`.
fn rewrite_time(from: &std::path::Path, to: &std::path::Path, times: &[f64]) {
    use npyz::WriterBuilder;
    use std::io::{Read, Write};
    let mut archive = zip::ZipArchive::new(std::fs::File::open(from).unwrap()).unwrap();
    let mut out = zip::ZipWriter::new(std::fs::File::create(to).unwrap());
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for k in 0..archive.len() {
        let mut entry = archive.by_index(k).unwrap();
        let name = entry.name().unwrap().into_owned();
        out.start_file(name.as_str(), stored).unwrap();
        if name == "time.npy" {
            let mut bytes = Vec::new();
            let mut writer = npyz::WriteOptions::<f64>::new()
                .default_dtype()
                .shape(&[times.len() as u64])
                .writer(&mut bytes)
                .begin_nd()
                .unwrap();
            writer.extend(times.iter().copied()).unwrap();
            writer.finish().unwrap();
            out.write_all(&bytes).unwrap();
        } else {
            let mut bytes = Vec::new();
            entry.read_to_end(&mut bytes).unwrap();
            out.write_all(&bytes).unwrap();
        }
    }
    out.finish().unwrap();
}

/// `grad` takes `run`'s energy guard on its forward pass: a stiff jelly under explicit Euler
/// whose energy grows past ten energy scales (finite all the while) is unstable at the same
/// step in both, exit 3, and has no gradient.
#[test]
fn grad_calls_unstable_what_run_calls_unstable_at_the_same_step() {
    let sandbox = Sandbox::new();
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/jelly-on-ground.toml"
    );
    let settings = [
        "--set",
        "body[0].structural.stiffness=1e6",
        "--set",
        "simulation.integrator=\"explicit-euler\"",
        "--set",
        "simulation.duration=0.1",
    ];
    let out = sandbox.path().join("run.jsonl");
    let with = |first: &[&str], last: &[&str]| -> Vec<String> {
        first
            .iter()
            .chain(&settings)
            .chain(last)
            .map(|s| s.to_string())
            .collect()
    };
    let ran = sandbox.run(&with(&["run", scene], &["--out", out.to_str().unwrap()]));
    ran.expect_status(EXIT_UNSTABLE);
    let graded = sandbox.run(&with(
        &["grad", scene],
        &["--wrt", "body[0].mass", "--target-com", "0,0,0"],
    ));
    graded.expect_status(EXIT_UNSTABLE);
    // "unstable at step K (t = …): particle P … energy reached E J, more than 10 energy scales"
    let at = |stderr: &str| {
        let from = stderr.find("at step").expect("the step");
        let to = stderr[from..].find(" above").expect("the guard's words") + from;
        stderr[from..to].to_owned()
    };
    assert!(ran.stderr.contains("energy scales"), "{}", ran.stderr);
    assert_eq!(at(&graded.stderr), at(&ran.stderr));
    // And the same advice.
    let advice = |stderr: &str| {
        let line = stderr.lines().find(|l| l.contains("unstable"))?;
        line.split_once("; ").map(|(_, advice)| advice.to_owned())
    };
    assert!(advice(&ran.stderr).is_some(), "{}", ran.stderr);
    assert_eq!(
        advice(&graded.stderr),
        advice(&ran.stderr),
        "{}",
        graded.stderr
    );
}
