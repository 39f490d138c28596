//! `softbody run` and `softbody check`: output locations, the JSON Lines header and frame
//! schedule, standard output and stderr behaviour, determinism across thread counts, exit
//! statuses 1 and 3.

mod common;

use common::*;
use serde_json::Value;

/// The scene with `cube` as `NAME.toml` in a new sandbox.
fn sandbox_with(cube: &Cube, name: &str) -> (Sandbox, String) {
    let sb = Sandbox::new();
    let path = sb.write(&format!("{name}.toml"), &cube.toml());
    (sb, path.to_str().unwrap().to_owned())
}

// ---------------------------------------------------------------- where the output goes

#[test]
fn run_without_out_writes_out_slash_stem_dot_jsonl_and_says_where() {
    let (sb, scene) = sandbox_with(&Cube::default(), "wobbly");
    let run = sb.run(&["run", &scene]);
    run.expect_status(EXIT_OK);
    let written = sb.path().join("out").join("wobbly.jsonl");
    assert_eq!(entries(&sb.path().join("out")), ["wobbly.jsonl"]);
    assert!(
        run.stderr.contains("out/wobbly.jsonl"),
        "stderr names the output file:\n{}",
        run.stderr
    );
    assert!(run.stdout.is_empty(), "frames go to the file, not stdout");
    let f = read_jsonl(&written);
    assert_eq!(f.frames.len(), frame_schedule(0.001, 0.05, 100.0).len());
}

#[test]
fn run_without_out_takes_the_extension_from_the_format() {
    let (sb, scene) = sandbox_with(&Cube::default(), "wobbly");
    sb.run(&["run", &scene, "--format", "csv", "--quiet"])
        .expect_status(EXIT_OK);
    sb.run(&["run", &scene, "--format", "npz", "--quiet"])
        .expect_status(EXIT_OK);
    assert_eq!(
        entries(&sb.path().join("out")),
        ["wobbly.csv", "wobbly.npz"]
    );
}

#[test]
fn out_path_in_a_missing_directory_is_created() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let out = sb.path().join("a/b/frames.jsonl");
    sb.run(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"])
        .expect_status(EXIT_OK);
    read_jsonl(&out);
    assert_eq!(
        entries(&sb.path().join("a/b")),
        ["frames.jsonl"],
        "no stray files"
    );
}

#[test]
fn existing_output_file_is_replaced() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let out = sb.write("frames.jsonl", "old contents that are not JSON\n");
    sb.run(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"])
        .expect_status(EXIT_OK);
    read_jsonl(&out);
}

/// A link at --out is followed: the file it names is written (made when missing), the link
/// stays a link.
#[cfg(unix)]
#[test]
fn a_symbolic_link_at_out_is_followed() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    std::fs::create_dir(sb.path().join("data")).unwrap();
    for (link, target, old) in [
        (
            "live.jsonl",
            "data/live-target.jsonl",
            Some("old contents\n"),
        ),
        ("dangling.jsonl", "data/dangling-target.jsonl", None),
    ] {
        let target_path = sb.path().join(target);
        if let Some(old) = old {
            std::fs::write(&target_path, old).unwrap();
        }
        let link_path = sb.path().join(link);
        std::os::unix::fs::symlink(target, &link_path).unwrap();
        sb.run(&[
            "run",
            &scene,
            "--out",
            link_path.to_str().unwrap(),
            "--quiet",
        ])
        .expect_status(EXIT_OK);
        let meta = std::fs::symlink_metadata(&link_path).unwrap();
        assert!(meta.file_type().is_symlink(), "{link} was replaced");
        assert_eq!(
            std::fs::read_link(&link_path).unwrap(),
            std::path::Path::new(target)
        );
        read_jsonl(&target_path);
    }
    assert_eq!(
        entries(&sb.path().join("data")),
        ["dangling-target.jsonl", "live-target.jsonl"],
        "nothing staged is left beside the targets"
    );
}

/// A replaced file keeps its permissions: a private 0600 file stays private.
#[cfg(unix)]
#[test]
fn a_replaced_file_keeps_its_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    for mode in [0o600, 0o640, 0o664] {
        let out = sb.write("private.jsonl", "old\n");
        std::fs::set_permissions(&out, std::fs::Permissions::from_mode(mode)).unwrap();
        sb.run(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"])
            .expect_status(EXIT_OK);
        read_jsonl(&out);
        let got = std::fs::metadata(&out).unwrap().permissions().mode() & 0o7777;
        assert_eq!(format!("{got:o}"), format!("{mode:o}"));
    }
}

