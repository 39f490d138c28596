//! The sweep from its file to its manifest: plans, located errors, jobs, local runs, resumption.

use std::collections::BTreeMap;

use serde_json::Value as Json;
use softbody_scene::SceneError;

use super::manifest::{header_line, read_records};
use super::*;

const SCENE: &str = "\
[simulation]
dt = 0.001
duration = 0.05
frame_rate = 100.0

[[body]]
name = \"cube\"
kind = \"cuboid\"
size = [0.2, 0.2, 0.2]
resolution = [3, 3, 3]
center = [0.0, 0.3, 0.0]
mass = 1.0
structural = { stiffness = 500.0, damping = 1.0 }

[[terrain]]
kind = \"plane\"
normal = [0.0, 1.0, 0.0]
friction = 0.3
";

fn sweep(body: &str) -> Result<Sweep, SweepError> {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("s.toml"), SCENE).unwrap();
    let text = format!("scene = \"s.toml\"\n{body}");
    Sweep::from_toml(&text, &dir.path().join("sweep.toml"))
}

#[test]
fn a_grid_is_every_combination_the_last_key_fastest() {
    let s =
        sweep("[grid]\n\"body[0].mass\" = [1.0, 2.0]\n\"terrain[0].friction\" = [0.1, 0.2, 0.3]\n")
            .unwrap();
    assert_eq!(s.len(), 6);
    let mass_friction = |i: usize| {
        let p = s.parameters(i);
        (p[0].1.as_float().unwrap(), p[1].1.as_float().unwrap())
    };
    assert_eq!(mass_friction(0), (1.0, 0.1));
    assert_eq!(mass_friction(2), (1.0, 0.3));
    assert_eq!(mass_friction(3), (2.0, 0.1));
    assert_eq!(mass_friction(5), (2.0, 0.3));
    assert_eq!(s.run_file(5).as_deref(), Some("runs/run-000005.npz"));
}

#[test]
fn random_draws_depend_on_the_seed_alone_and_stay_in_range() {
    let text = "[random]\nruns = 50\nseed = 7\n[random.parameters]\n\
                    \"body[0].mass\" = { uniform = [1.0, 3.0] }\n\
                    \"terrain[0].friction\" = { log_uniform = [0.01, 1.0] }\n\
                    \"simulation.integrator\" = { choice = [\"rk4\", \"midpoint\"] }\n";
    let a = sweep(text).unwrap();
    let b = sweep(text).unwrap();
    assert_eq!(a.len(), 50);
    let mut integrators = std::collections::BTreeSet::new();
    for i in 0..50 {
        assert_eq!(a.parameters(i), b.parameters(i), "same seed, same plan");
        let p: BTreeMap<_, _> = a.parameters(i).iter().cloned().collect();
        let mass = p["body[0].mass"].as_float().unwrap();
        let mu = p["terrain[0].friction"].as_float().unwrap();
        assert!((1.0..=3.0).contains(&mass) && (0.01..=1.0).contains(&mu));
        integrators.insert(p["simulation.integrator"].as_str().unwrap().to_owned());
    }
    assert_eq!(integrators.len(), 2, "both choices drawn in 50 runs");
    let c = sweep(&text.replace("seed = 7", "seed = 8")).unwrap();
    assert_ne!(a.parameters(0), c.parameters(0));
}

