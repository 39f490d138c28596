//! `--set KEY=VALUE` on `run`, `check`, `compare` and `render`: the value replaces the file's,
//! bad values are refused (exit 2) as the file's would be, naming the `--set`, and default
//! output names carry the settings.

mod common;

use common::*;

/// A cube scene in a new sandbox, as `s.toml`.
fn sandbox() -> (Sandbox, Cube, String) {
    let cube = Cube {
        velocity: [0.0; 3],
        ..Cube::default()
    };
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    (sb, cube, path.to_str().unwrap().to_owned())
}

#[test]
fn run_uses_the_set_values_and_names_its_output_after_them() {
    let (sb, cube, scene) = sandbox();
    sb.run(&[
        "run",
        &scene,
        "--quiet",
        "--set",
        "body[0].velocity=[1.5, 0.0, -0.5]",
        "--set",
        "simulation.duration=0.02",
    ])
    .expect_status(EXIT_OK);
    let name = "s-body0.velocity1.50.0-0.5-simulation.duration0.02.jsonl";
    assert_eq!(entries(&sb.path().join("out")), [name]);
    let f = read_jsonl(&sb.path().join("out").join(name));
    assert_eq!(
        f.frames.len(),
        frame_schedule(cube.dt, 0.02, cube.frame_rate).len()
    );
    for v in triples(&f.frames[0]["velocities"]) {
        assert_eq!(v, [1.5, 0.0, -0.5]);
    }
    // The header's scene text is the scene that ran: the file with the settings.
    let text = f.header["scene_text"].as_str().expect("scene_text");
    let ran: softbody::toml::Table = text.parse().unwrap();
    assert_eq!(ran["simulation"]["duration"].as_float(), Some(0.02));
    assert_eq!(
        ran["body"][0]["velocity"].as_array().unwrap()[0].as_float(),
        Some(1.5)
    );
}

#[test]
fn check_describes_the_scene_with_the_settings() {
    let (sb, cube, scene) = sandbox();
    let out = sb.run(&[
        "check",
        &scene,
        "--json",
        "--set",
        "body[0].mass=4.5",
        "--set",
        "simulation.dt=0.0005",
    ]);
    out.expect_status(EXIT_OK);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["total_mass"].as_f64(), Some(4.5));
    assert_eq!(v["dt"].as_f64(), Some(0.0005));
    assert_eq!(
        v["steps"].as_u64(),
        Some(planned_steps(0.0005, cube.duration))
    );
}

#[test]
fn a_bad_value_is_refused_naming_the_set_on_every_command() {
    let (sb, _, scene) = sandbox();
    let pictures = sb.path().join("p").to_str().unwrap().to_owned();
    for command in [
        vec!["run", &scene],
        vec!["check", &scene],
        vec!["compare", &scene, "--integrators", "rk4"],
        vec!["render", &scene, "--out", &pictures],
    ] {
        let mut args = command.clone();
        args.extend(["--set", "body[0].mass=-2"]);
        let out = sb.run(&args);
        out.expect_status(EXIT_BAD_INPUT);
        assert_eq!(
            out.stderr.trim_end(),
            format!(
                "error: {scene}: body[0].mass: must be greater than zero, not -2 (from --set \
                 body[0].mass=-2)"
            ),
            "{command:?}"
        );
    }
    assert!(!sb.path().join("out").exists() && !sb.path().join("p").exists());
}

#[test]
fn a_fault_the_settings_reveal_in_the_file_is_located_there() {
    let (sb, _, scene) = sandbox();
    // dt = 0.05 cannot serve the file's 100 frames/s.
    let out = sb.run(&["run", &scene, "--set", "simulation.dt=0.05"]);
    out.expect_status(EXIT_BAD_INPUT);
    let line = line_of(&std::fs::read_to_string(&scene).unwrap(), "frame_rate");
    assert!(
        out.stderr.starts_with(&format!(
            "error: {scene}:{line}:14: simulation.frame_rate: "
        )),
        "{}",
        out.stderr
    );
    assert!(
        out.stderr.contains("(with --set simulation.dt=0.05)"),
        "{}",
        out.stderr
    );
}

#[test]
fn unknown_keys_types_and_missing_entries_are_bad_input() {
    let (sb, _, scene) = sandbox();
    let cases = [
        ("simulation.dtt=0.1", "unknown field `dtt`"),
        (
            "terrain[1].friction=0.5",
            "terrain has 1 entries (terrain[0] to terrain[0])",
        ),
        ("body[1].mass=1", "body has 1 entries (body[0] to body[0])"),
        (
            "body[0].mass=heavy",
            "invalid type: string \"heavy\", expected a number",
        ),
        ("body[0]mass=1", "is not a key path"),
        ("mass", "is not KEY=VALUE"),
    ];
    for (set, expected) in cases {
        let out = sb.run(&["check", &scene, "--set", set]);
        out.expect_status(EXIT_BAD_INPUT);
        assert!(out.stderr.contains(expected), "{set}: {}", out.stderr);
    }
}

#[test]
fn render_of_frames_refuses_set() {
    let (sb, _, scene) = sandbox();
    sb.run(&["run", &scene, "--quiet", "--out", "f.jsonl"])
        .expect_status(EXIT_OK);
    let out = sb.run(&["render", "f.jsonl", "--set", "body[0].mass=2"]);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(out.stderr.contains("--set, --integrator"), "{}", out.stderr);
}
