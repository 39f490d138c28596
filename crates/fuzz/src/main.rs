//! Hostile inputs for the three readers of untrusted files: the scene parser (and, for the
//! scenes it accepts, the model and a few CPU steps), the OBJ loader (and what it feeds: the
//! terrain query structure, and the voxelisation of a mesh body with its winding numbers, the
//! fast ones of an open mesh), and the JSON Lines reader. Every input must be accepted or refused with
//! an error; a panic is a defect.
//!
//! ```text
//! cargo run --release -p softbody-fuzz -- [SECONDS] [SEED]      # default 30 s, seed 1
//! ```
//!
//! Inputs are mutations of the project's own files (every `scenes/*.toml`, `scenes/terrain.obj`
//! and a run's frames): lines deleted, duplicated, swapped or borrowed from another file, values
//! replaced by hostile ones (0, −1, 1e308, NaN, 2³², empty arrays, …), bytes inserted, the text
//! cut short. It is a stable-toolchain stand-in for cargo-fuzz (which needs nightly): no coverage
//! feedback, but structure-aware mutations reach the validators and the solvers. It prints the
//! executions and panics of each target, writes each panicking input to
//! `target/fuzz-failures/`, and exits with status 1 if there was one. `.ci/run` runs it for a
//! minute; BENCHMARKS.md records a long run.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use softbody::output::jsonl::Reader;
use softbody::output::{self, Format};
use softbody::scene::mesh::load_obj;
use softbody::scene::voxel::{LatticeSize, Voxels};
use softbody::scene::{FrictionModel, Terrain, TerrainShape};
use softbody::terrain::Surface;
use softbody::{Backend, CpuSolver, Model, Scene, Solver};
use softbody_testkit::Rng;

/// Values a mutation puts where a value was: the edges of every numeric range the format has.
const HOSTILE: &[&str] = &[
    "0",
    "-0.0",
    "-1",
    "1",
    "2",
    "0.5",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "1e15",
    "1000000",
    "\"\"",
    "\"x\"",
    "[]",
    "[[]]",
    "[0.0, 0.0]",
    "[1e308, 1e308, 1e308]",
    "{}",
    "true",
    "-",
    "//",
];

/// Scenes that the model is built for and stepped, at most this many particles (bigger ones are
/// parsed and validated only, which is what decides them).
const STEP_PARTICLES: u64 = 400;

