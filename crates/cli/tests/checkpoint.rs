//! `softbody run --checkpoint-every N` and `--resume`: a run killed outright (SIGKILL) and
//! resumed writes the bytes an uninterrupted run writes; what cannot be resumed is refused with
//! status 2 and left alone.

#![cfg(unix)]

mod common;

use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{EXIT_BAD_INPUT, EXIT_OK, Sandbox, entries};

/// A 4×4×4 jelly cube dropped onto a 20° slope with Coulomb friction μ = 0.8, where it sticks:
/// implicit Euler carries its warm start and who touches and sticks from step to step, the
/// history a checkpoint must hold. 360 steps, 121 frames.
const STICKY_SLOPE: &str = r#"
[simulation]
integrator = "implicit-euler"
dt = 0.005
duration = 1.8
frame_rate = 66.66666666666667

[[body]]
kind = "cuboid"
size = [0.4, 0.4, 0.4]
resolution = [4, 4, 4]
center = [0.0, 0.35, 0.0]
rotation = [0.0, 0.0, -20.0]
mass = 1.0
structural = { stiffness = 2000.0, damping = 2.0 }
shear = { stiffness = 2000.0, damping = 2.0 }
bending = { stiffness = 500.0, damping = 1.0 }

[[terrain]]
kind = "plane"
normal = [0.3420201433256687, 0.9396926207859084, 0.0]
friction = 0.8
friction_model = "coulomb"
"#;

/// Two cubes thrown at each other, meeting at about 0.15 s (frame 4): contact between bodies
/// (symplectic Euler).
const HEAD_ON: &str = r#"
[simulation]
integrator = "symplectic-euler"
dt = 0.0002
duration = 1.0
gravity = [0.0, 0.0, 0.0]
body_restitution = 0.5
body_friction = 0.3

[[body]]
kind = "cuboid"
name = "left"
size = [0.3, 0.3, 0.3]
resolution = [4, 4, 4]
center = [-0.3, 0.0, 0.0]
velocity = [1.0, 0.0, 0.0]
mass = 1.0
structural = { stiffness = 3000.0, damping = 1.0 }
shear = { stiffness = 3000.0, damping = 1.0 }

[[body]]
kind = "cuboid"
name = "right"
size = [0.3, 0.3, 0.3]
resolution = [4, 4, 4]
center = [0.3, 0.05, 0.0]
velocity = [-1.0, 0.0, 0.0]
mass = 1.0
structural = { stiffness = 3000.0, damping = 1.0 }
shear = { stiffness = 3000.0, damping = 1.0 }
"#;

/// Frames the checkpoint of `out` counts (the word after the magic, fingerprint and interval of
/// its `checkpoint` file), 0 while there is none.
fn checkpointed_frames(sb: &Sandbox, out: &str) -> u64 {
    let path = sb.path().join(format!("{out}.checkpoint/checkpoint"));
    std::fs::read(path)
        .ok()
        .filter(|b| b.len() >= 32 && b.starts_with(b"SBCKPT"))
        .map_or(0, |b| u64::from_le_bytes(b[24..32].try_into().unwrap()))
}

/// The CRC-32 (IEEE, reflected, as zlib's) of `bytes`, bit by bit: the checksum of a journal
/// record and of a `checkpoint` file, computed apart from the library's.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A `checkpoint` file's bytes, edited in place, with their closing checksum made to match.
fn reseal(bytes: &mut [u8]) {
    let end = bytes.len() - 4;
    let sum = crc32(&bytes[..end]);
    bytes[end..].copy_from_slice(&sum.to_le_bytes());
}

