//! CSV and NPZ output: the same numbers as the JSON Lines output of the same run, bit for bit,
//! and valid files after a run stopped by an instability.

mod common;

use std::io::Read;
use std::path::Path;

use common::*;

/// One run's frames in a format-neutral form.
#[derive(Debug, PartialEq)]
struct Table {
    time: Vec<f64>,
    /// [frame][particle]
    positions: Vec<Vec<[f64; 3]>>,
    velocities: Vec<Vec<[f64; 3]>>,
}

impl Table {
    fn from_jsonl(f: &Frames) -> Table {
        Table {
            time: f.frames.iter().map(|fr| f64_of(&fr["time"])).collect(),
            positions: f
                .frames
                .iter()
                .map(|fr| triples(&fr["positions"]))
                .collect(),
            velocities: f
                .frames
                .iter()
                .map(|fr| triples(&fr["velocities"]))
                .collect(),
        }
    }

    /// Every number as its bits, so that the comparison is exact (and -0.0 ≠ 0.0).
    fn bits(&self) -> (Vec<u64>, Vec<u64>, Vec<u64>) {
        let flat = |v: &Vec<Vec<[f64; 3]>>| -> Vec<u64> {
            v.iter().flatten().flatten().map(|x| x.to_bits()).collect()
        };
        (
            self.time.iter().map(|x| x.to_bits()).collect(),
            flat(&self.positions),
            flat(&self.velocities),
        )
    }
}

#[track_caller]
fn assert_same_bits(a: &Table, b: &Table, what: &str) {
    assert_eq!(a.time.len(), b.time.len(), "{what}: frame count");
    let (at, ap, av) = a.bits();
    let (bt, bp, bv) = b.bits();
    assert!(at == bt, "{what}: times differ");
    assert!(ap == bp, "{what}: positions differ");
    assert!(av == bv, "{what}: velocities differ");
}

/// Reads a CSV frame file strictly: the header line, then `frame,time,particle,x,y,z,vx,vy,vz`
/// rows grouped by frame in particle order, every row complete.
#[track_caller]
fn read_csv(path: &Path, particles: usize) -> Table {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.ends_with('\n'), "the last row is complete");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("frame,time,particle,x,y,z,vx,vy,vz"));
    let mut table = Table {
        time: Vec::new(),
        positions: Vec::new(),
        velocities: Vec::new(),
    };
    for (row, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), 9, "row {row}: {line}");
        let (k, i) = (row / particles, row % particles);
        assert_eq!(cells[0].parse::<usize>().unwrap(), k, "row {row}: frame");
        assert_eq!(cells[2].parse::<usize>().unwrap(), i, "row {row}: particle");
        let num = |c: usize| -> f64 {
            cells[c]
                .parse()
                .unwrap_or_else(|e| panic!("row {row} cell {c} {:?}: {e}", cells[c]))
        };
        if i == 0 {
            table.time.push(num(1));
            table.positions.push(Vec::new());
            table.velocities.push(Vec::new());
        } else {
            assert_eq!(num(1).to_bits(), table.time[k].to_bits(), "row {row}: time");
        }
        table.positions[k].push([num(3), num(4), num(5)]);
        table.velocities[k].push([num(6), num(7), num(8)]);
    }
    assert_eq!(
        table.positions.last().map_or(particles, Vec::len),
        particles,
        "the last frame holds every particle"
    );
    table
}

/// The arrays of an NPZ frame file, with their shapes checked against `particles`.
struct Npz {
    table: Table,
    springs: Vec<u32>,
    springs_shape: Vec<u64>,
}

fn read_npy<R: Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    name: &str,
) -> (Vec<u64>, npyz::NpyFile<std::io::Cursor<Vec<u8>>>) {
    let mut entry = zip
        .by_name(name)
        .unwrap_or_else(|e| panic!("the archive has no {name}: {e}"));
    let mut bytes = Vec::new();
    entry.read_to_end(&mut bytes).unwrap();
    let npy = npyz::NpyFile::new(std::io::Cursor::new(bytes))
        .unwrap_or_else(|e| panic!("{name} is not .npy: {e}"));
    (npy.shape().to_vec(), npy)
}

