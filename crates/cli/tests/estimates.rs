//! What `run` and `check` say before a run: the step's warning, and `check`'s estimates of the
//! run's memory, output and time.

mod common;

use common::*;

/// `run` warns of a step above the stable estimate before it steps: the warning comes first on
/// standard error, before the instability it announces (and with --quiet too, as warnings
/// are about the results); a run within the estimate says nothing of it.
#[test]
fn run_warns_of_a_step_above_the_stable_estimate_before_it_starts() {
    let sb = Sandbox::new();
    sb.write("unstable.toml", &Cube::unstable().toml());
    let says = "warning: dt = 0.01 s is above the estimated stable step of";
    for quiet in [false, true] {
        let mut args = vec!["run", "unstable.toml", "--out", "f.jsonl"];
        if quiet {
            args.push("-q");
        }
        let o = sb.run(&args);
        o.expect_status(EXIT_UNSTABLE);
        let lines: Vec<&str> = o.stderr.lines().collect();
        assert!(lines[0].starts_with(says), "{}", o.stderr);
        assert!(
            lines[1..].iter().any(|l| l.contains("became unstable")),
            "{}",
            o.stderr
        );
        assert_eq!(lines.iter().filter(|l| l.starts_with(says)).count(), 1);
    }
    // Two steps of it stay finite: the warning, then the summary.
    let o = sb.run(&[
        "run",
        "unstable.toml",
        "--out",
        "g.jsonl",
        "--duration",
        "0.02",
    ]);
    o.expect_status(EXIT_OK);
    let lines: Vec<&str> = o.stderr.lines().collect();
    assert_eq!(lines.len(), 2, "{}", o.stderr);
    assert!(
        lines[0].starts_with(says) && lines[1].contains("g.jsonl"),
        "{}",
        o.stderr
    );

    sb.write("stable.toml", &Cube::default().toml());
    let o = sb.run(&["run", "stable.toml", "--out", "h.jsonl", "-q"]);
    o.expect_status(EXIT_OK);
    assert_eq!(o.stderr, "");
}
