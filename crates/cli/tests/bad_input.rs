//! Bad input: every refused scene file exits with status 2 and a message naming the file, the
//! line and column, and the key; bad arguments exit with status 2; and a refused run leaves no
//! output file behind.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::*;

const SIM: &str = "[simulation]\ndt = 0.001\nduration = 0.01\n";

const CUBE: &str = "[[body]]\n\
                    kind = \"cuboid\"\n\
                    size = [1.0, 1.0, 1.0]\n\
                    resolution = [2, 2, 2]\n\
                    mass = 1.0\n";

const PAIR: &str = "[[body]]\n\
                    kind = \"particles\"\n\
                    positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\n\
                    masses = [1.0, 1.0]\n";

/// Runs `softbody check` and `softbody run` (once with `--out` into an empty directory, once
/// with the default output) on `path`, which holds `text`; both must exit with status 2 with a
/// message `FILE:LINE:COLUMN: KEY: ...` where LINE is the line of `text` holding `marker` and
/// COLUMN lies on it, and the runs must leave no output. Returns the message of `check`.
#[track_caller]
fn assert_refused_at(sb: &Sandbox, path: &Path, text: &str, key: &str, marker: &str) -> String {
    let line = line_of(text, marker);
    let source_line = text.lines().nth(line - 1).unwrap();
    let scene = path.to_str().unwrap();

    let out_dir = sb.mkdir("frames");
    let runs = [
        ("check", sb.run(&["check", scene])),
        ("check --json", sb.run(&["check", scene, "--json"])),
        (
            "run --out",
            sb.run(&[
                "run",
                scene,
                "--out",
                out_dir.join("f.jsonl").to_str().unwrap(),
            ]),
        ),
        ("run", sb.run(&["run", scene])),
    ];
    for (what, outcome) in &runs {
        outcome.expect_status(EXIT_BAD_INPUT);
        let msg = &outcome.stderr;
        let located = format!("{scene}:{line}:");
        let Some(at) = msg.find(&located) else {
            panic!(
                "`{what}`: the message does not name {scene} line {line} ({source_line:?}):\n{msg}"
            );
        };
        let rest = &msg[at + located.len()..];
        let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
        let column: usize = digits
            .parse()
            .unwrap_or_else(|_| panic!("`{what}`: no column after {located}:\n{msg}"));
        assert!(
            (1..=source_line.chars().count() + 1).contains(&column),
            "`{what}`: column {column} is not on line {line} ({source_line:?}):\n{msg}"
        );
        assert!(
            rest[digits.len()..].starts_with(&format!(": {key}: ")),
            "`{what}`: the message does not name the key `{key}` after {located}{column}:\n{msg}"
        );
        assert!(
            outcome.stdout.is_empty(),
            "`{what}`: nothing on stdout for a refused scene"
        );
    }
    assert_eq!(
        entries(&out_dir),
        Vec::<String>::new(),
        "a refused run left files in its --out directory"
    );
    assert_eq!(
        entries(&sb.path().join("out")),
        Vec::<String>::new(),
        "a refused run left files in out/"
    );
    runs[0].1.stderr.clone()
}

/// [`assert_refused_at`] for a scene file `scene.toml` holding `text`.
#[track_caller]
fn assert_refused(text: &str, key: &str, marker: &str) -> String {
    let sb = Sandbox::new();
    let path = sb.write("scene.toml", text);
    assert_refused_at(&sb, &path, text, key, marker)
}

// ---------------------------------------------------------------- syntax, keys, types

#[test]
fn toml_syntax_error_is_located() {
    let text = format!("{SIM}{}", CUBE.replace("mass = 1.0", "mass = 1.0.0"));
    let sb = Sandbox::new();
    let path = sb.write("scene.toml", &text);
    let out = sb.run(&["check", path.to_str().unwrap()]);
    out.expect_status(EXIT_BAD_INPUT);
    let line = line_of(&text, "mass = 1.0.0");
    assert!(
        out.stderr.contains(&format!("{}:{line}:", path.display())),
        "{}",
        out.stderr
    );
}