#[test]
fn bad_sweep_files_are_located() {
    let cases = [
        (
            "[grid]\n\"body[0].mass\" = 2.0\n",
            "grid.body[0].mass",
            "non-empty list",
        ),
        (
            "[grid]\n\"body[0]mass\" = [1.0]\n",
            "grid.body[0]mass",
            "is not a key path",
        ),
        ("", "(document)", "exactly one of"),
        (
            "format = \"xls\"\n[grid]\n\"body[0].mass\" = [1.0]\n",
            "format",
            "unknown format",
        ),
        (
            "metrics = [\"speed\"]\n[grid]\n\"body[0].mass\" = [1.0]\n",
            "metrics[0]",
            "unknown metric `speed`",
        ),
        (
            "[random]\nruns = 2\nseed = 1\n[random.parameters]\n\"body[0].mass\" = { uniform = [2.0, 1.0] }\n",
            "random.parameters.body[0].mass",
            "lo ≤ hi",
        ),
        (
            "colour = 1\n[grid]\n\"body[0].mass\" = [1.0]\n",
            "colour",
            "unknown field",
        ),
    ];
    for (body, key, says) in cases {
        let e = sweep(body).unwrap_err();
        let SweepError::File(SceneError::Invalid(d)) = &e else {
            panic!("{body}: {e}");
        };
        assert_eq!(d.key.to_string(), key, "{body}");
        assert!(d.message.contains(says), "{body}: {e}");
        assert!(e.is_bad_input());
    }
    // The base scene with the common settings must load.
    let e = sweep("set = { \"body[0].mass\" = -1.0 }\n[grid]\n\"terrain[0].friction\" = [0.1]\n")
        .unwrap_err();
    assert!(
        e.to_string().contains("(from set: body[0].mass = -1.0)"),
        "{e}"
    );
}

#[test]
fn jobs_record_ok_unstable_and_invalid_runs_with_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let s = sweep(
            "metrics = [\"frames\", \"min_height\", \"final_center\"]\n[[runs]]\n\"body[0].mass\" = 2.0\n\
             [[runs]]\n\"body[0].mass\" = -2.0\n\
             [[runs]]\n\"simulation.integrator\" = \"explicit-euler\"\n\"simulation.dt\" = 0.01\n\
             \"simulation.frame_rate\" = 50.0\n\"simulation.duration\" = 3.0\n\
             \"body[0].structural\" = { stiffness = 1e6 }\n",
        )
        .unwrap();
    let ok = s.job(0, dir.path()).run();
    assert_eq!(
        (ok.status, ok.exit_status, ok.error.as_deref()),
        (Status::Ok, 0, None)
    );
    assert_eq!(ok.metrics["frames"], Json::from(6));
    assert_eq!(ok.parameters["body[0].mass"], Json::from(2.0));
    assert_eq!(ok.file.as_deref(), Some("runs/run-000000.npz"));
    assert!(dir.path().join("runs/run-000000.npz").is_file());
    let center = ok.metrics["final_center"].as_array().unwrap();
    assert_eq!(center.len(), 3);
    assert!(ok.metrics["min_height"].as_f64().unwrap() > 0.0);

    let invalid = s.job(1, dir.path()).run();
    assert_eq!((invalid.status, invalid.exit_status), (Status::Invalid, 2));
    assert!(
        invalid
            .error
            .as_deref()
            .unwrap()
            .contains("must be greater than zero"),
        "{invalid:?}"
    );
    assert_eq!(invalid.file, None);
    assert_eq!(invalid.metrics["frames"], Json::from(0));
    assert_eq!(invalid.metrics["min_height"], Json::Null);
    assert!(!dir.path().join("runs/run-000001.npz").exists());

    let unstable = s.job(2, dir.path()).run();
    assert_eq!(
        (unstable.status, unstable.exit_status),
        (Status::Unstable, 3)
    );
    assert!(
        unstable
            .error
            .as_deref()
            .unwrap()
            .contains("became unstable")
    );
    assert_eq!(
        unstable.file.as_deref(),
        Some("runs/run-000002.npz"),
        "frames kept"
    );

    // A job travels as JSON and runs the same there: the same metrics, bit for bit.
    let json = serde_json::to_string(&s.job(0, &dir.path().join("elsewhere"))).unwrap();
    let shipped: Job = serde_json::from_str(&json).unwrap();
    let again = shipped.run();
    assert_eq!(again.metrics, ok.metrics);
}