/// Starts `softbody run ARGS` in `sb`.
// The child is returned, and its callers wait for it.
#[allow(clippy::zombie_processes)]
fn spawn(sb: &Sandbox, args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_softbody"))
        .args(args)
        .current_dir(sb.path())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits until `child`'s checkpoint of `out` counts at least `frames` frames.
fn wait_for_checkpoint(sb: &Sandbox, child: &mut Child, out: &str, frames: u64) {
    let started = Instant::now();
    while checkpointed_frames(sb, out) < frames {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the run ended ({status}) before its checkpoint counted {frames} frames");
        }
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "no checkpoint of {frames} frames after two minutes"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Every file under `dir` (recursively, hidden ones included) with its bytes, by path.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut all = Vec::new();
    for name in entries(dir) {
        let path = dir.join(&name);
        if path.is_dir() {
            all.extend(
                files(&path)
                    .into_iter()
                    .map(|(inner, bytes)| (format!("{name}/{inner}"), bytes)),
            );
        } else {
            all.push((name, std::fs::read(path).unwrap()));
        }
    }
    all
}

/// Removes everything in the sandbox but the scene.
fn clear(sb: &Sandbox) {
    for name in entries(sb.path()).into_iter().filter(|n| n != "scene.toml") {
        let path = sb.path().join(name);
        std::fs::remove_file(&path)
            .or_else(|_| std::fs::remove_dir_all(&path))
            .unwrap();
    }
}

/// Runs `scene` to `out` uninterrupted; then again with checkpoints every 2 frames, killed with
/// SIGKILL once 6 frames are checkpointed, and resumed: the outputs are the same bytes, and the
/// resumed run leaves neither its checkpoint nor the killed run's staging behind: the
/// directory holds exactly what the uninterrupted run left, byte for byte.
fn killed_and_resumed(scene: &str, out: &str, extra: &[&str]) {
    let sb = Sandbox::new();
    sb.write("scene.toml", scene);
    let args = |more: &[&'static str]| {
        let mut args = vec![
            "run",
            "scene.toml",
            "--out",
            out,
            "--threads",
            "2",
            "--quiet",
        ];
        args.extend(extra);
        args.extend(more);
        args
    };
    sb.run(&args(&[])).expect_status(EXIT_OK);
    let uninterrupted = files(sb.path());
    clear(&sb);

    let mut child = spawn(&sb, &args(&["--checkpoint-every", "2"]));
    wait_for_checkpoint(&sb, &mut child, out, 6);
    child.kill().unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.signal(), Some(9), "killed, not finished: {status}");
    assert!(
        !sb.path().join(out).exists(),
        "the killed run committed nothing"
    );

    let resumed = sb.run(&args(&["--resume"]));
    resumed.expect_status(EXIT_OK);
    let after = files(sb.path());
    let names =
        |files: &[(String, Vec<u8>)]| files.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names(&after), names(&uninterrupted), "what is left differs");
    for ((name, a), (_, b)) in uninterrupted.iter().zip(&after) {
        assert!(
            a == b,
            "the resumed run's {name} differs from the uninterrupted run's"
        );
    }
}

#[test]
fn an_implicit_run_with_sticking_contact_resumes_byte_for_byte() {
    killed_and_resumed(STICKY_SLOPE, "f.jsonl", &[]);
}

/// NPZ, written whole at the end, resumes from the journal like a stream.
#[test]
fn a_run_of_bodies_in_contact_resumes_byte_for_byte_into_npz() {
    killed_and_resumed(HEAD_ON, "f.npz", &[]);
}

/// A series (a file per frame and the `.pvd` naming them).
#[test]
fn a_vtk_series_resumes_byte_for_byte() {
    killed_and_resumed(
        STICKY_SLOPE,
        "f.pvd",
        &["--integrator", "symplectic-euler", "--dt", "1e-4"],
    );
}

/// A run stopped by Ctrl-C keeps its frames and its checkpoint (it says so), and goes on from
/// it; a completed run leaves no checkpoint.
#[test]
fn a_run_stopped_by_a_signal_keeps_its_checkpoint() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    let args = [
        "run",
        "scene.toml",
        "--out",
        "f.jsonl",
        "--quiet",
        "--checkpoint-every",
        "3",
    ];
    sb.run(&args).expect_status(EXIT_OK);
    let uninterrupted = std::fs::read(sb.path().join("f.jsonl")).unwrap();
    assert_eq!(
        entries(sb.path()),
        ["f.jsonl", "scene.toml"],
        "no checkpoint after a complete run"
    );

    let mut child = spawn(&sb, &args);
    wait_for_checkpoint(&sb, &mut child, "f.jsonl", 3);
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    assert!(
        stderr.contains("f.jsonl.checkpoint: go on with --resume"),
        "{stderr}"
    );
    assert!(checkpointed_frames(&sb, "f.jsonl") >= 3);

    let mut resume = args.to_vec();
    resume.push("--resume");
    let o = sb.run(&resume);
    o.expect_status(EXIT_OK);
    assert_eq!(
        std::fs::read(sb.path().join("f.jsonl")).unwrap(),
        uninterrupted
    );
    assert_eq!(entries(sb.path()), ["f.jsonl", "scene.toml"]);
}

