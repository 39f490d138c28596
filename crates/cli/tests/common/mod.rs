//! Helpers shared by the CLI integration tests: a sandbox directory, running the `softbody`
//! binary, small scene texts, reading JSON Lines, and the frame schedule computed from the
//! contract (independently of the library).

#![allow(dead_code, reason = "each test crate uses a different subset")]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use serde_json::Value;

/// Exit statuses of the contract.
pub const EXIT_OK: i32 = 0;
pub const EXIT_OUTPUT: i32 = 1;
pub const EXIT_BAD_INPUT: i32 = 2;
pub const EXIT_UNSTABLE: i32 = 3;

/// A temporary working directory for one test.
pub struct Sandbox {
    dir: tempfile::TempDir,
}

impl Sandbox {
    pub fn new() -> Self {
        Sandbox {
            dir: tempfile::tempdir().expect("temporary directory"),
        }
    }

    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Writes `text` to `name` inside the sandbox and returns its absolute path.
    pub fn write(&self, name: &str, text: &str) -> PathBuf {
        let path = self.path().join(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        std::fs::write(&path, text).unwrap();
        path
    }

    /// Creates (empty) and returns the directory `name` inside the sandbox.
    pub fn mkdir(&self, name: &str) -> PathBuf {
        let path = self.path().join(name);
        std::fs::create_dir_all(&path).unwrap();
        path
    }

    /// Runs `softbody ARGS` with the sandbox as working directory.
    pub fn run<S: AsRef<std::ffi::OsStr>>(&self, args: &[S]) -> Outcome {
        softbody(self.path(), args)
    }
}

/// What a run of the binary did.
#[derive(Debug)]
pub struct Outcome {
    pub status: i32,
    pub stdout: Vec<u8>,
    pub stderr: String,
}

impl Outcome {
    pub fn stdout_text(&self) -> String {
        String::from_utf8(self.stdout.clone()).expect("stdout is UTF-8")
    }