#[test]
fn a_local_sweep_writes_the_manifest_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let s =
        sweep("format = \"jsonl\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, -1.0, 3.0]\n").unwrap();
    let out = dir.path().join("out");
    let options = Options {
        workers: Some(2),
        task: None,
        stop: None,
    };
    let first = run_local(&s, &out, &options, &|_, _| {}).unwrap();
    assert_eq!(
        first,
        Outcome {
            planned: 4,
            ok: 3,
            invalid: 1,
            ..Outcome::default()
        }
    );
    let text = std::fs::read_to_string(out.join(MANIFEST)).unwrap();
    assert_eq!(text.lines().count(), 1 + 4, "a header and a line per run");
    let header: Json = serde_json::from_str(text.lines().next().unwrap()).unwrap();
    assert_eq!(header["softbody_sweep"], Json::from(MANIFEST_VERSION));
    assert_eq!(header["runs"], Json::from(4));
    let records = read_records(&out.join(MANIFEST)).unwrap();
    let mut runs: Vec<usize> = records.iter().map(|r| r.run).collect();
    runs.sort();
    assert_eq!(runs, [0, 1, 2, 3]);

    // Everything finished: a second sweep runs nothing and keeps the records.
    let second = run_local(&s, &out, &options, &|_, _| {}).unwrap();
    assert_eq!((second.skipped, second.ok + second.invalid), (4, 0));
    assert_eq!(read_records(&out.join(MANIFEST)).unwrap().len(), 4);

    // A failed record and a half-written line are run again.
    let mut failed = records.iter().find(|r| r.run == 3).unwrap().clone();
    failed.status = Status::Failed;
    failed.exit_status = 1;
    let kept: Vec<String> = records
        .iter()
        .filter(|r| r.run != 3 && r.run != 0)
        .map(|r| serde_json::to_string(r).unwrap())
        .collect();
    std::fs::write(
        out.join(MANIFEST),
        format!(
            "{}\n{}\n{}\n{{\"run\": 0, \"param",
            header_line(&s),
            kept.join("\n"),
            serde_json::to_string(&failed).unwrap()
        ),
    )
    .unwrap();
    let third = run_local(&s, &out, &options, &|_, _| {}).unwrap();
    assert_eq!((third.skipped, third.ok), (2, 2));
    let records = read_records(&out.join(MANIFEST)).unwrap();
    assert_eq!(records.len(), 4, "one record per run after the rewrite");
    assert!(records.iter().all(|r| r.status.finished()));

    // Another sweep's manifest is refused.
    let other = sweep("[grid]\n\"body[0].mass\" = [5.0]\n").unwrap();
    let e = run_local(&other, &out, &options, &|_, _| {}).unwrap_err();
    assert!(
        e.is_bad_input() && e.to_string().contains("another sweep"),
        "{e}"
    );
}

#[test]
fn slurm_tasks_write_their_own_manifests_and_a_sweep_merges_them() {
    let dir = tempfile::tempdir().unwrap();
    let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0]\n").unwrap();
    let out = dir.path().join("out");
    assert_eq!(task_runs(3, Some((1, 1))), [1]);
    assert_eq!(task_runs(3, Some((5, 1))), Vec::<usize>::new());
    assert_eq!(task_runs(5, Some((1, 2))), [1, 3]);
    for i in 0..3 {
        let options = Options {
            workers: Some(1),
            task: Some((i, 1)),
            stop: None,
        };
        let o = run_local(&s, &out, &options, &|_, _| {}).unwrap();
        assert_eq!((o.planned, o.ok), (1, 1));
        let own = read_records(&out.join(format!("manifest-task-{i}.jsonl"))).unwrap();
        assert_eq!(own.len(), 1);
        assert_eq!(own[0].run, i);
        assert_eq!(own[0].file, None, "metrics only");
    }
    let merged = run_local(&s, &out, &Options::default(), &|_, _| {}).unwrap();
    assert_eq!((merged.skipped, merged.ok), (3, 0));
    assert_eq!(read_records(&out.join(MANIFEST)).unwrap().len(), 3);
}

