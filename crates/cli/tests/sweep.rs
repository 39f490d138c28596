//! `softbody sweep`: runs in parallel into one file per run and a manifest; resumable; Slurm
//! array tasks; exit statuses.

mod common;

use common::*;
use serde_json::Value;

/// A sandbox with the cube scene `s.toml` and the sweep `sweep.toml` made of `body`.
fn sandbox(body: &str) -> (Sandbox, String) {
    let sb = Sandbox::new();
    sb.write("s.toml", &Cube::default().toml());
    let sweep = sb.write("sweep.toml", &format!("scene = \"s.toml\"\n{body}"));
    (sb, sweep.to_str().unwrap().to_owned())
}

/// The manifest's records, by run number.
fn records(sb: &Sandbox, name: &str) -> Vec<Value> {
    let text = std::fs::read_to_string(sb.path().join("out/sweep").join(name)).unwrap();
    let mut lines = text.lines();
    let header: Value = serde_json::from_str(lines.next().unwrap()).unwrap();
    assert_eq!(header["softbody_sweep"], 2);
    assert_eq!(header["job"]["backend"], "cpu");
    let mut records: Vec<Value> = lines.map(|l| serde_json::from_str(l).unwrap()).collect();
    records.sort_by_key(|r| r["run"].as_u64().unwrap());
    records
}

#[test]
fn a_grid_sweep_writes_each_run_and_the_manifest_then_resumes() {
    let (sb, sweep) = sandbox(
        "format = \"jsonl\"\nmetrics = [\"frames\", \"final_time\"]\n\
         [grid]\n\"body[0].mass\" = [1.0, -1.0]\n\"simulation.duration\" = [0.02, 0.03]\n",
    );
    let out = sb.run(&["sweep", &sweep, "--workers", "2"]);
    out.expect_status(EXIT_OK);
    assert!(
        out.stderr
            .contains("4 runs (0 finished before): 2 ok, 0 unstable, 2 invalid, 0 failed"),
        "{}",
        out.stderr
    );
    let r = records(&sb, "manifest.jsonl");
    assert_eq!(r.len(), 4);
    // Run 1: mass 1, duration 0.03 (the last key varies fastest).
    assert_eq!(r[1]["parameters"]["body[0].mass"], 1.0);
    assert_eq!(r[1]["parameters"]["simulation.duration"], 0.03);
    assert_eq!(r[1]["status"], "ok");
    assert_eq!(r[1]["exit_status"], 0);
    assert_eq!(r[1]["file"], "runs/run-000001.jsonl");
    assert_eq!(
        r[1]["metrics"]["frames"],
        frame_schedule(0.001, 0.03, 100.0).len()
    );
    assert_eq!(r[1]["metrics"]["final_time"], 0.03);
    // Its frames are the run's, with the scene text of the values it ran with.
    let frames = read_jsonl(&sb.path().join("out/sweep/runs/run-000001.jsonl"));
    assert_eq!(
        frames.frames.len(),
        frame_schedule(0.001, 0.03, 100.0).len()
    );
    let text = frames.header["scene_text"].as_str().unwrap();
    assert!(text.contains("duration = 0.03"), "{text}");
    // Runs 2 and 3: mass -1 is refused, with the scene's message; nothing written.
    assert_eq!(r[2]["status"], "invalid");
    assert_eq!(r[2]["exit_status"], 2);
    assert!(
        r[2]["error"]
            .as_str()
            .unwrap()
            .contains("body[0].mass: must be greater than zero, not -1")
    );
    assert_eq!(r[2]["file"], Value::Null);
    assert_eq!(
        entries(&sb.path().join("out/sweep/runs")),
        ["run-000000.jsonl", "run-000001.jsonl"]
    );

    // Again: every run is finished, nothing runs, the manifest is kept.
    let again = sb.run(&["sweep", &sweep]);
    again.expect_status(EXIT_OK);
    assert!(
        again.stderr.contains("4 runs (4 finished before): 0 ok"),
        "{}",
        again.stderr
    );
    assert_eq!(records(&sb, "manifest.jsonl"), r);
}