/// A FIFO at --out is written in place (its reader gets the frames) and stays a FIFO; as with
/// a character device such as /dev/null, a rename over it would replace it with a file.
#[cfg(unix)]
#[test]
fn a_fifo_at_out_is_written_not_replaced() {
    use std::os::unix::fs::FileTypeExt;
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let fifo = sb.path().join("pipe.jsonl");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read_to_string(fifo).unwrap())
    };
    sb.run(&["run", &scene, "--out", fifo.to_str().unwrap(), "--quiet"])
        .expect_status(EXIT_OK);
    let text = reader.join().unwrap();
    let frames = parse_jsonl(&text);
    assert!(!frames.frames.is_empty(), "the reader got the frames");
    let kind = std::fs::symlink_metadata(&fifo).unwrap().file_type();
    assert!(kind.is_fifo(), "the FIFO was replaced");
    assert_eq!(
        entries(sb.path()),
        ["pipe.jsonl", "s.toml"],
        "nothing staged"
    );
}

/// A destination that cannot be written is refused before the solver opens or a step runs: a
/// run of an hour fails at once.
#[test]
fn an_unwritable_destination_is_refused_before_the_run() {
    let sb = Sandbox::new();
    let scene = sb.write(
        "long.toml",
        &Cube {
            duration: 3600.0,
            ..Cube::default()
        }
        .toml(),
    );
    let dir = sb.mkdir("frames.jsonl");
    let started = std::time::Instant::now();
    sb.run(&[
        "run",
        scene.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
    ])
    .expect_status(EXIT_OUTPUT);
    assert!(
        started.elapsed().as_secs() < 60,
        "refused after {:?}: the run was simulated first",
        started.elapsed()
    );
}

#[cfg(unix)]
#[test]
fn output_file_has_the_permissions_of_an_ordinary_file() {
    use std::os::unix::fs::PermissionsExt;
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let out = sb.path().join("frames.jsonl");
    sb.run(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"])
        .expect_status(EXIT_OK);
    // What this process's umask makes of a new file.
    let reference = sb.write("reference.txt", "x");
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(
        format!("{:o}", mode(&out)),
        format!("{:o}", mode(&reference)),
        "the frames file should be created like any other file, not 0600 like a temporary one"
    );
}

#[test]
fn unwritable_output_exits_with_status_1() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    // The parent of the output "directory" is a regular file.
    let blocker = sb.write("blocker", "a file, not a directory\n");
    let out = blocker.join("frames.jsonl");
    let run = sb.run(&["run", &scene, "--out", out.to_str().unwrap()]);
    run.expect_status(EXIT_OUTPUT);
    assert!(run.stderr.contains("blocker"), "{}", run.stderr);
}

#[test]
fn output_onto_a_directory_exits_with_status_1() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let dir = sb.mkdir("frames.jsonl");
    let run = sb.run(&["run", &scene, "--out", dir.to_str().unwrap()]);
    run.expect_status(EXIT_OUTPUT);
    assert_eq!(entries(&dir), Vec::<String>::new());
    assert_eq!(
        entries(sb.path()),
        ["frames.jsonl", "s.toml"],
        "no temporary file left beside the destination"
    );
}

// ---------------------------------------------------------------- JSON Lines contents

#[test]
fn header_describes_the_run() {
    let sb = Sandbox::new();
    let mut text = Cube {
        resolution: [2, 3, 2],
        ..Cube::default()
    }
    .toml();
    text += "\n[[body]]\nname = \"pair\"\nkind = \"particles\"\n\
             positions = [[3.0, 1.0, 0.0], [4.0, 1.0, 0.0], [5.0, 1.0, 0.0]]\n\
             masses = [0.1, 0.2, 0.3]\n\
             springs = [{ a = 0, b = 1, stiffness = 10.0 }]\n";
    let scene = sb.write("two.toml", &text);
    let run = sb.run(&["run", scene.to_str().unwrap(), "--out", "-", "--quiet"]);
    run.expect_status(EXIT_OK);
    let h = parse_jsonl(&run.stdout_text()).header;
    assert_eq!(h["softbody_frames"], 1);
    assert_eq!(h["particles"], 15);
    assert_eq!(
        h["bodies"],
        serde_json::json!([
            {"name": "cube", "first": 0, "count": 12},
            {"name": "pair", "first": 12, "count": 3},
        ])
    );
    assert_eq!(h["integrator"], "symplectic-euler");
    assert_eq!(h["backend"], "cpu");
    assert_eq!(f64_of(&h["dt"]), 0.001);
    assert_eq!(f64_of(&h["frame_rate"]), 100.0);
    assert!(h["device"].is_string(), "{h}");
}

#[test]
fn frames_are_taken_at_round_k_over_frame_rate_dt() {
    // frame_rate·dt = 0.21: frames at steps 0, 5, 10, 14, 19, 24, 29, 33 of 33.
    let cube = Cube {
        dt: 0.003,
        duration: 0.1,
        frame_rate: 70.0,
        ..Cube::default()
    };
    let schedule = frame_schedule(cube.dt, cube.duration, cube.frame_rate);
    assert_eq!(
        schedule,
        [0, 5, 10, 14, 19, 24, 29, 33],
        "test's own formula"
    );
    let (sb, scene) = sandbox_with(&cube, "s");
    let run = sb.run(&["run", &scene, "--out", "-", "--quiet"]);
    run.expect_status(EXIT_OK);
    let f = parse_jsonl(&run.stdout_text());
    assert_eq!(f.frames.len(), schedule.len());
    for (k, (frame, &step)) in f.frames.iter().zip(&schedule).enumerate() {
        assert_frame_shape(frame, k, cube.particles());
        assert_eq!(
            f64_of(&frame["time"]).to_bits(),
            (step as f64 * cube.dt).to_bits(),
            "frame {k} is at step {step}: time = step·dt exactly"
        );
    }
    assert_eq!(f.header["frames"], schedule.len() as u64);
    assert_eq!(f.header["steps"], 33);
}