#[test]
fn toml_syntax_error_names_the_key() {
    let text = format!("{SIM}{}", CUBE.replace("mass = 1.0", "mass = 1.0.0"));
    assert_refused(&text, "body[0].mass", "mass = 1.0.0");
}

#[test]
fn unknown_top_level_table_is_refused() {
    let text = format!("{SIM}\n[extra]\nanswer = 42\n");
    let msg = assert_refused(&text, "extra", "[extra]");
    assert!(msg.contains("unknown field"), "{msg}");
}

#[test]
fn unknown_top_level_key_is_refused() {
    let text = format!("verbose = true\n{SIM}");
    assert_refused(&text, "verbose", "verbose = true");
}

#[test]
fn unknown_key_in_simulation_is_refused() {
    let text = format!("{SIM}speed = 3.0\n");
    let msg = assert_refused(&text, "simulation.speed", "speed = 3.0");
    assert!(msg.contains("speed"), "{msg}");
}

#[test]
fn unknown_key_in_body_is_refused() {
    let text = format!("{SIM}{CUBE}colour = \"red\"\n");
    assert_refused(&text, "body[0].colour", "colour");
}

#[test]
fn unknown_key_in_second_body_names_its_index() {
    let text = format!("{SIM}{CUBE}name = \"a\"\n{CUBE}name = \"b\"\nsqueeze = 2.0\n");
    assert_refused(&text, "body[1].squeeze", "squeeze");
}

#[test]
fn unknown_key_in_terrain_is_refused() {
    let text =
        format!("{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nbumpy = true\n");
    assert_refused(&text, "terrain[0].bumpy", "bumpy");
}

#[test]
fn key_of_another_kind_is_refused() {
    let text =
        format!("{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nradius = 2.0\n");
    assert_refused(&text, "terrain[0].radius", "radius");
}

#[test]
fn unknown_integrator_is_refused() {
    let text = SIM.replace("[simulation]\n", "[simulation]\nintegrator = \"verlet\"\n");
    let msg = assert_refused(&text, "simulation.integrator", "verlet");
    assert!(
        msg.contains("implicit-euler"),
        "lists the integrators: {msg}"
    );
}

#[test]
fn unknown_terrain_kind_is_refused() {
    let text = format!("{SIM}[[terrain]]\nkind = \"lava\"\n");
    assert_refused(&text, "terrain[0].kind", "lava");
}

#[test]
fn string_for_dt_is_refused() {
    let text = "[simulation]\ndt = \"fast\"\nduration = 0.01\n";
    assert_refused(text, "simulation.dt", "fast");
}

#[test]
fn missing_required_key_is_refused() {
    let text = format!("{SIM}{}", CUBE.replace("mass = 1.0\n", ""));
    let msg = assert_refused(&text, "body[0]", "[[body]]");
    assert!(msg.contains("mass"), "names the missing key: {msg}");
}

// ---------------------------------------------------------------- values

#[test]
fn negative_mass_is_refused() {
    let text = format!("{SIM}{}", CUBE.replace("mass = 1.0", "mass = -1.0"));
    assert_refused(&text, "body[0].mass", "mass = -1.0");
}

#[test]
fn zero_mass_is_refused() {
    let text = format!("{SIM}{}", CUBE.replace("mass = 1.0", "mass = 0.0"));
    assert_refused(&text, "body[0].mass", "mass = 0.0");
}

#[test]
fn zero_particle_mass_is_refused() {
    let text = format!("{SIM}{}", PAIR.replace("[1.0, 1.0]", "[1.0, 0.0]"));
    assert_refused(&text, "body[0].masses[1]", "masses");
}

#[test]
fn resolution_below_two_is_refused() {
    let text = format!("{SIM}{}", CUBE.replace("[2, 2, 2]", "[2, 1, 2]"));
    assert_refused(&text, "body[0].resolution[1]", "resolution");
}

fn huge_cube() -> String {
    format!(
        "{SIM}{}",
        CUBE.replace("[2, 2, 2]", "[100000, 100000, 100000]")
    )
}