/// 1,000 runs on two workers: each run's solver steps in a pool of its own, which nested
/// the runs on one stack (and overflowed it) when the workers were a rayon pool.
#[test]
fn a_thousand_runs_finish_on_two_workers() {
    let dir = tempfile::tempdir().unwrap();
    let scene = "[simulation]\ndt = 0.001\nduration = 0.005\nframe_rate = 200.0\n\
                     [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0]]\nmasses = [1.0]\n";
    std::fs::write(dir.path().join("p.toml"), scene).unwrap();
    let text = "scene = \"p.toml\"\nformat = \"none\"\nmetrics = [\"final_time\"]\n\
                    [random]\nruns = 1000\nseed = 5\n[random.parameters]\n\
                    \"body[0].masses\" = { choice = [[1.0], [2.0]] }\n";
    let s = Sweep::from_toml(text, &dir.path().join("sweep.toml")).unwrap();
    let options = Options {
        workers: Some(2),
        task: None,
        stop: None,
    };
    let out = dir.path().join("out");
    let o = run_local(&s, &out, &options, &|_, _| {}).unwrap();
    assert_eq!((o.planned, o.ok), (1000, 1000));
    let records = read_manifest(&s, &out).unwrap();
    assert_eq!(records.len(), 1000);
    assert!(records.iter().all(|r| r.metrics["final_time"] == 0.005));
}

#[test]
fn runs_are_reproducible_whatever_the_workers() {
    let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0]\n").unwrap();
    let metrics = |workers: usize| {
        let dir = tempfile::tempdir().unwrap();
        let options = Options {
            workers: Some(workers),
            task: None,
            stop: None,
        };
        run_local(&s, dir.path(), &options, &|_, _| {}).unwrap();
        let mut r = read_records(&dir.path().join(MANIFEST)).unwrap();
        r.sort_by_key(|r| r.run);
        r.into_iter().map(|r| r.metrics).collect::<Vec<_>>()
    };
    assert_eq!(metrics(1), metrics(3));
}

/// A sweep like `sweep(body)` whose base scene is `scene`, in `dir`.
fn sweep_in(dir: &Path, scene: &str, body: &str) -> Sweep {
    std::fs::write(dir.join("s.toml"), scene).unwrap();
    let text = format!("scene = \"s.toml\"\n{body}");
    std::fs::write(dir.join("sweep.toml"), &text).unwrap();
    Sweep::from_file(&dir.join("sweep.toml")).unwrap()
}

#[test]
fn a_sweep_of_another_job_into_an_existing_out_is_refused_not_answered_with_old_records() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let grid = "[grid]\n\"body[0].mass\" = [1.0, 2.0]\n";
    let options = Options {
        workers: Some(1),
        task: None,
        stop: None,
    };
    let first = sweep_in(dir.path(), SCENE, &format!("format = \"none\"\n{grid}"));
    run_local(&first, &out, &options, &|_, _| {}).unwrap();
    let manifest = std::fs::read(out.join(MANIFEST)).unwrap();

    // The same parameters, but the base scene edited, another format, other metrics, another
    // backend, other threads per run, or other settings of every run: each is another job.
    let edited = SCENE.replace("stiffness = 500.0", "stiffness = 800.0");
    let others = [
        (
            edited.as_str(),
            format!("format = \"none\"\n{grid}"),
            "base scene",
        ),
        (SCENE, format!("format = \"csv\"\n{grid}"), "format"),
        (
            SCENE,
            format!("format = \"none\"\nmetrics = [\"min_height\"]\n{grid}"),
            "metrics",
        ),
        (
            SCENE,
            format!("format = \"none\"\nthreads = 2\n{grid}"),
            "threads",
        ),
        (
            SCENE,
            format!("format = \"none\"\nset = {{ \"simulation.duration\" = 0.02 }}\n{grid}"),
            "base scene",
        ),
    ];
    for (scene, body, differs) in others {
        let other = sweep_in(dir.path(), scene, &body);
        let e = run_local(&other, &out, &options, &|_, _| {}).unwrap_err();
        assert!(e.is_bad_input(), "{e}");
        let message = e.to_string();
        assert!(message.contains(differs), "{differs}: {message}");
        assert!(message.contains("another --out"), "{message}");
        assert_eq!(
            std::fs::read(out.join(MANIFEST)).unwrap(),
            manifest,
            "{differs}: the manifest is left as it was"
        );
        let e = read_manifest(&other, &out).unwrap_err();
        assert!(
            e.is_bad_input(),
            "the records are not another job's answer: {e}"
        );
    }
    // The same job from a copy of the sweep file elsewhere is the same sweep.
    let again = sweep_in(dir.path(), SCENE, &format!("format = \"none\"\n{grid}"));
    let o = run_local(&again, &out, &options, &|_, _| {}).unwrap();
    assert_eq!((o.skipped, o.ok), (2, 0));
}