#[test]
fn steps_are_duration_over_dt_rounded() {
    // 0.0504 / 0.001 = 50.4 → 50 steps; frames every 10 steps → 0..=50: 6 frames;
    // 0.0556 / 0.001 = 55.6 → 56 steps; still 6 frames, the last at step 50.
    for (duration, steps, frames) in [(0.0504, 50, 6), (0.0556, 56, 6), (0.0596, 60, 7)] {
        assert_eq!(planned_steps(0.001, duration), steps);
        assert_eq!(frame_schedule(0.001, duration, 100.0).len(), frames);
        let (sb, scene) = sandbox_with(&Cube::default(), "s");
        let run = sb.run(&[
            "run",
            &scene,
            "--duration",
            &duration.to_string(),
            "--out",
            "-",
            "--quiet",
        ]);
        run.expect_status(EXIT_OK);
        let f = parse_jsonl(&run.stdout_text());
        assert_eq!(f.frames.len(), frames, "duration {duration}");
        assert_eq!(f.header["steps"], steps, "duration {duration}");
        let last = f64_of(&f.frames.last().unwrap()["time"]);
        assert_eq!(last, ((frames - 1) * 10) as f64 * 0.001);
    }
}

#[test]
fn frame_zero_is_the_initial_state() {
    let cube = Cube {
        resolution: [2, 2, 2],
        size: 0.5,
        center: [1.0, 2.0, 3.0],
        velocity: [0.5, 0.0, -0.25],
        mass: 2.0,
        ..Cube::default()
    };
    let (sb, scene) = sandbox_with(&cube, "s");
    let run = sb.run(&["run", &scene, "--out", "-", "--quiet"]);
    run.expect_status(EXIT_OK);
    let f = parse_jsonl(&run.stdout_text());
    let frame0 = &f.frames[0];
    assert_eq!(f64_of(&frame0["time"]), 0.0);
    let mut positions = triples(&frame0["positions"]);
    positions.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let mut corners = Vec::new();
    for x in [0.75, 1.25] {
        for y in [1.75, 2.25] {
            for z in [2.75, 3.25] {
                corners.push([x, y, z]);
            }
        }
    }
    assert_eq!(
        positions, corners,
        "a 2×2×2 cuboid's particles are its corners"
    );
    for v in triples(&frame0["velocities"]) {
        assert_eq!(v, [0.5, 0.0, -0.25]);
    }
    let e = &frame0["energy"];
    let kinetic = 0.5 * 2.0 * (0.5f64 * 0.5 + 0.25 * 0.25);
    assert!((f64_of(&e["kinetic"]) - kinetic).abs() < 1e-12, "{e}");
    assert!(
        (f64_of(&e["gravitational"]) - 2.0 * 9.81 * 2.0).abs() < 1e-9,
        "{e}"
    );
    assert_eq!(f64_of(&e["elastic"]), 0.0, "springs start at rest length");
}

#[test]
fn zero_duration_writes_only_the_initial_frame() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&["run", &scene, "--duration", "0", "--out", "-", "--quiet"]);
    run.expect_status(EXIT_OK);
    let f = parse_jsonl(&run.stdout_text());
    assert_eq!(f.frames.len(), 1);
    assert_frame_shape(&f.frames[0], 0, 27);
}

#[test]
fn command_line_overrides_the_scene() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&[
        "run",
        &scene,
        "--integrator",
        "rk4",
        "--dt",
        "0.002",
        "--fps",
        "25",
        "--duration",
        "0.1",
        "--out",
        "-",
        "--quiet",
    ]);
    run.expect_status(EXIT_OK);
    let f = parse_jsonl(&run.stdout_text());
    assert_eq!(f.header["integrator"], "rk4");
    assert_eq!(f64_of(&f.header["dt"]), 0.002);
    assert_eq!(f64_of(&f.header["frame_rate"]), 25.0);
    let schedule = frame_schedule(0.002, 0.1, 25.0);
    assert_eq!(schedule, [0, 20, 40]);
    let times: Vec<f64> = f.frames.iter().map(|fr| f64_of(&fr["time"])).collect();
    let expected: Vec<f64> = schedule.iter().map(|&s| s as f64 * 0.002).collect();
    assert_eq!(times, expected);
}

#[test]
fn dt_takes_a_fraction() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&["run", &scene, "--dt", "1/2000", "--out", "-", "--quiet"]);
    run.expect_status(EXIT_OK);
    let f = parse_jsonl(&run.stdout_text());
    assert_eq!(f64_of(&f.header["dt"]), 1.0 / 2000.0);
    assert_eq!(
        f.frames.len(),
        frame_schedule(1.0 / 2000.0, 0.05, 100.0).len()
    );
}