#[track_caller]
fn read_npz(path: &Path, particles: usize) -> Npz {
    let file = std::fs::File::open(path).unwrap();
    let mut zip = zip::ZipArchive::new(file).expect("a zip archive");
    let mut names: Vec<String> = zip
        .file_names()
        .map(|n| n.expect("entry name").into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "backend.npy",
            "body_count.npy",
            "body_first.npy",
            "body_names.npy",
            "damping.npy",
            "device.npy",
            "dt.npy",
            "energy_elastic.npy",
            "energy_gravitational.npy",
            "energy_kinetic.npy",
            "frame_rate.npy",
            "integrator.npy",
            "masses.npy",
            "positions.npy",
            "rest_lengths.npy",
            "scene_file.npy",
            "scene_text.npy",
            "springs.npy",
            "stiffness.npy",
            "time.npy",
            "velocities.npy",
        ]
    );
    let (shape, npy) = read_npy(&mut zip, "time.npy");
    let time: Vec<f64> = npy.into_vec().expect("time is float64");
    assert_eq!(shape, [time.len() as u64]);
    let frames = time.len();
    let mut arrays = Vec::new();
    for name in ["positions.npy", "velocities.npy"] {
        let (shape, npy) = read_npy(&mut zip, name);
        assert_eq!(shape, [frames as u64, particles as u64, 3], "{name} shape");
        let flat: Vec<f64> = npy.into_vec().unwrap_or_else(|e| panic!("{name}: {e}"));
        let per_frame: Vec<Vec<[f64; 3]>> = flat
            .chunks_exact(particles * 3)
            .map(|f| f.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect())
            .collect();
        arrays.push(per_frame);
    }
    let (springs_shape, npy) = read_npy(&mut zip, "springs.npy");
    let springs: Vec<u32> = npy.into_vec().expect("springs are uint32");
    let velocities = arrays.pop().unwrap();
    let positions = arrays.pop().unwrap();
    Npz {
        table: Table {
            time,
            positions,
            velocities,
        },
        springs,
        springs_shape,
    }
}

/// Runs `scene` in `sb` writing to `name` (format from its extension); returns the status.
fn run_to(sb: &Sandbox, scene: &Path, name: &str, extra: &[&str]) -> i32 {
    let out = sb.path().join(name);
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    sb.run(&args).status
}

fn scene() -> Cube {
    // dt and frame rate chosen so the times are not round decimals.
    Cube {
        integrator: "rk4",
        dt: 0.0007,
        duration: 0.03,
        frame_rate: 300.0,
        resolution: [3, 2, 4],
        ..Cube::default()
    }
}

#[test]
fn csv_holds_the_same_numbers_as_jsonl() {
    let cube = scene();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    assert_eq!(run_to(&sb, &path, "f.jsonl", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "f.csv", &[]), EXIT_OK);
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    let n = cube.particles();
    assert_eq!(
        jsonl.frames.len(),
        frame_schedule(cube.dt, cube.duration, cube.frame_rate).len()
    );
    let csv = read_csv(&sb.path().join("f.csv"), n);
    assert_same_bits(&Table::from_jsonl(&jsonl), &csv, "CSV vs JSON Lines");
}