/// A checkpoint of another run (here another dt) is refused with status 2 and left as it was,
/// so is a damaged one and one whose history the solver does not take; `--resume` without a
/// checkpoint starts from the beginning; standard output cannot be checkpointed.
#[test]
fn what_cannot_be_resumed_is_refused_and_left_alone() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    let run = |more: &[&str]| {
        let mut args = vec!["run", "scene.toml", "--out", "f.jsonl"];
        args.extend(more);
        sb.run(&args)
    };
    let o = run(&["--resume", "--checkpoint-every", "4", "--duration", "0.1"]);
    o.expect_status(EXIT_OK);
    assert!(
        o.stderr
            .contains("no checkpoint in f.jsonl.checkpoint: starting from the beginning"),
        "{}",
        o.stderr
    );

    // The checkpoint of a run killed after two frames.
    let mut child = spawn(
        &sb,
        &[
            "run",
            "scene.toml",
            "--out",
            "f.jsonl",
            "--checkpoint-every",
            "2",
        ],
    );
    wait_for_checkpoint(&sb, &mut child, "f.jsonl", 2);
    child.kill().unwrap();
    child.wait().unwrap();
    let checkpoint = sb.path().join("f.jsonl.checkpoint/checkpoint");
    let saved = std::fs::read(&checkpoint).unwrap();

    let o = run(&["--resume", "--dt", "0.004"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr
            .contains("f.jsonl.checkpoint: the checkpoint is of another run"),
        "{}",
        o.stderr
    );
    assert_eq!(std::fs::read(&checkpoint).unwrap(), saved, "left as it was");

    // A history this version's solver does not take (a part it needs, renamed): a checkpoint
    // of another version, not a failing solver.
    let at = (saved.windows(8).position(|w| w == b"sticking")).expect("implicit Euler's part");
    let mut renamed = saved.clone();
    renamed[at..at + 8].copy_from_slice(b"stickinG");
    reseal(&mut renamed);
    std::fs::write(&checkpoint, &renamed).unwrap();
    let o = run(&["--resume"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr.contains(
            "checkpoint: not a checkpoint of this version of softbody (restore: the history \
             has no part `sticking`)"
        ),
        "{}",
        o.stderr
    );
    assert_eq!(
        std::fs::read(&checkpoint).unwrap(),
        renamed,
        "left as it was"
    );

    std::fs::write(&checkpoint, b"SBCKPT02 cut short").unwrap();
    let o = run(&["--resume"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr
            .contains("checkpoint: the checkpoint is damaged (it does not match its checksum)"),
        "{}",
        o.stderr
    );

    let o = sb.run(&["run", "scene.toml", "--out", "-", "--checkpoint-every", "2"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr.contains("need an output file (--out)"),
        "{}",
        o.stderr
    );
    assert!(o.stdout.is_empty());
}

/// STICKY_SLOPE to `f.jsonl`, checkpointed every 2 frames and killed once its checkpoint counts
/// `frames` frames.
fn killed_checkpoint(sb: &Sandbox, frames: u64) {
    let args = [
        "run",
        "scene.toml",
        "--out",
        "f.jsonl",
        "--checkpoint-every",
        "2",
    ];
    let mut child = spawn(sb, &args);
    wait_for_checkpoint(sb, &mut child, "f.jsonl", frames);
    child.kill().unwrap();
    child.wait().unwrap();
}

/// `softbody run scene.toml --out f.jsonl ARGS` in `sb`.
fn run_to_f(sb: &Sandbox, more: &[&str]) -> common::Outcome {
    let mut args = vec!["run", "scene.toml", "--out", "f.jsonl"];
    args.extend(more);
    sb.run(&args)
}

/// Bytes of a journal record of STICKY_SLOPE's 64 particles: frame number, step, time and the
/// three energies (48 bytes), each particle's position and velocity (48 bytes), and the
/// record's CRC-32 (4 bytes).
const RECORD: usize = 48 + 48 * 64 + 4;

/// A bit flipped in a frame the checkpoint counts, or in the checkpoint itself, is refused with
/// status 2, naming the file (and the frame), and nothing is touched or written; so is a
/// checkpoint of the format's first version, which had no checksums.
#[test]
fn a_flipped_bit_in_a_checkpoint_is_refused_and_left_alone() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    killed_checkpoint(&sb, 4);
    let dir = sb.path().join("f.jsonl.checkpoint");
    let (journal, checkpoint) = (dir.join("frames"), dir.join("checkpoint"));
    let (frames, saved) = (
        std::fs::read(&journal).unwrap(),
        std::fs::read(&checkpoint).unwrap(),
    );
    let refused = |what: &str| {
        let damaged = files(&dir);
        let o = run_to_f(&sb, &["--resume"]);
        o.expect_status(EXIT_BAD_INPUT);
        assert!(o.stderr.contains(what), "{}", o.stderr);
        assert_eq!(files(&dir), damaged, "left as it was");
        assert!(!sb.path().join("f.jsonl").exists(), "nothing written");
    };

    let record = &frames[RECORD..2 * RECORD];
    assert_eq!(
        record[RECORD - 4..],
        crc32(&record[..RECORD - 4]).to_le_bytes(),
        "a record ends in the CRC-32 of its bytes"
    );
    assert_eq!(
        saved[saved.len() - 4..],
        crc32(&saved[..saved.len() - 4]).to_le_bytes(),
        "so does the checkpoint"
    );
    // The lowest bit of frame 1's first coordinate: one ulp, which nothing else would notice.
    let mut flipped = frames.clone();
    flipped[RECORD + 48] ^= 1;
    std::fs::write(&journal, &flipped).unwrap();
    refused(
        "f.jsonl.checkpoint/frames: the checkpoint is damaged (frame 1 does not match its checksum)",
    );
    std::fs::write(&journal, &frames).unwrap();

    // The interval between checkpoints, 2, made 3.
    let mut flipped = saved.clone();
    flipped[16] ^= 1;
    std::fs::write(&checkpoint, &flipped).unwrap();
    refused(
        "f.jsonl.checkpoint/checkpoint: the checkpoint is damaged (it does not match its checksum)",
    );

    let mut old = saved.clone();
    old[..8].copy_from_slice(b"SBCKPT01");
    std::fs::write(&checkpoint, &old).unwrap();
    refused(
        "f.jsonl.checkpoint/checkpoint: not a checkpoint of this version of softbody (it is of \
         version 1 of the format, and this version reads version 2)",
    );

    std::fs::write(&checkpoint, &saved).unwrap();
    run_to_f(&sb, &["--resume", "--quiet"]).expect_status(EXIT_OK);
}

/// A checkpointing run (or a resume) aimed at the output of one still running is refused at
/// once with status 1, naming the process that holds it, and the running one's checkpoint goes
/// on: the second does not replace it.
#[test]
fn a_second_run_to_a_checkpointed_output_is_refused() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    let long = ["--checkpoint-every", "2", "--duration", "60"];
    let mut args = vec!["run", "scene.toml", "--out", "f.jsonl"];
    args.extend(long);
    let mut first = spawn(&sb, &args);
    wait_for_checkpoint(&sb, &mut first, "f.jsonl", 2);
    let busy = format!(
        "error: f.jsonl is being written by another softbody process (process {}) (it holds \
         f.jsonl.lock); wait for it to end, or write elsewhere",
        first.id()
    );
    for more in [&[][..], &["--resume"]] {
        let o = run_to_f(&sb, &[&long[..], more].concat());
        o.expect_status(common::EXIT_OUTPUT);
        assert!(o.stderr.contains(&busy), "{}", o.stderr);
    }
    let counted = checkpointed_frames(&sb, "f.jsonl");
    wait_for_checkpoint(&sb, &mut first, "f.jsonl", counted + 4);
    first.kill().unwrap();
    first.wait().unwrap();
}

/// A run whose output cannot be put in place when it ends (its destination became a
/// directory) fails with status 1 and says that its checkpoint is kept and that `--resume`
/// goes on from it, which it does.
#[test]
fn a_run_whose_output_fails_says_its_checkpoint_is_kept() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    let args = [
        "run",
        "scene.toml",
        "--out",
        "f.jsonl",
        "--checkpoint-every",
        "2",
        "--duration",
        "4",
        "--quiet",
    ];
    let mut child = spawn(&sb, &args);
    wait_for_checkpoint(&sb, &mut child, "f.jsonl", 2);
    std::fs::create_dir(sb.path().join("f.jsonl")).unwrap();
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(common::EXIT_OUTPUT), "{stderr}");
    assert!(
        stderr.contains("cannot write f.jsonl: it is a directory"),
        "{stderr}"
    );
    assert!(
        stderr.contains("the checkpoint is in f.jsonl.checkpoint: go on with --resume"),
        "{stderr}"
    );
    assert!(checkpointed_frames(&sb, "f.jsonl") >= 2);

    std::fs::remove_dir(sb.path().join("f.jsonl")).unwrap();
    let o = run_to_f(&sb, &["--duration", "4", "--resume"]);
    o.expect_status(EXIT_OK);
    assert!(o.stderr.contains("resuming after frame"), "{}", o.stderr);
    assert_eq!(entries(sb.path()), ["f.jsonl", "scene.toml"]);
}