#[test]
fn an_override_error_names_the_overrides() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&["run", &scene, "--fps", "5000", "--integrator", "rk4"]);
    run.expect_status(EXIT_BAD_INPUT);
    assert!(
        run.stderr.contains("simulation.frame_rate") && run.stderr.contains("(from --fps 5000)"),
        "{}",
        run.stderr
    );
}

#[test]
fn every_integrator_runs() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    for name in [
        "explicit-euler",
        "symplectic-euler",
        "midpoint",
        "rk4",
        "implicit-euler",
    ] {
        let run = sb.run(&["run", &scene, "--integrator", name, "--out", "-", "--quiet"]);
        run.expect_status(EXIT_OK);
        let f = parse_jsonl(&run.stdout_text());
        assert_eq!(f.header["integrator"], name);
        assert_eq!(f.frames.len(), 6, "{name}");
        for (k, frame) in f.frames.iter().enumerate() {
            assert_frame_shape(frame, k, 27);
        }
        // It moved: the body was thrown sideways under gravity.
        assert_ne!(f.frames[0]["positions"], f.frames[5]["positions"], "{name}");
    }
}

// ---------------------------------------------------------------- stdout, stderr

#[test]
fn out_dash_writes_header_and_frames_to_stdout() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&["run", &scene, "--out", "-"]);
    run.expect_status(EXIT_OK);
    let f = parse_jsonl(&run.stdout_text());
    assert_eq!(f.header["softbody_frames"], 1);
    assert_eq!(f.frames.len(), 6);
    assert_eq!(
        entries(sb.path()),
        ["s.toml"],
        "no file written, no out/ directory created"
    );
    assert!(
        !run.stderr.contains("softbody_frames"),
        "frames do not leak to stderr"
    );
}

#[test]
fn no_progress_bar_when_stderr_is_not_a_terminal() {
    let cube = Cube {
        duration: 0.6, // more than one progress interval of steps
        frame_rate: 10.0,
        ..Cube::default()
    };
    let (sb, scene) = sandbox_with(&cube, "s");
    let run = sb.run(&["run", &scene, "--out", "f.jsonl"]);
    run.expect_status(EXIT_OK);
    assert!(
        !run.stderr.contains('\r') && !run.stderr.contains('\x1b'),
        "no carriage returns or escape sequences: {:?}",
        run.stderr
    );
    let lines: Vec<&str> = run.stderr.lines().collect();
    assert_eq!(lines.len(), 1, "one summary line: {:?}", run.stderr);
    assert!(lines[0].contains("f.jsonl"), "{}", lines[0]);
}

#[test]
fn quiet_prints_nothing_on_stderr() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&["run", &scene, "--quiet"]);
    run.expect_status(EXIT_OK);
    assert_eq!(run.stderr, "");
    assert!(sb.path().join("out/s.jsonl").is_file());
    let run = sb.run(&["run", &scene, "-q", "--out", "-"]);
    run.expect_status(EXIT_OK);
    assert_eq!(run.stderr, "");
    parse_jsonl(&run.stdout_text());
}

// ---------------------------------------------------------------- determinism

/// Runs `cube` with 1 and 2 threads and asserts the JSON Lines agree byte for byte except the
/// header's `device`.
#[track_caller]
fn assert_thread_count_invariant(cube: &Cube) {
    let (sb, scene) = sandbox_with(cube, "s");
    let outputs: Vec<String> = ["1", "2"]
        .iter()
        .map(|threads| {
            let run = sb.run(&["run", &scene, "--threads", threads, "--out", "-", "--quiet"]);
            run.expect_status(EXIT_OK);
            run.stdout_text()
        })
        .collect();
    let (one, two) = (parse_jsonl(&outputs[0]), parse_jsonl(&outputs[1]));
    assert_eq!(
        one.frames.len(),
        frame_schedule(cube.dt, cube.duration, cube.frame_rate).len()
    );
    let strip = |mut h: Value| {
        h.as_object_mut().unwrap().remove("device");
        h
    };
    assert_ne!(
        one.header["device"], two.header["device"],
        "the device names the thread count"
    );
    assert_eq!(strip(one.header), strip(two.header));
    for (k, (a, b)) in one.frame_lines.iter().zip(&two.frame_lines).enumerate() {
        assert!(a == b, "frame {k} differs between 1 and 2 threads");
    }
    assert_eq!(one.frame_lines.len(), two.frame_lines.len());
}

#[test]
fn one_and_two_threads_give_identical_frames_symplectic() {
    // 4913 particles: per-particle reductions span more than one 8192-value chunk (3N values).
    assert_thread_count_invariant(&Cube {
        resolution: [17, 17, 17],
        duration: 0.03,
        frame_rate: 100.0,
        mass: 50.0, // 0.01 kg a particle: dt = 1 ms is well within the stable step
        stiffness: 100.0,
        ..Cube::default()
    });
}