    /// Panics with the whole outcome unless the exit status is `status`.
    #[track_caller]
    pub fn expect_status(&self, status: i32) -> &Self {
        assert_eq!(
            self.status,
            status,
            "expected exit status {status}, got {}\n--- stderr ---\n{}\n--- stdout (first 2000 bytes) ---\n{}",
            self.status,
            self.stderr,
            String::from_utf8_lossy(&self.stdout[..self.stdout.len().min(2000)])
        );
        self
    }
}

/// Runs the `softbody` binary in `cwd`; stdin is empty, stdout and stderr are pipes (so not
/// terminals).
pub fn softbody<S: AsRef<std::ffi::OsStr>>(cwd: &Path, args: &[S]) -> Outcome {
    let out = Command::new(env!("CARGO_BIN_EXE_softbody"))
        .args(args)
        .current_dir(cwd)
        .stdin(Stdio::null())
        .env_remove("RAYON_NUM_THREADS")
        .output()
        .expect("the softbody binary starts");
    Outcome {
        status: out.status.code().expect("exited, not killed by a signal"),
        stdout: out.stdout,
        stderr: String::from_utf8(out.stderr).expect("stderr is UTF-8"),
    }
}

/// Names of the entries of `dir` (empty when it does not exist), sorted.
pub fn entries(dir: &Path) -> Vec<String> {
    let Ok(read) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut names: Vec<String> = read
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// A cuboid scene (one body, optionally a ground plane), written as TOML by hand so the tests
/// do not depend on the library's idea of the format.
#[derive(Debug, Clone)]
pub struct Cube {
    pub integrator: &'static str,
    pub dt: f64,
    pub duration: f64,
    pub frame_rate: f64,
    pub resolution: [u32; 3],
    pub size: f64,
    pub center: [f64; 3],
    pub velocity: [f64; 3],
    pub mass: f64,
    pub stiffness: f64,
    pub damping: f64,
    pub bending: bool,
    pub ground: bool,
}

impl Default for Cube {
    fn default() -> Self {
        Cube {
            integrator: "symplectic-euler",
            dt: 0.001,
            duration: 0.05,
            frame_rate: 100.0,
            resolution: [3, 3, 3],
            size: 1.0,
            center: [0.0, 1.0, 0.0],
            velocity: [0.5, 0.0, -0.25],
            mass: 1.0,
            stiffness: 200.0,
            damping: 0.5,
            bending: true,
            ground: true,
        }
    }
}

/// `[a, b, c]` with every number written so TOML reads it as a float.
pub fn vec3(v: [f64; 3]) -> String {
    format!("[{:?}, {:?}, {:?}]", v[0], v[1], v[2])
}

impl Cube {
    pub fn toml(&self) -> String {
        let [nx, ny, nz] = self.resolution;
        let spring = format!(
            "{{ stiffness = {:?}, damping = {:?} }}",
            self.stiffness, self.damping
        );
        let mut t = format!(
            "[simulation]\n\
             integrator = \"{}\"\n\
             dt = {:?}\n\
             duration = {:?}\n\
             frame_rate = {:?}\n\
             \n\
             [[body]]\n\
             name = \"cube\"\n\
             kind = \"cuboid\"\n\
             size = {}\n\
             resolution = [{nx}, {ny}, {nz}]\n\
             center = {}\n\
             velocity = {}\n\
             mass = {:?}\n\
             structural = {spring}\n\
             shear = {spring}\n",
            self.integrator,
            self.dt,
            self.duration,
            self.frame_rate,
            vec3([self.size; 3]),
            vec3(self.center),
            vec3(self.velocity),
            self.mass,
        );
        if self.bending {
            t += &format!("bending = {spring}\n");
        }
        if self.ground {
            t += "\n[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nfriction = 0.5\n";
        }
        t
    }

    pub fn particles(&self) -> usize {
        self.resolution.iter().map(|&r| r as usize).product()
    }

    /// The stiff cube of the contract that explicit Euler cannot hold at dt = 0.01.
    pub fn unstable() -> Cube {
        Cube {
            integrator: "explicit-euler",
            dt: 0.01,
            duration: 2.0,
            frame_rate: 50.0,
            resolution: [4, 4, 4],
            velocity: [0.0; 3],
            mass: 1.0,
            stiffness: 2000.0,
            damping: 0.0,
            ..Cube::default()
        }
    }
}

/// steps = round(duration / dt).
pub fn planned_steps(dt: f64, duration: f64) -> u64 {
    (duration / dt).round() as u64
}

/// The step of every frame of a complete run: frame k is at step round(k / (frame_rate·dt)),
/// for every k whose step is within the run.
pub fn frame_schedule(dt: f64, duration: f64, frame_rate: f64) -> Vec<u64> {
    let steps = planned_steps(dt, duration);
    (0u64..)
        .map(|k| (k as f64 / (frame_rate * dt)).round() as u64)
        .take_while(|&s| s <= steps)
        .collect()
}

/// A JSON Lines frame file, read strictly: every line (the last one included) ends in `\n`
/// and is one JSON object.
#[derive(Debug)]
pub struct Frames {
    pub header: Value,
    pub frames: Vec<Value>,
    /// The frame lines as written, without their `\n`.
    pub frame_lines: Vec<String>,
}

#[track_caller]
pub fn parse_jsonl(text: &str) -> Frames {
    assert!(!text.is_empty(), "empty JSON Lines output");
    assert!(
        text.ends_with('\n'),
        "the last line is incomplete: {:?}",
        &text[text.len().saturating_sub(200)..]
    );
    let mut lines = text.lines();
    let header: Value = serde_json::from_str(lines.next().unwrap()).expect("header line is JSON");
    assert!(header.is_object(), "header is an object: {header}");
    let mut frames = Vec::new();
    let mut frame_lines = Vec::new();
    for (i, line) in lines.enumerate() {
        let value: Value = serde_json::from_str(line)
            .unwrap_or_else(|e| panic!("frame line {} is not JSON ({e}): {line:.200}", i + 2));
        assert!(value.is_object(), "frame line {} is an object", i + 2);
        frames.push(value);
        frame_lines.push(line.to_owned());
    }
    Frames {
        header,
        frames,
        frame_lines,
    }
}

#[track_caller]
pub fn read_jsonl(path: &Path) -> Frames {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    parse_jsonl(&text)
}

/// `value` as f64, panicking with context.
#[track_caller]
pub fn f64_of(value: &Value) -> f64 {
    value
        .as_f64()
        .unwrap_or_else(|| panic!("not a number: {value}"))
}

/// An `[[x,y,z], ...]` array as triples.
#[track_caller]
pub fn triples(value: &Value) -> Vec<[f64; 3]> {
    value
        .as_array()
        .unwrap_or_else(|| panic!("not an array: {value:.200}"))
        .iter()
        .map(|p| {
            let p = p.as_array().expect("a triple is an array");
            assert_eq!(p.len(), 3, "a triple has three numbers");
            [f64_of(&p[0]), f64_of(&p[1]), f64_of(&p[2])]
        })
        .collect()
}

/// Checks the shape of one JSON Lines frame with N particles.
#[track_caller]
pub fn assert_frame_shape(frame: &Value, k: usize, n: usize) {
    assert_eq!(frame["frame"].as_u64(), Some(k as u64), "frame number");
    assert!(frame["time"].is_number(), "frame {k} has a time");
    assert_eq!(triples(&frame["positions"]).len(), n, "frame {k} positions");
    assert_eq!(
        triples(&frame["velocities"]).len(),
        n,
        "frame {k} velocities"
    );
    for key in ["kinetic", "gravitational", "elastic"] {
        assert!(
            frame["energy"][key].is_number(),
            "frame {k} energy.{key}: {}",
            frame["energy"]
        );
    }
}

/// 1-based number of the only line of `text` containing `marker`.
#[track_caller]
pub fn line_of(text: &str, marker: &str) -> usize {
    let hits: Vec<usize> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| l.contains(marker))
        .map(|(i, _)| i + 1)
        .collect();
    assert_eq!(
        hits.len(),
        1,
        "test bug: marker {marker:?} must be on exactly one line of\n{text}"
    );
    hits[0]
}