#[test]
fn npz_holds_the_same_numbers_as_jsonl() {
    let cube = scene();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    assert_eq!(run_to(&sb, &path, "f.jsonl", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "f.npz", &[]), EXIT_OK);
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    let n = cube.particles();
    let npz = read_npz(&sb.path().join("f.npz"), n);
    assert_same_bits(&Table::from_jsonl(&jsonl), &npz.table, "NPZ vs JSON Lines");

    // springs [S, 2]: S from `check --json`, every pair two distinct existing particles, no
    // pair twice.
    let check = sb.run(&["check", path.to_str().unwrap(), "--json"]);
    check.expect_status(EXIT_OK);
    let v: serde_json::Value = serde_json::from_str(&check.stdout_text()).unwrap();
    let s = ["structural", "shear", "bending"]
        .iter()
        .map(|k| v["springs"][k].as_u64().unwrap())
        .sum::<u64>();
    assert_eq!(npz.springs_shape, [s, 2]);
    let mut pairs: Vec<(u32, u32)> = npz
        .springs
        .chunks_exact(2)
        .map(|p| (p[0].min(p[1]), p[0].max(p[1])))
        .collect();
    for &(a, b) in &pairs {
        assert!(a != b && (b as usize) < n, "spring ({a}, {b})");
    }
    pairs.sort_unstable();
    pairs.dedup();
    assert_eq!(pairs.len() as u64, s, "no spring listed twice");
}

/// An NPZ array of `T` with its shape.
fn npz_array<T: npyz::Deserialize>(path: &Path, name: &str) -> (Vec<u64>, Vec<T>) {
    let mut zip = zip::ZipArchive::new(std::fs::File::open(path).unwrap()).unwrap();
    let (shape, npy) = read_npy(&mut zip, &format!("{name}.npy"));
    let values = npy
        .into_vec()
        .unwrap_or_else(|e| panic!("{name} of the expected type: {e}"));
    (shape, values)
}

#[test]
fn npz_describes_its_run() {
    let cube = Cube {
        ground: true,
        ..scene()
    };
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    assert_eq!(run_to(&sb, &path, "f.jsonl", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "f.npz", &[]), EXIT_OK);
    let npz = sb.path().join("f.npz");
    let n = cube.particles() as u64;
    let scalar = |name: &str| {
        let (shape, v) = npz_array::<f64>(&npz, name);
        assert_eq!(shape, [0u64; 0], "{name} is a scalar");
        v[0]
    };
    let string = |name: &str| {
        let (shape, v) = npz_array::<String>(&npz, name);
        assert_eq!(shape, [0u64; 0], "{name} is a scalar");
        v[0].clone()
    };
    assert_eq!(scalar("dt"), cube.dt);
    assert_eq!(scalar("frame_rate"), cube.frame_rate);
    assert_eq!(string("integrator"), "rk4");
    assert_eq!(string("backend"), "cpu");
    assert!(string("device").starts_with("CPU"), "{}", string("device"));
    assert_eq!(
        string("scene_text"),
        std::fs::read_to_string(&path).unwrap()
    );
    assert_eq!(
        Path::new(&string("scene_file")),
        std::path::absolute(&path).unwrap()
    );
    let (shape, masses) = npz_array::<f64>(&npz, "masses");
    assert_eq!(shape, [n]);
    let total: f64 = masses.iter().sum();
    assert!((total - cube.mass).abs() < 1e-12 * cube.mass, "{total}");
    let (_, names) = npz_array::<String>(&npz, "body_names");
    let (_, first) = npz_array::<u32>(&npz, "body_first");
    let (_, count) = npz_array::<u32>(&npz, "body_count");
    assert_eq!(
        (names, first, count),
        (vec!["cube".to_owned()], vec![0], vec![n as u32])
    );

    // Rest lengths are the springs' lengths in frame 0 (the cube starts undeformed);
    // stiffness and damping are the scene's.
    let (_, springs) = npz_array::<u32>(&npz, "springs");
    let (shape, rest) = npz_array::<f64>(&npz, "rest_lengths");
    assert_eq!(shape, [springs.len() as u64 / 2]);
    let (_, x) = npz_array::<f64>(&npz, "positions");
    let at = |i: u32| &x[3 * i as usize..3 * i as usize + 3];
    for (pair, r) in springs.chunks_exact(2).zip(&rest) {
        let (a, b) = (at(pair[0]), at(pair[1]));
        let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        assert!((d - r).abs() <= 1e-12 * r, "rest {r} vs length {d}");
    }
    for (name, value) in [("stiffness", cube.stiffness), ("damping", cube.damping)] {
        let (shape, v) = npz_array::<f64>(&npz, name);
        assert_eq!(shape, [rest.len() as u64]);
        assert!(v.iter().all(|&k| k == value), "{name}");
    }

    // Energies per frame: JSON Lines' to the bit.
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    for key in ["kinetic", "gravitational", "elastic"] {
        let (shape, e) = npz_array::<f64>(&npz, &format!("energy_{key}"));
        assert_eq!(shape, [jsonl.frames.len() as u64]);
        let expected: Vec<u64> = jsonl
            .frames
            .iter()
            .map(|f| f64_of(&f["energy"][key]).to_bits())
            .collect();
        assert_eq!(
            e.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            expected,
            "{key}"
        );
    }
    // JSON Lines' header holds the scene text too.
    assert_eq!(
        jsonl.header["scene_text"].as_str(),
        Some(std::fs::read_to_string(&path).unwrap().as_str())
    );

    // With --set and an override the text is the scene that ran, and loads as it.
    assert_eq!(
        run_to(
            &sb,
            &path,
            "g.npz",
            &["--set", "body[0].mass=3.5", "--dt", "0.0005"]
        ),
        EXIT_OK
    );
    let (_, text) = npz_array::<String>(&sb.path().join("g.npz"), "scene_text");
    let again = sb.write("again.toml", &text[0]);
    let check = sb.run(&["check", again.to_str().unwrap(), "--json"]);
    check.expect_status(EXIT_OK);
    let v: serde_json::Value = serde_json::from_str(&check.stdout_text()).unwrap();
    assert_eq!(v["total_mass"].as_f64(), Some(3.5));
    assert_eq!(v["dt"].as_f64(), Some(0.0005));
    assert_eq!(v["integrator"].as_str(), Some("rk4"));
}