#[test]
fn one_and_two_threads_give_identical_frames_implicit() {
    assert_thread_count_invariant(&Cube {
        integrator: "implicit-euler",
        resolution: [8, 8, 8],
        dt: 0.005,
        duration: 0.05,
        frame_rate: 100.0,
        stiffness: 2000.0,
        center: [0.0, 0.45, 0.0], // starts in contact with the ground
        ..Cube::default()
    });
}

// ---------------------------------------------------------------- instability

/// The step, time and particle an instability message names ("... at step S (t = T s):
/// particle P ...").
#[track_caller]
fn instability_in(stderr: &str) -> (f64, f64, f64) {
    // The error, after the warning of a step above the stable estimate that comes before it.
    let msg = &stderr[stderr
        .find("error: ")
        .unwrap_or_else(|| panic!("no error in:\n{stderr}"))..];
    let number_after = |label: &str| -> f64 {
        let at = msg
            .find(label)
            .unwrap_or_else(|| panic!("the message has no {label:?}:\n{msg}"));
        let rest = &msg[at + label.len()..];
        let end = rest
            .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == 'e' || c == '-'))
            .unwrap_or(rest.len());
        rest[..end]
            .parse()
            .unwrap_or_else(|_| panic!("no number after {label:?}:\n{msg}"))
    };
    (
        number_after("step "),
        number_after("t = "),
        number_after("particle "),
    )
}

#[test]
fn unstable_run_exits_3_naming_step_time_particle_and_remedy() {
    let cube = Cube::unstable();
    let (sb, scene) = sandbox_with(&cube, "stiff");
    let out = sb.path().join("frames.jsonl");
    let run = sb.run(&["run", &scene, "--out", out.to_str().unwrap()]);
    run.expect_status(EXIT_UNSTABLE);
    let msg = &run.stderr;

    let (step, time, particle) = instability_in(msg);
    assert!(step >= 1.0 && step.fract() == 0.0, "{msg}");
    // To four significant digits.
    assert!(
        (time - step * cube.dt).abs() <= 5e-4 * time,
        "t = step·dt: {msg}"
    );
    assert!(particle < cube.particles() as f64, "{msg}");
    assert!(msg.contains("smaller dt"), "suggests a smaller dt: {msg}");
    assert!(
        msg.contains("implicit-euler"),
        "suggests implicit-euler: {msg}"
    );
    assert!(
        msg.contains("frames.jsonl"),
        "says where the frames are: {msg}"
    );

    let planned = frame_schedule(cube.dt, cube.duration, cube.frame_rate);
    let f = read_jsonl(&out);
    assert!(
        !f.frames.is_empty(),
        "at least the initial frame is written"
    );
    assert!(
        f.frames.len() < planned.len(),
        "{} of {} frames: the run stopped early",
        f.frames.len(),
        planned.len()
    );
    for (k, frame) in f.frames.iter().enumerate() {
        assert_frame_shape(frame, k, cube.particles());
        assert_eq!(f64_of(&frame["time"]), planned[k] as f64 * cube.dt);
        assert!(
            f64_of(&frame["time"]) < time,
            "frame {k} precedes the instability"
        );
    }
    assert!(
        f.frames.len() == planned.len() || (planned[f.frames.len()] as f64) >= step,
        "every frame before the unstable step is written"
    );
}

#[test]
fn unstable_run_to_stdout_exits_3_with_valid_frames() {
    let cube = Cube::unstable();
    let (sb, scene) = sandbox_with(&cube, "stiff");
    let run = sb.run(&["run", &scene, "--out", "-", "--quiet"]);
    run.expect_status(EXIT_UNSTABLE);
    assert!(
        run.stderr.contains("unstable"),
        "--quiet still reports the failure: {}",
        run.stderr
    );
    let f = parse_jsonl(&run.stdout_text());
    assert!(!f.frames.is_empty());
    assert!(f.frames.len() < frame_schedule(cube.dt, cube.duration, cube.frame_rate).len());
}

#[test]
fn run_diverging_between_frames_exits_3_with_the_frames_before_it() {
    // Stiff enough that explicit Euler overflows to a non-finite state within 100 steps, between
    // frame 0 and frame 1 (one frame a second): the solver's per-step check stops the run.
    let cube = Cube {
        integrator: "explicit-euler",
        dt: 0.01,
        duration: 5.0,
        frame_rate: 1.0,
        resolution: [4, 4, 4],
        stiffness: 2.0e6,
        damping: 0.0,
        ground: false,
        ..Cube::default()
    };
    let (sb, scene) = sandbox_with(&cube, "s");
    let out = sb.path().join("frames.jsonl");
    let run = sb.run(&["run", &scene, "--out", out.to_str().unwrap()]);
    run.expect_status(EXIT_UNSTABLE);
    let (step, time, particle) = instability_in(&run.stderr);
    assert!(
        step > 1.0 && step < 100.0,
        "diverges between the first two frames: {}",
        run.stderr
    );
    assert!((time - step * cube.dt).abs() < 1e-9, "{}", run.stderr);
    assert!(particle < 64.0);
    assert!(run.stderr.contains("smaller dt") && run.stderr.contains("implicit-euler"));
    let f = read_jsonl(&out);
    assert_eq!(f.frames.len(), 1, "frame 0 only");
    assert_frame_shape(&f.frames[0], 0, 64);
}