/// A directory named `<out>.checkpoint` that is not a checkpoint (it holds a file of the
/// user's) is refused with status 1 and left as it is, and nothing is written; one holding only
/// a checkpoint's files is replaced.
#[test]
fn a_directory_that_is_not_a_checkpoint_is_refused_and_left_alone() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    sb.write("f.jsonl.checkpoint/notes.txt", "mine");
    for more in [&[][..], &["--resume"]] {
        let o = run_to_f(&sb, &[&["--checkpoint-every", "2"][..], more].concat());
        o.expect_status(common::EXIT_OUTPUT);
        assert!(
            o.stderr.contains(
                "refusing to use f.jsonl.checkpoint as a checkpoint: it holds \
                 f.jsonl.checkpoint/notes.txt, which is not one of a checkpoint's files; choose \
                 another --out or remove it"
            ),
            "{}",
            o.stderr
        );
        assert_eq!(entries(sb.path()), ["f.jsonl.checkpoint", "scene.toml"]);
        assert_eq!(
            files(&sb.path().join("f.jsonl.checkpoint")),
            [("notes.txt".to_owned(), b"mine".to_vec())]
        );
    }

    std::fs::remove_file(sb.path().join("f.jsonl.checkpoint/notes.txt")).unwrap();
    sb.write("f.jsonl.checkpoint/frames", "an earlier journal");
    run_to_f(&sb, &["--checkpoint-every", "2", "--duration", "0.1"]).expect_status(EXIT_OK);
    assert_eq!(entries(sb.path()), ["f.jsonl", "scene.toml"]);
}