/// 3.4e9 particles: within the u32 index range, far beyond any machine's memory.
fn cube_beyond_memory() -> String {
    format!("{SIM}{}", CUBE.replace("[2, 2, 2]", "[1500, 1500, 1500]"))
}

/// Runs `softbody ARGS SCENE` on `text` and asserts status 2 within two seconds (the size
/// check comes before anything is allocated), with `mention` in the message.
#[track_caller]
fn assert_refused_quickly(text: &str, args: &[&str], mention: &str) {
    let sb = Sandbox::new();
    let path = sb.write("scene.toml", text);
    let mut args = args.to_vec();
    args.push(path.to_str().unwrap());
    let started = Instant::now();
    let out = sb.run(&args);
    let took = started.elapsed();
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        took < Duration::from_secs(2),
        "took {took:?}: the size check must come before allocating"
    );
    assert!(out.stdout.is_empty());
    assert!(out.stderr.contains(mention), "{}", out.stderr);
}

#[test]
fn huge_scene_is_refused_before_allocating() {
    assert_refused_quickly(&huge_cube(), &["run", "--out", "-"], "particles");
    assert_refused_quickly(&huge_cube(), &["check"], "particles");
}

#[test]
fn huge_scene_error_points_at_the_resolution() {
    assert_refused(&huge_cube(), "body[0].resolution", "resolution");
}

#[test]
fn scene_larger_than_memory_is_refused_before_allocating() {
    assert_refused_quickly(&cube_beyond_memory(), &["run", "--out", "-"], "GiB");
    assert_refused_quickly(&cube_beyond_memory(), &["check"], "GiB");
}

#[test]
fn scene_larger_than_memory_error_points_at_the_resolution() {
    assert_refused(&cube_beyond_memory(), "body[0].resolution", "resolution");
}

#[test]
fn spring_naming_a_missing_particle_is_refused() {
    let text = format!("{SIM}{PAIR}springs = [{{ a = 0, b = 5, stiffness = 10.0 }}]\n");
    let msg = assert_refused(&text, "body[0].springs[0].b", "springs");
    assert!(msg.contains('5'), "{msg}");
}

#[test]
fn spring_naming_a_missing_particle_in_a_table_array_is_refused() {
    let text = format!("{SIM}{PAIR}\n[[body.springs]]\na = 7\nb = 1\nstiffness = 10.0\n");
    assert_refused(&text, "body[0].springs[0].a", "a = 7");
}

#[test]
fn pinned_index_out_of_range_is_refused() {
    let text = format!("{SIM}{CUBE}pinned = [0, 8]\n");
    let msg = assert_refused(&text, "body[0].pinned[1]", "pinned");
    assert!(msg.contains('8'), "{msg}");
}

#[test]
fn zero_length_spring_is_refused() {
    let text = format!(
        "{SIM}{}springs = [{{ a = 0, b = 1, stiffness = 10.0 }}]\n",
        PAIR.replace("[1.0, 0.0, 0.0]]", "[0.0, 0.0, 0.0]]")
    );
    let msg = assert_refused(&text, "body[0].springs[0]", "springs");
    assert!(msg.contains("zero-length"), "{msg}");
}

#[test]
fn spring_joining_a_particle_to_itself_is_refused() {
    let text = format!("{SIM}{PAIR}springs = [{{ a = 1, b = 1, stiffness = 10.0 }}]\n");
    assert_refused(&text, "body[0].springs[0].b", "springs");
}

#[test]
fn zero_dt_is_refused() {
    let text = "[simulation]\ndt = 0.0\nduration = 0.01\n";
    assert_refused(text, "simulation.dt", "dt = 0.0");
}

#[test]
fn negative_dt_is_refused() {
    let text = "[simulation]\ndt = -0.001\nduration = 0.01\n";
    assert_refused(text, "simulation.dt", "dt = -0.001");
}

#[test]
fn nan_dt_is_refused() {
    let text = "[simulation]\ndt = nan\nduration = 0.01\n";
    let msg = assert_refused(text, "simulation.dt", "nan");
    assert!(msg.contains("finite"), "{msg}");
}