#[test]
fn the_same_stiff_cube_is_stable_with_implicit_euler() {
    let cube = Cube::unstable();
    let (sb, scene) = sandbox_with(&cube, "stiff");
    let run = sb.run(&[
        "run",
        &scene,
        "--integrator",
        "implicit-euler",
        "--duration",
        "0.5",
        "--out",
        "-",
        "--quiet",
    ]);
    run.expect_status(EXIT_OK);
    assert_eq!(
        parse_jsonl(&run.stdout_text()).frames.len(),
        frame_schedule(0.01, 0.5, 50.0).len()
    );
}

// ---------------------------------------------------------------- check

/// Springs of each family on an nx×ny×nz grid, counted by offsets: structural (1,0,0)-type,
/// shear the face diagonals (2 per grid face) and body diagonals (4 per cell), bending
/// (2,0,0)-type.
fn grid_springs([nx, ny, nz]: [u64; 3]) -> (u64, u64, u64) {
    let structural = (nx - 1) * ny * nz + nx * (ny - 1) * nz + nx * ny * (nz - 1);
    let faces = (nx - 1) * (ny - 1) * nz + (nx - 1) * ny * (nz - 1) + nx * (ny - 1) * (nz - 1);
    let shear = 2 * faces + 4 * (nx - 1) * (ny - 1) * (nz - 1);
    let bending = nx.saturating_sub(2) * ny * nz
        + nx * ny.saturating_sub(2) * nz
        + nx * ny * nz.saturating_sub(2);
    (structural, shear, bending)
}

#[test]
fn check_json_counts_particles_springs_and_mass() {
    let sb = Sandbox::new();
    let mut text = Cube {
        resolution: [3, 4, 5],
        mass: 2.5,
        ..Cube::default()
    }
    .toml();
    // Springs of a particles body count as structural.
    text += "\n[[body]]\nname = \"chain\"\nkind = \"particles\"\n\
             positions = [[3.0, 1.0, 0.0], [4.0, 1.0, 0.0], [5.0, 1.0, 0.0]]\n\
             masses = [0.25, 0.125, 0.125]\n\
             springs = [{ a = 0, b = 1, stiffness = 10.0 }, { a = 1, b = 2, stiffness = 10.0 }]\n";
    let scene = sb.write("s.toml", &text);
    let run = sb.run(&["check", scene.to_str().unwrap(), "--json"]);
    run.expect_status(EXIT_OK);
    let stdout = run.stdout_text();
    assert_eq!(stdout.trim_end().lines().count(), 1, "one object: {stdout}");
    let v: Value = serde_json::from_str(&stdout).expect("JSON");
    let (structural, shear, bending) = grid_springs([3, 4, 5]);
    assert_eq!(
        (structural, shear, bending),
        (133, 292, 86),
        "test's own formula"
    );
    assert_eq!(v["particles"], 60 + 3);
    assert_eq!(v["springs"]["structural"], structural + 2);
    assert_eq!(v["springs"]["shear"], shear);
    assert_eq!(v["springs"]["bending"], bending);
    assert_eq!(f64_of(&v["total_mass"]), 3.0);
    assert_eq!(f64_of(&v["bodies"][0]["mass"]), 2.5);
    assert_eq!(f64_of(&v["bodies"][1]["mass"]), 0.5);
    assert!(v["bodies"][0].get("volume").is_none(), "{v}");
    let stable = f64_of(&v["stable_dt"]);
    assert!(stable.is_finite() && stable > 0.0, "{v}");
}