#[test]
fn a_plan_past_the_bound_is_refused_before_it_is_built() {
    for (body, at) in [
        (
            "[random]\nruns = 9223372036854775807\nseed = 1\n[random.parameters]\n\
             \"body[0].mass\" = { uniform = [1.0, 2.0] }\n",
            "random.runs",
        ),
        (
            &*format!(
                "[grid]\n{}",
                (0..8)
                    .map(|k| format!(
                        "\"body[0].{}\" = [{}]\n",
                        [
                            "mass",
                            "center",
                            "velocity",
                            "rotation",
                            "size",
                            "structural.stiffness",
                            "structural.damping",
                            "shear.stiffness"
                        ][k],
                        vec!["1.0"; 40].join(", ")
                    ))
                    .collect::<String>()
            ),
            "grid",
        ),
    ] {
        let e = sweep(body).unwrap_err();
        let SweepError::File(SceneError::Invalid(d)) = &e else {
            panic!("{body}: {e}")
        };
        assert_eq!(d.key.to_string(), at, "{e}");
        assert!(d.message.contains("1000000"), "{e}");
    }
}

#[test]
fn a_task_manifest_cut_mid_line_is_cut_before_it_is_appended_to() {
    let dir = tempfile::tempdir().unwrap();
    let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0]\n").unwrap();
    let out = dir.path().join("out");
    let task = |i| Options {
        workers: Some(1),
        task: Some((i, 1)),
        stop: None,
    };
    run_local(&s, &out, &task(0), &|_, _| {}).unwrap();
    let path = out.join("manifest-task-0.jsonl");
    let whole = std::fs::read_to_string(&path).unwrap();
    // A kill (or a full disk) in the middle of the record's line.
    std::fs::write(&path, &whole[..whole.len() - 20]).unwrap();
    let o = run_local(&s, &out, &task(0), &|_, _| {}).unwrap();
    assert_eq!((o.skipped, o.ok), (0, 1), "the cut record's run runs again");
    assert_eq!(
        std::fs::read_to_string(&path).unwrap().lines().count(),
        2,
        "the header and the new record, no remnant"
    );
    run_local(&s, &out, &task(1), &|_, _| {}).unwrap();
    let merged = run_local(&s, &out, &Options::default(), &|_, _| {}).unwrap();
    assert_eq!((merged.skipped, merged.ok), (2, 0));
}