#[test]
fn infinite_duration_is_refused() {
    let text = "[simulation]\ndt = 0.001\nduration = inf\n";
    assert_refused(text, "simulation.duration", "inf");
}

#[test]
fn nan_gravity_is_refused() {
    let text = format!("{SIM}gravity = [0.0, nan, 0.0]\n");
    assert_refused(&text, "simulation.gravity[1]", "gravity");
}

#[test]
fn infinite_position_is_refused() {
    let text = format!(
        "{SIM}{}",
        PAIR.replace("[1.0, 0.0, 0.0]]", "[1.0, -inf, 0.0]]")
    );
    assert_refused(&text, "body[0].positions[1][1]", "positions");
}

#[test]
fn nan_spring_stiffness_is_refused() {
    let text = format!("{SIM}{CUBE}structural = {{ stiffness = nan }}\n");
    assert_refused(&text, "body[0].structural.stiffness", "structural");
}

#[test]
fn more_frames_than_steps_is_refused() {
    let text = format!("{SIM}frame_rate = 5000.0\n");
    assert_refused(&text, "simulation.frame_rate", "frame_rate");
}

#[test]
fn duplicate_body_name_is_refused() {
    let text = format!("{SIM}{CUBE}name = \"twin\"\n{PAIR}name = \"twin\"\n");
    let lines: Vec<&str> = text.lines().collect();
    // The second `name = "twin"` is the offending one.
    let second = lines.iter().rposition(|l| l.contains("twin")).unwrap() + 1;
    let sb = Sandbox::new();
    let path = sb.write("scene.toml", &text);
    let out = sb.run(&["check", path.to_str().unwrap()]);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        out.stderr
            .contains(&format!("{}:{second}:", path.display())),
        "{}",
        out.stderr
    );
    assert!(out.stderr.contains(": body[1].name: "), "{}", out.stderr);
}

#[test]
fn zero_plane_normal_is_refused() {
    let text = format!("{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 0.0, 0.0]\n");
    assert_refused(&text, "terrain[0].normal", "normal");
}

#[test]
fn negative_sphere_radius_is_refused() {
    let text = format!("{SIM}[[terrain]]\nkind = \"sphere\"\nradius = -1.0\n");
    assert_refused(&text, "terrain[0].radius", "radius");
}

#[test]
fn negative_bowl_radius_in_second_terrain_is_refused() {
    let text = format!(
        "{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n\
         [[terrain]]\nkind = \"bowl\"\nradius = -2.0\n"
    );
    assert_refused(&text, "terrain[1].radius", "radius");
}

#[test]
fn negative_stiffness_is_refused() {
    let text = format!("{SIM}{CUBE}structural = {{ stiffness = -5.0 }}\n");
    assert_refused(&text, "body[0].structural.stiffness", "structural");
}

#[test]
fn negative_explicit_spring_stiffness_is_refused() {
    let text = format!("{SIM}{PAIR}springs = [{{ a = 0, b = 1, stiffness = -1.0 }}]\n");
    assert_refused(&text, "body[0].springs[0].stiffness", "springs");
}

#[test]
fn negative_damping_is_refused() {
    let text = format!("{SIM}{CUBE}shear = {{ stiffness = 5.0, damping = -0.1 }}\n");
    assert_refused(&text, "body[0].shear.damping", "shear");
}

#[test]
fn negative_friction_is_refused() {
    let text =
        format!("{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nfriction = -0.2\n");
    assert_refused(&text, "terrain[0].friction", "friction");
}

#[test]
fn restitution_above_one_is_refused() {
    let text = format!(
        "{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nrestitution = 1.5\n"
    );
    assert_refused(&text, "terrain[0].restitution", "restitution");
}

#[test]
fn negative_restitution_is_refused() {
    let text = format!(
        "{SIM}[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nrestitution = -0.1\n"
    );
    assert_refused(&text, "terrain[0].restitution", "restitution");
}