/// A mesh body given a density: `check` says what volume it weighed, the box's 0.4 × 0.3 ×
/// 0.2 m (not the 0.0309 m³ of its 6 × 5 × 3 cells of 7 cm), in the text and the JSON.
#[test]
fn check_says_what_a_density_weighed() {
    let sb = Sandbox::new();
    let mut obj = String::new();
    for i in 0..8 {
        let [x, y, z] = [i & 1, i >> 1 & 1, i >> 2 & 1];
        obj += &format!("v {x} {y} {z}\n");
    }
    // Each face as two triangles, counter-clockwise seen from outside (OBJ counts from 1).
    for [a, b, c, d] in [
        [1, 3, 4, 2],
        [5, 6, 8, 7],
        [1, 2, 6, 5],
        [3, 7, 8, 4],
        [1, 5, 7, 3],
        [2, 4, 8, 6],
    ] {
        obj += &format!("f {a} {b} {c}\nf {a} {c} {d}\n");
    }
    sb.write("box.obj", &obj);
    let scene = sb.write(
        "s.toml",
        "[simulation]\ndt = 0.001\nduration = 0.01\n[[body]]\nname = \"box\"\nkind = \"mesh\"\n\
         file = \"box.obj\"\nscale = [0.4, 0.3, 0.2]\ncell = 0.07\ndensity = 500.0\n",
    );
    let run = sb.run(&["check", scene.to_str().unwrap()]);
    run.expect_status(EXIT_OK);
    let text = run.stdout_text();
    assert!(
        text.contains(
            "    box        168 particles from 0, 12 kg (500 kg/m³ × 0.024 m³ the mesh encloses)\n"
        ),
        "{text}"
    );
    let run = sb.run(&["check", scene.to_str().unwrap(), "--json"]);
    run.expect_status(EXIT_OK);
    let v: Value = serde_json::from_str(&run.stdout_text()).unwrap();
    let body = &v["bodies"][0];
    assert!((f64_of(&body["mass"]) - 12.0).abs() < 1e-12, "{v}");
    assert!((f64_of(&body["volume"]) - 0.024).abs() < 1e-15, "{v}");
    assert_eq!(f64_of(&body["density"]), 500.0);
    assert_eq!(body["volume_of"], "mesh");
}

#[test]
fn check_json_stable_dt_of_one_spring_is_two_over_omega() {
    // Two unit masses on one spring k = 50: ω² = 2k/m = 100, leapfrog bound 2/ω = 0.2 s.
    let sb = Sandbox::new();
    let scene = sb.write(
        "s.toml",
        "[simulation]\ndt = 0.001\nduration = 1.0\n\
         [[body]]\nkind = \"particles\"\npositions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\n\
         masses = [1.0, 1.0]\nsprings = [{ a = 0, b = 1, stiffness = 50.0 }]\n",
    );
    let run = sb.run(&["check", scene.to_str().unwrap(), "--json"]);
    run.expect_status(EXIT_OK);
    let v: Value = serde_json::from_str(&run.stdout_text()).unwrap();
    assert_eq!(v["particles"], 2);
    assert_eq!(v["springs"]["structural"], 1);
    assert_eq!(v["springs"]["shear"], 0);
    assert_eq!(v["springs"]["bending"], 0);
    assert_eq!(f64_of(&v["total_mass"]), 2.0);
    assert!((f64_of(&v["stable_dt"]) - 0.2).abs() < 1e-12, "{v}");
}

#[test]
fn check_json_of_a_scene_without_springs() {
    let sb = Sandbox::new();
    let scene = sb.write(
        "s.toml",
        "[simulation]\ndt = 0.001\nduration = 1.0\n\
         [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0]]\nmasses = [0.5]\n",
    );
    let run = sb.run(&["check", scene.to_str().unwrap(), "--json"]);
    run.expect_status(EXIT_OK);
    let v: Value = serde_json::from_str(&run.stdout_text()).unwrap();
    assert_eq!(v["particles"], 1);
    assert_eq!(v["springs"]["structural"], 0);
    assert!(v.get("stable_dt").is_some(), "the key is present: {v}");
}

#[test]
fn check_says_valid_and_writes_nothing() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let run = sb.run(&["check", &scene]);
    run.expect_status(EXIT_OK);
    let text = run.stdout_text();
    assert!(text.contains("valid"), "{text}");
    assert!(text.contains("27"), "particle count: {text}");
    assert_eq!(entries(sb.path()), ["s.toml"]);
}

#[test]
fn check_warns_when_dt_is_above_the_stable_step() {
    let (sb, scene) = sandbox_with(&Cube::unstable(), "s");
    let run = sb.run(&["check", &scene]);
    run.expect_status(EXIT_OK);
    assert!(
        run.stdout_text().contains("unstable"),
        "{}",
        run.stdout_text()
    );
}

/// A body that starts inside the terrain is valid but warned about, by `check` (text and
/// `--json`) and by `run` (on stderr, also with --quiet, and the run goes on); one placed on the
/// ground is not.
#[test]
fn a_body_starting_inside_the_terrain_is_warned_about() {
    let sb = Sandbox::new();
    let sunk = Cube {
        center: [0.0, 0.25, 0.0],
        ..Cube::default()
    };
    let on = Cube {
        center: [0.0, 0.5, 0.0],
        ..Cube::default()
    };
    sb.write("sunk.toml", &sunk.toml());
    sb.write("on.toml", &on.toml());
    let says = "body `cube` starts with 9 of its 27 particles inside terrain[0]";

    let check = sb.run(&["check", "sunk.toml"]);
    check.expect_status(EXIT_OK);
    assert!(
        check.stdout_text().contains(&format!("warning     {says}")),
        "{}",
        check.stdout_text()
    );
    let json = sb.run(&["check", "sunk.toml", "--json"]);
    let v: Value = serde_json::from_str(&json.stdout_text()).unwrap();
    let warnings = v["warnings"].as_array().unwrap();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].as_str().unwrap().starts_with(says));

    let run = sb.run(&["run", "sunk.toml", "--out", "f.jsonl", "--quiet"]);
    run.expect_status(EXIT_OK);
    assert!(
        run.stderr.contains(&format!("warning: {says}")),
        "{}",
        run.stderr
    );

    let json = sb.run(&["check", "on.toml", "--json"]);
    let v: Value = serde_json::from_str(&json.stdout_text()).unwrap();
    assert_eq!(v["warnings"], serde_json::json!([]));
    let run = sb.run(&["run", "on.toml", "--out", "g.jsonl", "--quiet"]);
    run.expect_status(EXIT_OK);
    assert_eq!(run.stderr, "", "no warning for a body on the ground");
}