fn main() -> ExitCode {
    let numbers: Vec<u64> = match std::env::args().skip(1).map(|a| a.parse()).collect() {
        Ok(numbers) => numbers,
        Err(_) => {
            eprintln!("usage: softbody-fuzz [SECONDS] [SEED] (whole numbers)");
            return ExitCode::from(2);
        }
    };
    let seconds = numbers.first().copied().unwrap_or(30);
    let seed = numbers.get(1).copied().unwrap_or(1);
    // The workspace's root, whose scenes/ and target/ the inputs and failures are.
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."));
    let corpus = Corpus::load(root);

    // Panics are counted, not printed as they happen.
    let last_panic = Arc::new(Mutex::new(String::new()));
    let record = Arc::clone(&last_panic);
    std::panic::set_hook(Box::new(move |info| {
        *record.lock().unwrap_or_else(|e| e.into_inner()) = info.to_string();
    }));

    let scratch = tempfile::tempdir().expect("a scratch directory");
    let mut rng = Rng::new(seed);
    let mut targets = [
        Target::new("scene"),
        Target::new("obj"),
        Target::new("jsonl"),
    ];
    let started = Instant::now();
    let budget = Duration::from_secs(seconds);
    let mut n = 0u64;
    while started.elapsed() < budget {
        let which = (n % 3) as usize;
        n += 1;
        let input = match which {
            0 => mutate(&corpus.scenes, &mut rng),
            1 => mutate(std::slice::from_ref(&corpus.obj), &mut rng),
            _ => mutate(std::slice::from_ref(&corpus.jsonl), &mut rng),
        };
        let outcome = catch_unwind(AssertUnwindSafe(|| match which {
            0 => scene(&input, &corpus.scene_origin),
            1 => obj(&input, scratch.path()),
            _ => jsonl(&input),
        }));
        let target = &mut targets[which];
        target.executions += 1;
        match outcome {
            Ok(true) => target.accepted += 1,
            Ok(false) => {}
            Err(_) => {
                let message = last_panic.lock().unwrap_or_else(|e| e.into_inner()).clone();
                target.failed(&input, &message, root);
            }
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    let total: u64 = targets.iter().map(|t| t.executions).sum();
    let panics: u64 = targets.iter().map(|t| t.panics).sum();
    println!(
        "fuzz: {total} executions in {elapsed:.1} s ({:.0}/s), seed {seed}",
        total as f64 / elapsed
    );
    for t in &targets {
        println!(
            "  {:<6} {:>10} executions, {:>9} accepted, {} panics",
            t.name, t.executions, t.accepted, t.panics
        );
    }
    if panics > 0 {
        eprintln!("{panics} panics: the inputs are in target/fuzz-failures/");
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}

/// The files the mutations start from.
struct Corpus {
    scenes: Vec<String>,
    /// Where mutated scenes claim to come from: mesh paths resolve beside it.
    scene_origin: PathBuf,
    obj: String,
    jsonl: String,
}

impl Corpus {
    fn load(root: &Path) -> Corpus {
        let dir = root.join("scenes");
        let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
            .expect("scenes/")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
        paths.sort();
        let scenes = paths
            .iter()
            .map(|p| std::fs::read_to_string(p).expect("a scene"))
            .collect();
        // The terrain mesh is long: its first lines (vertices, then faces that name them) keep
        // an execution short.
        let obj = std::fs::read_to_string(dir.join("terrain.obj")).expect("scenes/terrain.obj");
        let obj = small_obj(&obj);
        Corpus {
            scenes,
            scene_origin: dir.join("fuzzed.toml"),
            obj,
            jsonl: frames(&dir.join("jelly-on-ground.toml")),
        }
    }
}

/// A cube's 8 vertices and 12 triangles, then a few lines of `mesh` (its `v`/`f` syntax).
fn small_obj(mesh: &str) -> String {
    let mut text = String::from(
        "# a cube\nmtllib cube.mtl\no cube\n\
         v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
         usemtl grey\n\
         f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 4 8 7\nf 4 7 3\n\
         f 1 5 8\nf 1 8 4\nf 2 3 7\nf 2 7 6\n",
    );
    for line in mesh.lines().take(12) {
        text.push_str(line);
        text.push('\n');
    }
    text
}

/// The JSON Lines frames of a short run of `scene`.
fn frames(scene: &Path) -> String {
    let mut scene = Scene::from_file(scene).expect("a scene of the project");
    scene.simulation.duration = 0.1;
    let mut solver = softbody::open(&scene, Backend::Cpu, Some(1)).expect("a CPU solver");
    let mut bytes = Vec::new();
    {
        let mut sink = output::sink(Format::Jsonl, Box::new(&mut bytes)).expect("a sink");
        softbody::run::run(solver.as_mut(), None, sink.as_mut(), &mut |_, _| {}).expect("the run");
        sink.finish().expect("the frames");
    }
    String::from_utf8(bytes).expect("UTF-8")
}

/// Counts of one target.
struct Target {
    name: &'static str,
    executions: u64,
    accepted: u64,
    panics: u64,
}

impl Target {
    fn new(name: &'static str) -> Target {
        Target {
            name,
            executions: 0,
            accepted: 0,
            panics: 0,
        }
    }

    fn failed(&mut self, input: &str, message: &str, root: &Path) {
        self.panics += 1;
        let dir = root.join("target/fuzz-failures");
        let path = dir.join(format!("{}-{}.txt", self.name, self.panics));
        let _ = std::fs::create_dir_all(&dir);
        let _ = std::fs::write(&path, input);
        eprintln!(
            "panic ({}): {message}\n  input: {}",
            self.name,
            path.display()
        );
    }
}

/// A random index below `n` (> 0).
fn below(rng: &mut Rng, n: usize) -> usize {
    ((rng.unit() * n as f64) as usize).min(n - 1)
}

/// One of `corpus`, changed by one to four mutations.
fn mutate(corpus: &[String], rng: &mut Rng) -> String {
    let base = &corpus[below(rng, corpus.len())];
    let mut lines: Vec<String> = base.lines().map(str::to_owned).collect();
    if lines.is_empty() {
        lines.push(String::new());
    }
    let mut cut = None;
    for _ in 0..1 + below(rng, 4) {
        let at = below(rng, lines.len());
        match below(rng, 9) {
            0 if lines.len() > 1 => {
                lines.remove(at);
            }
            1 => {
                let line = lines[at].clone();
                lines.insert(at, line);
            }
            2 => {
                let other = below(rng, lines.len());
                lines.swap(at, other);
            }
            3 => {
                // A value: what follows `=`, or a number or word in the line.
                let hostile = HOSTILE[below(rng, HOSTILE.len())];
                let line = &lines[at];
                lines[at] = match line.find('=') {
                    Some(eq) if rng.unit() < 0.5 => format!("{}= {hostile}", &line[..eq]),
                    _ => replace_token(line, hostile, rng),
                };
            }
            4 => {
                let hostile = HOSTILE[below(rng, HOSTILE.len())];
                lines[at] = replace_token(&lines[at], hostile, rng);
            }
            5 => {
                let donor = &corpus[below(rng, corpus.len())];
                let donor: Vec<&str> = donor.lines().collect();
                if !donor.is_empty() {
                    lines.insert(at, donor[below(rng, donor.len())].to_owned());
                }
            }
            6 => {
                // A few random printable or control characters inside the line.
                let line = &lines[at];
                let mut chars: Vec<char> = line.chars().collect();
                for _ in 0..1 + below(rng, 3) {
                    let c = char::from(below(rng, 128) as u8);
                    chars.insert(below(rng, chars.len() + 1), c);
                }
                lines[at] = chars.into_iter().collect();
            }
            7 => cut = Some(rng.unit()),
            _ => {
                // A number scaled far out of its range, keeping the format's shape.
                let line = &lines[at];
                let scale = ["e30", "e-30", "e300", "0000"][below(rng, 4)];
                lines[at] = append_to_number(line, scale, rng);
            }
        }
    }
    let mut text = lines.join("\n");
    text.push('\n');
    if let Some(fraction) = cut {
        let mut end = (text.len() as f64 * fraction) as usize;
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        text.truncate(end);
    }
    text
}

/// `line` with one of its tokens (runs of characters that are not separators) replaced.
fn replace_token(line: &str, with: &str, rng: &mut Rng) -> String {
    let tokens = token_spans(line);
    if tokens.is_empty() {
        return format!("{line}{with}");
    }
    let (a, b) = tokens[below(rng, tokens.len())];
    format!("{}{with}{}", &line[..a], &line[b..])
}

/// `line` with `suffix` appended to one of its numeric tokens.
fn append_to_number(line: &str, suffix: &str, rng: &mut Rng) -> String {
    let numbers: Vec<(usize, usize)> = token_spans(line)
        .into_iter()
        .filter(|&(a, b)| line[a..b].parse::<f64>().is_ok())
        .collect();
    if numbers.is_empty() {
        return line.to_owned();
    }
    let (_, b) = numbers[below(rng, numbers.len())];
    format!("{}{suffix}{}", &line[..b], &line[b..])
}

/// Byte spans of the tokens of `line`: runs of letters, digits, `.`, `-`, `+`, `_`.
fn token_spans(line: &str) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut start = None;
    for (i, c) in line.char_indices().chain([(line.len(), ' ')]) {
        let part = c.is_alphanumeric() || matches!(c, '.' | '-' | '+' | '_');
        match (part, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                spans.push((s, i));
                start = None;
            }
            _ => {}
        }
    }
    spans
}

/// Parses a scene; a small accepted one is built, warned about and stepped on the CPU.
/// Whether it was accepted.
fn scene(text: &str, origin: &Path) -> bool {
    let Ok(mut scene) = Scene::from_toml(text, origin) else {
        return false;
    };
    if scene.particle_count() <= STEP_PARTICLES {
        scene.simulation.duration = scene.simulation.duration.min(3.0 * scene.simulation.dt);
        let (model, state) = Model::build(&scene);
        let _ = softbody::warnings::warnings(&model, &state.x);
        if let Ok(mut solver) = CpuSolver::new(model, state, Some(1)) {
            let _ = solver.advance(3);
            let _ = solver.energies();
        }
    }
    true
}

/// Loads an OBJ file holding `text` and, if it loads, builds the terrain surface of it and
/// queries it, and voxelises it as a mesh body (6 cells along its longest side) and embeds
/// its vertices. Whether it was accepted as an OBJ file.
fn obj(text: &str, dir: &Path) -> bool {
    let path = dir.join("fuzzed.obj");
    if std::fs::write(&path, text).is_err() {
        return false;
    }
    let Ok(mesh) = load_obj(&path) else {
        return false;
    };
    if let Ok(voxels) = Voxels::new(mesh.clone(), glam::DVec3::ONE, LatticeSize::Resolution(6)) {
        let _ = (
            voxels.embedding(),
            voxels.enclosed_volume(),
            voxels.lattice_surface(),
        );
    }
    let surface = Surface::new(&Terrain {
        shape: TerrainShape::Mesh(mesh),
        restitution: 0.5,
        friction: 0.5,
        friction_model: FrictionModel::default(),
    });
    for p in [
        glam::DVec3::ZERO,
        glam::DVec3::splat(0.5),
        glam::DVec3::new(3.0, -2.0, 1e3),
    ] {
        let _ = surface.query(p, 0.1);
    }
    true
}

/// Reads JSON Lines frames to the end. Whether every line read.
fn jsonl(text: &str) -> bool {
    let Ok(reader) = Reader::new(text.as_bytes(), Path::new("fuzzed.jsonl")) else {
        return false;
    };
    reader.into_iter().all(|frame| frame.is_ok())
}