#[test]
fn heightfield_smaller_than_two_by_two_is_refused() {
    let text = format!(
        "{SIM}[[terrain]]\nkind = \"heightfield\"\nheights = [[0.0, 0.0]]\ncell_size = [1.0, 1.0]\n"
    );
    assert_refused(&text, "terrain[0].heights", "heights");
}

#[test]
fn ragged_heightfield_is_refused() {
    let text = format!(
        "{SIM}[[terrain]]\nkind = \"heightfield\"\nheights = [\n  [0.0, 0.0, 0.0],\n  [0.0, 0.0],\n]\ncell_size = [1.0, 1.0]\n"
    );
    assert_refused(&text, "terrain[0].heights[1]", "[0.0, 0.0],");
}

#[test]
fn missing_mesh_file_is_refused() {
    let text = format!("{SIM}[[terrain]]\nkind = \"mesh\"\npath = \"missing.obj\"\n");
    let msg = assert_refused(&text, "terrain[0].path", "missing.obj");
    assert!(msg.contains("missing.obj"), "{msg}");
}

#[test]
fn broken_mesh_file_is_refused() {
    let sb = Sandbox::new();
    // A face naming vertex 9 of 3.
    sb.write("broken.obj", "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 9\n");
    let text = format!("{SIM}[[terrain]]\nkind = \"mesh\"\npath = \"broken.obj\"\n");
    let path = sb.write("scene.toml", &text);
    let msg = assert_refused_at(&sb, &path, &text, "terrain[0].path", "broken.obj");
    assert!(msg.contains("broken.obj"), "{msg}");
}

#[test]
fn mesh_file_without_triangles_is_refused() {
    let sb = Sandbox::new();
    sb.write("empty.obj", "# nothing here\nv 0 0 0\n");
    let text = format!("{SIM}[[terrain]]\nkind = \"mesh\"\npath = \"empty.obj\"\n");
    let path = sb.write("scene.toml", &text);
    assert_refused_at(&sb, &path, &text, "terrain[0].path", "empty.obj");
}

#[test]
fn mesh_path_is_relative_to_the_scene_file() {
    // The same scene loads from another working directory: the mesh is found beside the scene.
    let sb = Sandbox::new();
    sb.write(
        "scenes/ground.obj",
        "v -5 0 -5\nv 5 0 -5\nv 5 0 5\nv -5 0 5\nf 1 3 2\nf 1 4 3\n",
    );
    let path = sb.write(
        "scenes/scene.toml",
        &format!("{SIM}{PAIR}[[terrain]]\nkind = \"mesh\"\npath = \"ground.obj\"\n"),
    );
    sb.run(&["check", path.to_str().unwrap()])
        .expect_status(EXIT_OK);
}

#[test]
fn missing_scene_file_is_bad_input() {
    let sb = Sandbox::new();
    let out = sb.run(&["run", "no-such-scene.toml"]);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(out.stderr.contains("no-such-scene.toml"), "{}", out.stderr);
    assert_eq!(entries(sb.path()), Vec::<String>::new());
    sb.run(&["check", "no-such-scene.toml"])
        .expect_status(EXIT_BAD_INPUT);
}

// ---------------------------------------------------------------- arguments

/// `softbody run` of a valid scene with `extra` arguments must exit with status 2, say
/// something mentioning `mention` on stderr, and leave its --out directory empty.
#[track_caller]
fn assert_bad_arguments(extra: &[&str], mention: &str) {
    let sb = Sandbox::new();
    let scene = sb.write("scene.toml", &Cube::default().toml());
    let out_dir = sb.mkdir("frames");
    let out_file = out_dir.join("f.jsonl");
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out_file.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = sb.run(&args);
    out.expect_status(EXIT_BAD_INPUT);
    assert!(
        out.stderr.contains(mention),
        "the message should mention {mention:?}:\n{}",
        out.stderr
    );
    assert!(out.stdout.is_empty(), "nothing on stdout");
    assert_eq!(entries(&out_dir), Vec::<String>::new(), "no output file");
    assert_eq!(entries(&sb.path().join("out")), Vec::<String>::new());
}