#[test]
fn slurm_array_tasks_each_run_their_share_and_a_plain_sweep_merges_them() {
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0]\n");
    for task in ["0", "1", "2"] {
        sb.run(&["sweep", &sweep, "--task-index", task, "--quiet"])
            .expect_status(EXIT_OK);
        let own = records(&sb, &format!("manifest-task-{task}.jsonl"));
        assert_eq!(own.len(), 1);
        assert_eq!(own[0]["run"].as_u64().unwrap().to_string(), task);
    }
    // Past the end: no run to take, refused rather than an exit 0 that did nothing.
    let past = sb.run(&["sweep", &sweep, "--task-index", "7", "--quiet"]);
    past.expect_status(EXIT_BAD_INPUT);
    assert!(
        past.stderr.contains("task index 7 names no run"),
        "{}",
        past.stderr
    );
    let past = sb.run(&["sweep", &sweep, "--task-index", "2", "--task-count", "2"]);
    past.expect_status(EXIT_BAD_INPUT);
    let merged = sb.run(&["sweep", &sweep]);
    merged.expect_status(EXIT_OK);
    assert!(
        merged.stderr.contains("3 runs (3 finished before)"),
        "{}",
        merged.stderr
    );
    assert_eq!(records(&sb, "manifest.jsonl").len(), 3);
    // --task-count shares the runs out: task 1 of 2 takes run 1 alone.
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0]\n");
    sb.run(&[
        "sweep",
        &sweep,
        "--task-index",
        "1",
        "--task-count",
        "2",
        "--quiet",
    ])
    .expect_status(EXIT_OK);
    let r = records(&sb, "manifest-task-1.jsonl");
    assert_eq!(r.len(), 1);
    assert_eq!(r[0]["run"], 1);
}

#[test]
fn a_bad_sweep_file_is_bad_input_with_its_line() {
    let (sb, sweep) = sandbox("[grid]\n\"body[0].mass\" = 2.0\n");
    let out = sb.run(&["sweep", &sweep]);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        out.stderr.starts_with(&format!(
            "error: {sweep}:3:18: grid.body[0].mass: a grid parameter takes a non-empty list"
        )),
        "{}",
        out.stderr
    );
    assert!(!sb.path().join("out").exists());
    // Another sweep's manifest in the out directory is refused too.
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0]\n");
    sb.run(&["sweep", &sweep, "--quiet"]).expect_status(EXIT_OK);
    sb.write(
        "sweep.toml",
        "scene = \"s.toml\"\nformat = \"none\"\n[grid]\n\"body[0].mass\" = [9.0]\n",
    );
    let out = sb.run(&["sweep", &sweep]);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(out.stderr.contains("is another sweep's"), "{}", out.stderr);
}

#[test]
fn unstable_runs_are_results_and_failed_writes_are_exit_1() {
    let (sb, sweep) = sandbox(
        "format = \"npz\"\n[[runs]]\n\"simulation.integrator\" = \"explicit-euler\"\n\
         \"simulation.dt\" = 0.01\n\"simulation.frame_rate\" = 50.0\n\"simulation.duration\" = 2.0\n\
         \"body[0].structural\" = { stiffness = 1e6 }\n",
    );
    let out = sb.run(&["sweep", &sweep]);
    out.expect_status(EXIT_OK);
    let r = records(&sb, "manifest.jsonl");
    assert_eq!(
        (r[0]["status"].as_str(), r[0]["exit_status"].as_u64()),
        (Some("unstable"), Some(3))
    );
    assert_eq!(
        r[0]["file"], "runs/run-000000.npz",
        "the frames before it are kept"
    );
    // runs/ is a file: the run's output cannot be made.
    let (sb, sweep) = sandbox("[grid]\n\"body[0].mass\" = [1.0]\n");
    sb.mkdir("out/sweep");
    sb.write("out/sweep/runs", "in the way");
    let out = sb.run(&["sweep", &sweep]);
    out.expect_status(EXIT_OUTPUT);
    assert!(out.stderr.contains("1 runs failed"), "{}", out.stderr);
    assert_eq!(records(&sb, "manifest.jsonl")[0]["status"], "failed");
}