/// NPZ stages its arrays beside its destination, not in `$TMPDIR`: a run to a file writes the
/// archive whatever `$TMPDIR` is (here a directory that does not exist), the same numbers as
/// JSON Lines, and leaves nothing beside it; a run to standard output, which has no directory
/// of its own, stages in `$TMPDIR` and names it, once, when it cannot.
#[test]
fn npz_stages_beside_its_destination() {
    let cube = scene();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    let missing = sb.path().join("no-tmp");
    let with_missing_tmp = |out: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_softbody"))
            .args(["run", path.to_str().unwrap(), "--quiet", "--format", "npz"])
            .args(["--out", out])
            .current_dir(sb.path())
            .env("TMPDIR", &missing)
            .output()
            .unwrap()
    };
    let o = with_missing_tmp("f.npz");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(EXIT_OK), "{stderr}");
    assert_eq!(run_to(&sb, &path, "f.jsonl", &[]), EXIT_OK);
    let npz = read_npz(&sb.path().join("f.npz"), cube.particles());
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    assert_same_bits(&Table::from_jsonl(&jsonl), &npz.table, "NPZ vs JSON Lines");
    assert_eq!(entries(sb.path()), ["f.jsonl", "f.npz", "s.toml"]);

    let o = with_missing_tmp("-");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(EXIT_OUTPUT), "{stderr}");
    let expected = format!(
        "cannot stage the NPZ arrays in {}: No such file or directory (os error 2)",
        missing.display()
    );
    assert!(stderr.contains(&expected), "{stderr}");
    assert_eq!(stderr.matches("(os error 2)").count(), 1, "{stderr}");
    assert!(o.stdout.is_empty());
}