#[test]
fn negative_dt_argument_is_refused() {
    // A negative number is a value, not an option: the message is about --dt.
    assert_bad_arguments(&["--dt", "-1"], "--dt");
}

#[test]
fn zero_dt_argument_is_refused() {
    assert_bad_arguments(&["--dt", "0"], "--dt");
}

#[test]
fn nan_dt_argument_is_refused() {
    assert_bad_arguments(&["--dt", "nan"], "--dt");
}

#[test]
fn negative_fps_argument_is_refused() {
    assert_bad_arguments(&["--fps", "-30"], "--fps");
}

#[test]
fn negative_threads_argument_is_refused() {
    assert_bad_arguments(&["--threads", "-2"], "--threads");
}

#[test]
fn unknown_integrator_argument_is_refused() {
    assert_bad_arguments(&["--integrator", "foo"], "foo");
}

#[test]
fn unknown_format_argument_is_refused() {
    assert_bad_arguments(&["--format", "xml"], "xml");
}

#[test]
fn zero_threads_argument_is_refused() {
    assert_bad_arguments(&["--threads", "0"], "--threads");
}

#[test]
fn zero_fps_argument_is_refused() {
    assert_bad_arguments(&["--fps", "0"], "--fps");
}

#[test]
fn negative_duration_argument_is_refused() {
    assert_bad_arguments(&["--duration", "-1"], "--duration");
}

#[test]
fn unknown_option_is_refused() {
    assert_bad_arguments(&["--colour"], "--colour");
}

#[test]
fn override_that_makes_the_scene_invalid_is_refused() {
    // dt = 0.001 and 5000 frames/s: more than one frame per step.
    assert_bad_arguments(&["--fps", "5000"], "frame_rate");
}

#[test]
fn dt_override_too_coarse_for_the_frame_rate_is_refused() {
    // The scene asks for 100 frames/s; dt = 0.05 s cannot give them.
    assert_bad_arguments(&["--dt", "0.05"], "frame_rate");
}

#[test]
fn missing_scene_argument_is_refused() {
    let sb = Sandbox::new();
    sb.run(&["run"]).expect_status(EXIT_BAD_INPUT);
    sb.run(&["check"]).expect_status(EXIT_BAD_INPUT);
    assert_eq!(entries(sb.path()), Vec::<String>::new());
}

#[test]
fn unknown_subcommand_is_refused() {
    let sb = Sandbox::new();
    sb.run(&["simulate", "scene.toml"])
        .expect_status(EXIT_BAD_INPUT);
}

#[test]
fn negative_contact_radius_is_refused() {
    let text = format!("{SIM}{CUBE}contact_radius = -0.01\n");
    assert_refused(&text, "body[0].contact_radius", "contact_radius");
}

#[test]
fn body_restitution_above_one_is_refused() {
    let text = SIM.replace("duration", "body_restitution = 1.5\nduration") + CUBE;
    assert_refused(&text, "simulation.body_restitution", "body_restitution");
}

#[test]
fn negative_body_friction_is_refused() {
    let text = SIM.replace("duration", "body_friction = -0.2\nduration") + CUBE;
    assert_refused(&text, "simulation.body_friction", "body_friction");
}

#[test]
fn contact_radius_beyond_the_lattice_spacing_is_refused() {
    // The cube's spacing is 1 m (2 particles per 1 m edge).
    let text = format!("{SIM}{CUBE}contact_radius = 1.5\n");
    let message = assert_refused(&text, "body[0].contact_radius", "contact_radius");
    assert!(
        message.contains("smallest lattice spacing, 1 m"),
        "{message}"
    );
}

