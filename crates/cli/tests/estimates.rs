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

/// `check --json`'s estimates from the counts: the lean solver's 44 B of model and 48 B per
/// state (two for symplectic Euler, four for RK4) plus a quarter for a cuboid, 128 B a particle
/// a frame of JSON Lines, and 8 M (symplectic Euler) or 2 M (RK4) particle-steps a second.
#[test]
fn check_estimates_the_memory_output_and_time_of_the_run() {
    let sb = Sandbox::new();
    let cube = Cube::default();
    sb.write("cube.toml", &cube.toml());
    let n = cube.particles() as u64;
    let frames = frame_schedule(cube.dt, cube.duration, cube.frame_rate).len() as u64;
    let steps = planned_steps(cube.dt, cube.duration) as f64;
    for (integrator, states, rate) in [("symplectic-euler", 2, 8e6), ("rk4", 4, 2e6)] {
        let o = sb.run(&["check", "cube.toml", "--json", "--integrator", integrator]);
        o.expect_status(EXIT_OK);
        let v: serde_json::Value = serde_json::from_str(&o.stdout_text()).unwrap();
        let e = &v["estimates"];
        let lean = 44 + 48 * states;
        assert_eq!(
            e["memory_bytes"].as_u64(),
            Some(n * (lean + lean / 4)),
            "{e}"
        );
        assert_eq!(e["output_bytes"].as_u64(), Some(frames * n * 128), "{e}");
        assert_eq!(f64_of(&e["seconds"]), steps * n as f64 / rate, "{e}");
        assert!(f64_of(&e["memory_available_bytes"]) > 0.0, "{e}");
    }
    let o = sb.run(&["check", "cube.toml"]);
    let text = o.stdout_text();
    for says in [
        "  memory      about 4.6 KiB for the CPU solver (",
        "  output      about 20.2 KiB as JSON Lines (6 frames of 27 particles, 128 B each)",
        "  run time    about 0.00 s of stepping on two CPU cores (an estimate at 8.0e6",
    ] {
        assert!(text.contains(says), "{says:?} in\n{text}");
    }
}

/// Peak resident memory of the finished children of this process, bytes.
fn children_peak_rss() -> u64 {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given.
    let usage = unsafe {
        assert_eq!(
            libc::getrusage(libc::RUSAGE_CHILDREN, usage.as_mut_ptr()),
            0
        );
        usage.assume_init()
    };
    // Linux reports kilobytes.
    usage.ru_maxrss as u64 * 1024
}

/// `check` of a cuboid too large to build cheaply (150³, 3.4 M particles, 53 M springs)
/// answers from its counts and a piece of its lattice: its peak memory stays below the state
/// alone (positions and velocities, 48 B a particle) that a model of the scene would hold, and
/// what it says is the whole cuboid's: the guaranteed step of its stiffest particle (an
/// interior one, 32 springs) and the particles that start in the ground.
#[test]
fn check_of_a_large_cuboid_does_not_build_it() {
    let sb = Sandbox::new();
    let side = 150u64;
    let cube = Cube {
        resolution: [side as u32; 3],
        // 1 cm apart; the lowest five layers, -4.5 cm to -0.5 cm, are in the ground.
        size: 0.01 * (side - 1) as f64,
        center: [0.0, 0.7, 0.0],
        ..Cube::default()
    };
    sb.write("large.toml", &cube.toml());
    let o = sb.run(&["check", "large.toml", "--json"]);
    o.expect_status(EXIT_OK);
    let n = side.pow(3);
    let peak = children_peak_rss();
    assert!(peak < 48 * n, "peak {peak} B for {n} particles");

    let v: serde_json::Value = serde_json::from_str(&o.stdout_text()).unwrap();
    assert_eq!(v["particles"].as_u64(), Some(n));
    let m = cube.mass / n as f64;
    let lambda = 2.0 * 32.0 * cube.stiffness / m;
    let c = 2.0 * 32.0 * cube.damping / m;
    let bound = (-c + (c * c + 4.0 * lambda).sqrt()) / lambda;
    let stable = f64_of(&v["stable_dt"]);
    assert!(
        (stable - bound).abs() <= 1e-12 * bound,
        "{stable} vs {bound}"
    );
    let warnings: Vec<&str> = v["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_str().unwrap())
        .collect();
    let inside = 5 * side * side;
    assert!(
        warnings[0].starts_with(&format!(
            "body `cube` starts with {inside} of its {n} particles inside terrain[0] (up to \
             4.500e-2 m deep)"
        )),
        "{warnings:?}"
    );
    assert!(
        warnings[1].starts_with("dt = 0.001 s is above"),
        "{warnings:?}"
    );
}
