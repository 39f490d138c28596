//! Input at the edges, as the command line shows it: a mesh or a run's frames given as a scene,
//! a near miss of an integrator's name, a `--set` value of two lines, a scene whose initial
//! energy overflows (refused by `check` as by `run`, naming the body), a ground mesh wound the
//! wrong way, and a Blender-style OBJ mesh body whose exports give the file's vertices in the
//! file's order.

mod common;

use common::*;

/// The unit cube as Blender writes it: `vt`/`vn` corners, quads, vertices in another order
/// than the faces', and a ninth vertex no face uses (the scene crate's test mesh).
const BLENDER_CUBE: &str = include_str!("../../scene/tests/data/blender-cube.obj");

#[test]
fn an_obj_or_a_frames_file_given_as_a_scene_is_named_for_what_it_is() {
    let sb = Sandbox::new();
    sb.write("torus.obj", BLENDER_CUBE);
    for command in ["run", "check"] {
        let o = sb.run(&[command, "torus.obj"]);
        o.expect_status(EXIT_BAD_INPUT);
        assert!(
            o.stderr.contains(
                "torus.obj: (document): this looks like an OBJ file (a mesh); a scene is a TOML \
                 file (see docs/guide/scene-format.md)"
            ),
            "{command}: {}",
            o.stderr
        );
    }
    let cube = sb.write("cube.toml", &Cube::default().toml());
    sb.run(&["run", cube.to_str().unwrap(), "--quiet", "--out", "f.jsonl"])
        .expect_status(EXIT_OK);
    let o = sb.run(&["check", "f.jsonl"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr
            .contains("f.jsonl: (document): this looks like JSON (a run's frames, JSON Lines)"),
        "{}",
        o.stderr
    );
}

#[test]
fn an_integrator_in_capitals_is_answered_with_its_name() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &Cube::default().toml());
    let o = sb.run(&["check", "cube.toml", "--integrator", "RK4"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr
            .contains("unknown integrator `RK4`; did you mean `rk4`?"),
        "{}",
        o.stderr
    );
    sb.run(&["check", "cube.toml", "--integrator", "rk4"])
        .expect_status(EXIT_OK);
}

#[test]
fn a_set_value_of_two_lines_is_refused() {
    let sb = Sandbox::new();
    sb.write("cube.toml", &Cube::default().toml());
    let o = sb.run(&["check", "cube.toml", "--set", "body[0].mass=2\n3"]);
    o.expect_status(EXIT_BAD_INPUT);
    assert!(
        o.stderr.contains(
            "the value of `body[0].mass` holds a line break: a value is one line of TOML"
        ),
        "{}",
        o.stderr
    );
}

/// `check` refused nothing `run` would refuse: a mass of 1e308 kg held 10 m up has a
/// gravitational energy beyond f64, said with the body and the values, in exponent form.
#[test]
fn check_refuses_an_initial_energy_beyond_f64_naming_the_body() {
    let sb = Sandbox::new();
    let heavy = Cube {
        mass: 1e308,
        center: [0.0, 10.0, 0.0],
        velocity: [0.0; 3],
        ..Cube::default()
    };
    sb.write("heavy.toml", &heavy.toml());
    for command in ["check", "run"] {
        let o = sb.run(&[command, "heavy.toml"]);
        o.expect_status(EXIT_BAD_INPUT);
        assert!(
            o.stderr.contains(
                "body[0]: the initial gravitational energy −m·g·x is not a finite number: \
                 1e308 kg at g·x = -98.10000000000001 J/kg is beyond f64's range"
            ),
            "{command}: {}",
            o.stderr
        );
    }
    assert_eq!(entries(sb.path()), ["heavy.toml"], "nothing written");
}

/// A ground patch wound clockwise seen from above counts the space above it as solid: `check`
/// warns that the cube resting on it starts with every particle inside, and says why.
#[test]
fn a_ground_mesh_wound_the_wrong_way_is_named_as_the_likely_cause() {
    let sb = Sandbox::new();
    sb.write(
        "ground.obj",
        "v -3 0 -3\nv 3 0 -3\nv 3 0 3\nv -3 0 3\nf 1 2 3\nf 1 3 4\n",
    );
    let text = Cube::default().toml().replace(
        "kind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n",
        "kind = \"mesh\"\npath = \"ground.obj\"\n",
    );
    sb.write("cube.toml", &text);
    let o = sb.run(&["check", "cube.toml"]);
    o.expect_status(EXIT_OK);
    let out = o.stdout_text();
    assert!(
        out.contains(
            "warning     body `cube` starts with 27 of its 27 particles inside terrain[0]"
        ),
        "{out}"
    );
    assert!(
        out.contains("so many inside a mesh suggest it is wound the wrong way round"),
        "{out}"
    );
}

/// A mesh body of the Blender cube, exported as OBJ: frame 0's vertices are the file's nine,
/// in the file's order (the unused ninth included), each where the scene puts it.
#[test]
fn a_mesh_body_exports_the_files_vertices_in_the_files_order() {
    let sb = Sandbox::new();
    sb.write("cube.obj", BLENDER_CUBE);
    let text = "[simulation]\ndt = 0.001\nduration = 0.01\n\n[[body]]\nname = \"cube\"\n\
                kind = \"mesh\"\nfile = \"cube.obj\"\ncell = 0.25\nmass = 1.0\n\
                center = [10.5, 0.5, 0.5]\nstructural = { stiffness = 100.0 }\n";
    sb.write("s.toml", text);
    sb.run(&[
        "run", "s.toml", "--quiet", "--format", "obj", "--out", "meshes",
    ])
    .expect_status(EXIT_OK);
    let frame = std::fs::read_to_string(sb.path().join("meshes/meshes_000000.obj")).unwrap();
    let vertices: Vec<[f64; 3]> = frame
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let c: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [c[0], c[1], c[2]]
        })
        .collect();
    let file: Vec<[f64; 3]> = BLENDER_CUBE
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let c: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [c[0] + 10.0, c[1], c[2]]
        })
        .collect();
    assert_eq!(file.len(), 9);
    assert_eq!(vertices.len(), 9, "{frame}");
    for (i, (v, f)) in vertices.iter().zip(&file).enumerate() {
        let off = (0..3).map(|a| (v[a] - f[a]).abs()).fold(0.0, f64::max);
        assert!(off <= 1e-12, "vertex {i}: {v:?} is not the file's {f:?}");
    }
    let faces: Vec<&str> = frame.lines().filter(|l| l.starts_with("f ")).collect();
    assert_eq!(faces.len(), 12);
    assert_eq!(faces[0], "f 5 7 3");
}