/// Energies that overflow f64 are never written as JSON `null`: a scene whose initial energy
/// overflows (a velocity of 1e200 m/s) is refused before anything is written (status 2), and
/// one whose energy overflows as it runs (falling at 1e308 m/s²) stops as unstable (status 3)
/// with the frames before it, every number in them finite.
#[test]
fn overflowing_energies_are_refused_or_stop_the_run_never_written_as_null() {
    let sb = Sandbox::new();
    let fast = Cube {
        velocity: [1e200, 0.0, 0.0],
        ..Cube::default()
    };
    sb.write("fast.toml", &fast.toml());
    let o = sb.run(&["run", "fast.toml", "--out", "fast.jsonl"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr.contains(
            "body[0].velocity: the initial kinetic energy is not a finite number: the speed \
             1e200 m/s squared"
        ),
        "{}",
        o.stderr
    );
    assert_eq!(entries(sb.path()), ["fast.toml"], "nothing written");

    let falling = Cube {
        ground: false,
        ..Cube::default()
    };
    let heavy = falling.toml().replace(
        "[simulation]\n",
        "[simulation]\ngravity = [0.0, -1e308, 0.0]\n",
    );
    sb.write("heavy.toml", &heavy);
    let o = sb.run(&["run", "heavy.toml", "--out", "heavy.jsonl"]);
    o.expect_status(EXIT_UNSTABLE);
    assert!(o.stderr.contains("unstable"), "{}", o.stderr);
    let text = std::fs::read_to_string(sb.path().join("heavy.jsonl")).unwrap();
    assert!(!text.contains("null"), "a non-number was written:\n{text}");
    assert!(!parse_jsonl(&text).frames.is_empty(), "frame 0 is kept");
}

/// A scene without a body is refused (docs/guide/scene-format.md), by `check` and `run` alike.
#[test]
fn a_scene_without_a_body_is_refused() {
    let sb = Sandbox::new();
    let text = format!("{SIM}\n[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n");
    let scene = sb.write("empty.toml", &text);
    let scene = scene.to_str().unwrap();
    for args in [
        &["check", scene][..],
        &["run", scene, "--out", "f.jsonl"][..],
    ] {
        let o = sb.run(args);
        o.expect_status(EXIT_BAD_INPUT);
        assert!(
            o.stderr.contains("empty.toml") && o.stderr.contains("the scene has no [[body]]"),
            "{args:?}: {}",
            o.stderr
        );
    }
    assert_eq!(entries(sb.path()), ["empty.toml"], "nothing written");
}

/// Under an address-space limit (`ulimit -v`, as batch schedulers set) a scene that needs more
/// is refused up front with the limit named (status 2), instead of aborting on an allocation.
/// A cuboid's springs are a stencil, not a list: a 100³ cube (15.7 M springs) is checked
/// within 1 GiB, where its list alone would take 630 MB more.
#[cfg(target_os = "linux")]
#[test]
fn a_scene_beyond_the_address_space_limit_is_refused() {
    let sb = Sandbox::new();
    let cube = |n: u32, integrator: &str| {
        format!(
            "{SIM}integrator = \"{integrator}\"\n[[body]]\nkind = \"cuboid\"\n\
             size = [1.0, 1.0, 1.0]\nresolution = [{n}, {n}, {n}]\n\
             center = [0.0, 1.0, 0.0]\nmass = 1.0\n\
             structural = {{ stiffness = 100.0, damping = 0.1 }}\n\
             shear = {{ stiffness = 100.0, damping = 0.1 }}\n\
             bending = {{ stiffness = 100.0, damping = 0.1 }}\n"
        )
    };
    // 4.6 GiB even lean; 1.7 GiB under implicit Euler (1.5 kB a particle).
    sb.write("big.toml", &cube(300, "symplectic-euler"));
    sb.write("implicit.toml", &cube(100, "implicit-euler"));
    sb.write("lean.toml", &cube(100, "symplectic-euler"));
    let limited_to = |kib: u64, command: &str| {
        std::process::Command::new("sh")
            .arg("-c")
            .arg(format!("ulimit -v {kib} && exec \"$0\" {command}"))
            .arg(env!("CARGO_BIN_EXE_softbody"))
            .current_dir(sb.path())
            .stdin(std::process::Stdio::null())
            .output()
            .unwrap()
    };
    let limited = |command: &str| limited_to(1 << 20, command);
    for command in [
        "check big.toml",
        "run big.toml --out f.jsonl",
        "check implicit.toml",
        "run implicit.toml --out f.jsonl",
    ] {
        let out = limited(command);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(
            out.status.code(),
            Some(EXIT_BAD_INPUT),
            "{command}: {stderr}"
        );
        assert!(
            stderr.contains("body[0].resolution") && stderr.contains("address-space limit"),
            "{command}: {stderr}"
        );
    }
    let out = limited("check lean.toml --json");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}");
    assert!(stdout.contains("\"total\":15671796"), "{stdout}");
    // Implicit Euler on a cuboid lists no springs either: its 1.7 GiB fit in 2.5 GiB, where a
    // listed model's 1 kB a particle and 144 B a spring (3 GiB) did not.
    let out = limited_to(5 << 19, "check implicit.toml --json");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}");
    assert_eq!(
        entries(sb.path()),
        ["big.toml", "implicit.toml", "lean.toml"],
        "nothing written"
    );
    // The output's header: NPZ holds every spring's ends, rest length and coefficients (40 B a
    // spring, 0.58 GiB here), refused where the header is made, with what it needs and what
    // is left, and nothing written; JSON Lines, which does without them, runs in the same room.
    let one_step = "--dt 1e-6 --duration 1e-6 --threads 1";
    let out = limited_to(640 << 10, &format!("run lean.toml --out f.npz {one_step}"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(EXIT_BAD_INPUT), "{stderr}");
    assert!(
        stderr.contains("the output takes every spring's ends")
            && stderr.contains("15671796 springs, 0.58 GiB")
            && stderr.contains("address-space limit"),
        "{stderr}"
    );
    assert_eq!(
        entries(sb.path()),
        ["big.toml", "implicit.toml", "lean.toml"],
        "nothing written"
    );
    let out = limited_to(
        640 << 10,
        &format!("run lean.toml --out g.jsonl {one_step}"),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert_eq!(
        entries(sb.path()),
        ["big.toml", "g.jsonl", "implicit.toml", "lean.toml"]
    );
}

/// A VTK frame is encoded as it is written: the run that `run`'s memory check lets through
/// writes its frame. A 60³ cube (3.3 M springs) under 400 MiB: the sink built each frame's
/// cells and arrays in memory (about 105 B a spring) and aborted on an allocation up to 500 MiB.
#[cfg(target_os = "linux")]
#[test]
fn a_vtk_frame_fits_where_its_header_does() {
    let sb = Sandbox::new();
    sb.write(
        "cube.toml",
        "[simulation]\ndt = 1e-6\nduration = 1e-6\n\
         [[body]]\nkind = \"cuboid\"\nsize = [1.0, 1.0, 1.0]\nresolution = [60, 60, 60]\n\
         center = [0.0, 1.0, 0.0]\nmass = 1.0\n\
         structural = { stiffness = 100.0, damping = 0.1 }\n\
         shear = { stiffness = 100.0, damping = 0.1 }\n\
         bending = { stiffness = 100.0, damping = 0.1 }\n",
    );
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 409600 && exec \"$0\" run cube.toml --out f.pvd --threads 1")
        .arg(env!("CARGO_BIN_EXE_softbody"))
        .current_dir(sb.path())
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert_eq!(entries(sb.path()), ["cube.toml", "f", "f.pvd"]);
    assert_eq!(entries(&sb.path().join("f")), ["f_000000.vtu"]);
    let vtu = std::fs::read_to_string(sb.path().join("f/f_000000.vtu")).unwrap();
    assert!(
        vtu.contains("<Piece NumberOfPoints=\"216000\" NumberOfCells=\"3380048\">"),
        "{}",
        &vtu[..vtu.len().min(600)]
    );
}

/// Standard error closed before the message (`softbody … 2>&1 | head -0` gone): the refusal's
/// exit status stays 2, not a panic's 101.
#[test]
fn a_closed_standard_error_keeps_the_exit_status() {
    let sb = Sandbox::new();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_softbody"))
        .args(["run", "missing.toml"])
        .current_dir(sb.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("softbody starts");
    drop(child.stderr.take());
    let status = child.wait().expect("softbody ends");
    assert_eq!(status.code(), Some(2), "{status}");
}