// ---------------------------------------------------------------- signals

/// Starts `softbody run` on an hour-long scene writing `f.jsonl` in `sb`, and waits until it
/// has staged some frames (its `.softbody-*.part` file has grown past the header).
#[cfg(unix)]
// The child is returned, and its callers wait for it.
#[allow(clippy::zombie_processes)]
fn start_a_long_run(sb: &Sandbox) -> std::process::Child {
    let long = Cube {
        duration: 3600.0,
        ..Cube::default()
    };
    sb.write("long.toml", &long.toml());
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_softbody"))
        .args(["run", "long.toml", "--out", "f.jsonl", "--quiet"])
        .current_dir(sb.path())
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    loop {
        let staged = staged_files(sb);
        let grown = staged
            .iter()
            .any(|n| std::fs::metadata(sb.path().join(n)).is_ok_and(|m| m.len() > 4096));
        if grown {
            return child;
        }
        if started.elapsed().as_secs() >= 60 {
            let _ = child.kill();
            let _ = child.wait();
            panic!("no frames staged after a minute");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

#[cfg(unix)]
fn staged_files(sb: &Sandbox) -> Vec<String> {
    entries(sb.path())
        .into_iter()
        .filter(|n| n.starts_with(".softbody-"))
        .collect()
}

#[cfg(unix)]
fn signal(child: &std::process::Child, name: &str) {
    let sent = std::process::Command::new("kill")
        .args([&format!("-{name}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
}

/// SIGINT and SIGTERM stop a run after complete frames: exit 130 / 143, every frame written so
/// far kept (a valid JSON Lines file, frames 0, 1, … in order), nothing staged left behind.
#[cfg(unix)]
#[test]
fn a_signal_stops_the_run_keeping_its_complete_frames() {
    for (name, status) in [("INT", 130), ("TERM", 143)] {
        let sb = Sandbox::new();
        let child = start_a_long_run(&sb);
        signal(&child, name);
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(status), "SIG{name}: {stderr}");
        assert!(stderr.contains("stopped after"), "SIG{name}: {stderr}");
        let frames = read_jsonl(&sb.path().join("f.jsonl"));
        assert!(!frames.frames.is_empty(), "SIG{name}: no frame kept");
        for (k, frame) in frames.frames.iter().enumerate() {
            assert_eq!(frame["frame"], k, "SIG{name}");
        }
        assert_eq!(staged_files(&sb), Vec::<String>::new(), "SIG{name}");
    }
}

/// A run killed outright (SIGKILL) leaves its staged file; the next run to the same
/// destination removes it, and leaves another destination's staging alone.
#[cfg(unix)]
#[test]
fn the_next_run_removes_what_a_killed_run_staged() {
    let sb = Sandbox::new();
    let mut child = start_a_long_run(&sb);
    child.kill().unwrap();
    child.wait().unwrap();
    let left = staged_files(&sb);
    assert_eq!(left.len(), 1, "{left:?}");
    // Another destination's (a run still going: this process) stays.
    let other = format!(
        ".softbody-{}-abcdef-0123456789abcdef.part",
        std::process::id()
    );
    sb.write(&other, "someone else's");
    sb.write("short.toml", &Cube::default().toml());
    sb.run(&["run", "short.toml", "--out", "f.jsonl", "--quiet"])
        .expect_status(EXIT_OK);
    read_jsonl(&sb.path().join("f.jsonl"));
    assert_eq!(staged_files(&sb), [other]);
}

/// `check` takes the overrides `run` takes (here `--dt 1/60` as a fraction and
/// `--integrator`), and describes the scene as it would run.
#[test]
fn check_takes_the_overrides_of_run() {
    let (sb, scene) = sandbox_with(&Cube::default(), "s");
    let o = sb.run(&[
        "check",
        &scene,
        "--json",
        "--dt",
        "1/60",
        "--integrator",
        "implicit-euler",
        "--duration",
        "1",
        "--fps",
        "30",
    ]);
    o.expect_status(EXIT_OK);
    let v: Value = serde_json::from_str(&o.stdout_text()).unwrap();
    assert_eq!(v["dt"].as_f64(), Some(1.0 / 60.0));
    assert_eq!(v["integrator"], "implicit-euler");
    assert_eq!(
        (v["steps"].as_u64(), v["frames"].as_u64()),
        (Some(60), Some(31))
    );
    sb.run(&["check", &scene, "--dt", "-1"])
        .expect_status(EXIT_BAD_INPUT);
}