/// Checkpoints go beside a regular file: a device or a FIFO as the output is refused with
/// status 2 before anything is written (no `/dev/null.checkpoint`), and a FIFO is not opened.
#[test]
fn checkpoints_need_a_regular_file() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    let made = Command::new("mkfifo")
        .arg(sb.path().join("pipe"))
        .status()
        .unwrap();
    assert!(made.success());
    for (out, what) in [("/dev/null", "a character device"), ("pipe", "a FIFO")] {
        let o = sb.run(&["run", "scene.toml", "--out", out, "--checkpoint-every", "2"]);
        o.expect_status(EXIT_BAD_INPUT);
        let expected = format!(
            "cannot checkpoint a run to {out}: it is {what}, not a regular file (the checkpoint \
             goes beside the output, in {out}.checkpoint)"
        );
        assert!(o.stderr.contains(&expected), "{}", o.stderr);
    }
    for made in ["/dev/null.checkpoint", "/dev/null.lock"] {
        assert!(!Path::new(made).exists(), "{made}");
    }
    assert_eq!(entries(sb.path()), ["pipe", "scene.toml"]);
}

/// A checkpoint that cannot be read (a directory where its file goes) fails with status 1,
/// naming it and saying why once.
#[test]
fn a_checkpoint_that_cannot_be_read_says_why_once() {
    let sb = Sandbox::new();
    sb.write("scene.toml", STICKY_SLOPE);
    sb.mkdir("f.jsonl.checkpoint/checkpoint");
    let o = run_to_f(&sb, &["--resume"]);
    o.expect_status(common::EXIT_OUTPUT);
    assert!(
        o.stderr
            .starts_with("error: cannot read f.jsonl.checkpoint/checkpoint: Is a directory"),
        "{}",
        o.stderr
    );
    assert_eq!(o.stderr.matches("(os error 21)").count(), 1, "{}", o.stderr);
}