#[test]
fn a_second_sweep_into_an_out_being_written_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0]\n").unwrap();
    let out = dir.path().join("out");
    let first = Manifest::open(&s, &out, None).unwrap();
    let e = run_local(&s, &out, &Options::default(), &|_, _| {}).unwrap_err();
    assert!(!e.is_bad_input(), "{e}");
    assert!(e.to_string().contains("another softbody process"), "{e}");
    // Slurm tasks share the directory with each other, not with a merging sweep.
    let task = |i| Options {
        workers: Some(1),
        task: Some((i, 2)),
        stop: None,
    };
    assert!(run_local(&s, &out, &task(0), &|_, _| {}).is_err());
    drop(first);
    let t0 = Manifest::open(&s, &out, Some(0)).unwrap();
    run_local(&s, &out, &task(1), &|_, _| {}).unwrap();
    assert!(
        run_local(&s, &out, &task(0), &|_, _| {}).is_err(),
        "task 0 is running"
    );
    assert!(run_local(&s, &out, &Options::default(), &|_, _| {}).is_err());
    drop(t0);
    run_local(&s, &out, &Options::default(), &|_, _| {}).unwrap();
}

#[test]
fn sweep_files_refuse_aliased_keys_unbounded_ranges_and_tasks_past_the_count() {
    for (body, at, says) in [
        (
            "[grid]\n\"body[0].mass\" = [1.0]\n\"body[00].mass\" = [2.0]\n",
            "grid.body[0].mass",
            "body[00].mass",
        ),
        (
            "set = { \"body[0].mass\" = 1.0 }\n[grid]\n\"body[0].mass\" = [2.0]\n",
            "grid.body[0].mass",
            "set",
        ),
        (
            "[random]\nruns = 2\nseed = 1\n[random.parameters]\n\
             \"body[0].mass\" = { uniform = [-1e308, 1e308] }\n",
            "random.parameters.body[0].mass",
            "finite",
        ),
    ] {
        let e = sweep(body).unwrap_err();
        let SweepError::File(SceneError::Invalid(d)) = &e else {
            panic!("{body}: {e}")
        };
        assert_eq!(d.key.to_string(), at, "{e}");
        assert!(d.message.contains(says), "{e}");
    }
    // A duplicate key is located on its line.
    let e = sweep("[grid]\n\"body[0].mass\" = [1.0]\n\"body[0].mass\" = [2.0]\n").unwrap_err();
    let SweepError::File(SceneError::Invalid(d)) = &e else {
        panic!("{e}")
    };
    assert_eq!(d.line, 4, "{e}");

    let dir = tempfile::tempdir().unwrap();
    let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0]\n").unwrap();
    for (task, workers) in [
        (Some((2, 2)), Some(1)),
        (Some((2, 1)), Some(1)),
        (None, Some(0)),
    ] {
        let options = Options {
            workers,
            task,
            stop: None,
        };
        let e = run_local(&s, dir.path(), &options, &|_, _| {}).unwrap_err();
        assert!(e.is_bad_input(), "{e}");
    }
    let zero = Options {
        workers: Some(1),
        task: Some((0, 0)),
        stop: None,
    };
    assert!(
        run_local(&s, dir.path(), &zero, &|_, _| {})
            .unwrap_err()
            .is_bad_input()
    );
}

#[test]
fn a_stopped_sweep_records_only_the_runs_it_finished_and_a_rerun_takes_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let s = sweep("format = \"none\"\n[grid]\n\"body[0].mass\" = [1.0, 2.0, 3.0, 4.0]\n").unwrap();
    let stop = std::sync::atomic::AtomicBool::new(false);
    let options = Options {
        workers: Some(1),
        task: None,
        stop: Some(&stop),
    };
    let o = run_local(&s, dir.path(), &options, &|done, _| {
        if done == 1 {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    })
    .unwrap();
    assert_eq!(
        (o.ok, o.stopped),
        (1, 0),
        "one worker: the stop falls between runs"
    );
    assert_eq!(read_manifest(&s, dir.path()).unwrap().len(), 1);
    let rest = run_local(&s, dir.path(), &Options::default(), &|_, _| {}).unwrap();
    assert_eq!((rest.skipped, rest.ok), (1, 3));
}