/// A full disk (`/dev/full`, a device written in place) fails with status 1, naming the
/// destination and saying the cause once, whatever the format.
#[cfg(target_os = "linux")]
#[test]
fn a_full_disk_names_the_destination_once() {
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &scene().toml());
    for format in ["jsonl", "csv", "npz"] {
        let o = sb.run(&[
            "run",
            path.to_str().unwrap(),
            "--out",
            "/dev/full",
            "--format",
            format,
            "--quiet",
        ]);
        o.expect_status(EXIT_OUTPUT);
        assert!(
            o.stderr
                .contains("cannot write frames: /dev/full: No space left on device (os error 28)"),
            "{format}: {}",
            o.stderr
        );
        assert_eq!(o.stderr.matches("(os error 28)").count(), 1, "{}", o.stderr);
    }
}

#[test]
fn format_follows_the_out_extension_and_the_flag_must_agree() {
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &Cube::default().toml());
    assert_eq!(run_to(&sb, &path, "a.csv", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "b.npz", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "c.jsonl", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "d.txt", &["--format", "csv"]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "e", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "f.ply", &[]), EXIT_OK);
    assert_eq!(run_to(&sb, &path, "g.obj", &[]), EXIT_OK);
    let head = |name: &str| {
        let bytes = std::fs::read(sb.path().join(name)).unwrap();
        bytes[..bytes.len().min(40)].to_vec()
    };
    assert!(head("a.csv").starts_with(b"frame,time,particle,"));
    assert!(head("b.npz").starts_with(b"PK\x03\x04"), "a zip archive");
    assert!(head("c.jsonl").starts_with(b"{\"softbody_frames\":1"));
    assert!(head("d.txt").starts_with(b"frame,time,particle,"));
    assert!(
        head("e").starts_with(b"{\"softbody_frames\":1"),
        "JSON Lines for a name without an extension"
    );
    // NAME.ply and NAME.obj name the directory NAME, as NAME.pvd does for VTK.
    assert!(head("f/f_000000.ply").starts_with(b"ply\n"));
    assert!(head("g/g_000000.obj").starts_with(b"# "));

    // A contradiction or an extension that names no format: refused before anything is
    // written.
    for (name, flags, says) in [
        (
            "h.csv",
            &["--format", "jsonl"][..],
            "its extension is csv's, but --format jsonl",
        ),
        (
            "i.npz",
            &["--format", "csv"][..],
            "its extension is npz's, but --format csv",
        ),
        ("j.dat", &[][..], ".dat names no output format"),
        ("k.json", &[][..], "JSON Lines files end in .jsonl"),
        ("l.vtu", &[][..], "named by its .pvd collection"),
    ] {
        let out = sb.path().join(name);
        let mut args = vec![
            "run",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(flags);
        let run = sb.run(&args);
        run.expect_status(EXIT_BAD_INPUT);
        assert!(run.stderr.contains(says), "{name}: {}", run.stderr);
        assert!(!out.exists(), "{name} was written");
    }
}

#[test]
fn unstable_run_leaves_valid_csv_and_npz_with_the_frames_of_jsonl() {
    let cube = Cube::unstable();
    let n = cube.particles();
    let planned = frame_schedule(cube.dt, cube.duration, cube.frame_rate).len();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    for name in ["f.jsonl", "f.csv", "f.npz"] {
        assert_eq!(run_to(&sb, &path, name, &[]), EXIT_UNSTABLE, "{name}");
    }
    assert_eq!(entries(sb.path()), ["f.csv", "f.jsonl", "f.npz", "s.toml"]);
    let jsonl = Table::from_jsonl(&read_jsonl(&sb.path().join("f.jsonl")));
    assert!(!jsonl.time.is_empty() && jsonl.time.len() < planned);
    let csv = read_csv(&sb.path().join("f.csv"), n);
    assert_same_bits(&jsonl, &csv, "partial CSV vs JSON Lines");
    let npz = read_npz(&sb.path().join("f.npz"), n);
    assert_same_bits(&jsonl, &npz.table, "partial NPZ vs JSON Lines");
}