#[test]
fn ray_without_the_python_package_is_bad_input() {
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0]\n");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_softbody"))
        .args(["sweep", &sweep, "--ray", "auto"])
        .current_dir(sb.path())
        .env("SOFTBODY_PYTHON", "/nonexistent/python")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(EXIT_BAD_INPUT));
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(
        stderr.contains("cannot import with Ray: pip install ./crates/python ray"),
        "{stderr}"
    );
    assert!(!sb.path().join("out").exists());
}

#[test]
fn batch_needs_ray_and_a_positive_count() {
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0]\n");
    for args in [
        &["sweep", &sweep, "--batch", "4"][..],
        &["sweep", &sweep, "--ray", "local", "--batch", "0"],
        &["sweep", &sweep, "--ray", "local", "--batch", "x"],
    ] {
        let out = sb.run(args);
        out.expect_status(EXIT_BAD_INPUT);
        assert!(out.stderr.contains("--batch"), "{args:?}: {}", out.stderr);
    }
    assert!(!sb.path().join("out").exists());
}

#[test]
fn a_sweep_of_an_edited_scene_into_the_old_out_is_refused_and_the_old_records_kept() {
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0]\n");
    sb.run(&["sweep", &sweep, "--quiet"]).expect_status(EXIT_OK);
    let before = records(&sb, "manifest.jsonl");
    sb.write(
        "s.toml",
        &Cube {
            stiffness: 900.0,
            ..Cube::default()
        }
        .toml(),
    );
    let again = sb.run(&["sweep", &sweep]);
    again.expect_status(EXIT_BAD_INPUT);
    assert!(
        again.stderr.contains("another sweep job") && again.stderr.contains("the base scene"),
        "{}",
        again.stderr
    );
    assert_eq!(records(&sb, "manifest.jsonl"), before);
}

#[test]
fn a_sweep_into_an_out_another_process_writes_is_refused_at_once() {
    let (sb, sweep) = sandbox("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0]\n");
    let out = sb.path().join("out/sweep");
    std::fs::create_dir_all(&out).unwrap();
    let held = softbody::lock::OutputLock::directory(&out).unwrap();
    let refused = sb.run(&["sweep", &sweep]);
    refused.expect_status(EXIT_OUTPUT);
    assert!(
        refused
            .stderr
            .contains(&format!("(process {})", std::process::id())),
        "{}",
        refused.stderr
    );
    assert!(!out.join("manifest.jsonl").exists(), "nothing written");
    drop(held);
    sb.run(&["sweep", &sweep, "--quiet"]).expect_status(EXIT_OK);
}

/// Ctrl-C or SIGTERM ends the runs under way after their complete frames and records none of
/// them: exit 130 / 143, and the manifest holds its header alone, so a sweep run again runs
/// them.
#[cfg(unix)]
#[test]
fn a_signal_stops_a_sweep_recording_no_run_under_way() {
    for (name, status) in [("INT", 130), ("TERM", 143)] {
        let sb = Sandbox::new();
        let long = Cube {
            duration: 3600.0,
            ..Cube::default()
        };
        sb.write("s.toml", &long.toml());
        sb.write(
            "sweep.toml",
            "scene = \"s.toml\"\nformat = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0]\n",
        );
        let child = std::process::Command::new(env!("CARGO_BIN_EXE_softbody"))
            .args(["sweep", "sweep.toml", "--workers", "2", "--quiet"])
            .current_dir(sb.path())
            .stdin(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // The manifest is opened after the handlers are in place, before the runs start.
        let manifest = sb.path().join("out/sweep/manifest.jsonl");
        let started = std::time::Instant::now();
        while !manifest.exists() {
            assert!(
                started.elapsed().as_secs() < 60,
                "no manifest after a minute"
            );
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
        let sent = std::process::Command::new("kill")
            .args([&format!("-{name}"), &child.id().to_string()])
            .status()
            .unwrap();
        assert!(sent.success());
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(status), "SIG{name}: {stderr}");
        assert!(
            stderr.contains("stopped: 2 runs under way were not recorded"),
            "SIG{name}: {stderr}"
        );
        assert_eq!(
            records(&sb, "manifest.jsonl"),
            Vec::<Value>::new(),
            "SIG{name}"
        );
    }
}
