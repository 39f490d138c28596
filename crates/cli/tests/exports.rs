//! VTK, PLY and OBJ exports, read back with independent parsers (roxmltree and base64 for
//! VTK's XML, a minimal PLY reader written here, tobj for OBJ) and compared with the JSON
//! Lines (and NPZ springs) of the same run; multi-file outputs put in place whole, also after
//! an instability; refusals.

mod common;

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use base64::Engine;
use common::*;

// ---------------------------------------------------------------- readers

/// One `.vtu` frame, decoded.
struct Vtu {
    time: f64,
    points: Vec<[f64; 3]>,
    velocity: Vec<[f64; 3]>,
    speed: Vec<f64>,
    /// Cells as particle lists, in file order, with their VTK type.
    cells: Vec<(u8, Vec<i64>)>,
    kind: Vec<u8>,
    strain: Vec<f64>,
}

impl Vtu {
    fn lines(&self) -> Vec<[i64; 2]> {
        self.cells
            .iter()
            .filter(|(t, _)| *t == 3)
            .map(|(_, c)| [c[0], c[1]])
            .collect()
    }

    fn triangles(&self) -> Vec<[i64; 3]> {
        self.cells
            .iter()
            .filter(|(t, _)| *t == 5)
            .map(|(_, c)| [c[0], c[1], c[2]])
            .collect()
    }
}

/// The bytes of a `format="binary"` DataArray: base64 of a UInt64 byte count and the data.
#[track_caller]
fn binary(node: roxmltree::Node<'_, '_>) -> Vec<u8> {
    assert_eq!(node.attribute("format"), Some("binary"), "{node:?}");
    let text: String = node
        .text()
        .unwrap_or("")
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect();
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(text)
        .expect("valid base64");
    let (count, data) = bytes.split_at(8);
    assert_eq!(
        u64::from_le_bytes(count.try_into().unwrap()) as usize,
        data.len(),
        "the block header gives the byte count"
    );
    data.to_vec()
}

fn f64s(bytes: &[u8]) -> Vec<f64> {
    bytes
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

fn i64s(bytes: &[u8]) -> Vec<i64> {
    bytes
        .chunks_exact(8)
        .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

fn triples_of(v: Vec<f64>) -> Vec<[f64; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// The DataArray named `name` under `parent`, with its declared type and components checked.
#[track_caller]
fn array<'a, 'i>(
    parent: roxmltree::Node<'a, 'i>,
    name: &str,
    ty: &str,
    components: usize,
) -> roxmltree::Node<'a, 'i> {
    let node = parent
        .children()
        .find(|n| n.has_tag_name("DataArray") && n.attribute("Name") == Some(name))
        .unwrap_or_else(|| panic!("no DataArray {name}"));
    assert_eq!(node.attribute("type"), Some(ty), "{name} type");
    let declared = node
        .attribute("NumberOfComponents")
        .map_or(1, |c| c.parse().unwrap());
    assert_eq!(declared, components, "{name} components");
    node
}

#[track_caller]
fn child<'a, 'i>(parent: roxmltree::Node<'a, 'i>, tag: &str) -> roxmltree::Node<'a, 'i> {
    parent
        .children()
        .find(|n| n.has_tag_name(tag))
        .unwrap_or_else(|| panic!("no <{tag}> in <{}>", parent.tag_name().name()))
}

#[track_caller]
fn read_vtu(path: &Path) -> Vtu {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let doc = roxmltree::Document::parse(&text)
        .unwrap_or_else(|e| panic!("{} is not XML: {e}", path.display()));
    let root = doc.root_element();
    assert!(root.has_tag_name("VTKFile"));
    assert_eq!(root.attribute("type"), Some("UnstructuredGrid"));
    assert_eq!(root.attribute("byte_order"), Some("LittleEndian"));
    assert_eq!(root.attribute("header_type"), Some("UInt64"));
    let grid = child(root, "UnstructuredGrid");
    let time_value = array(child(grid, "FieldData"), "TimeValue", "Float64", 1);
    assert_eq!(time_value.attribute("format"), Some("ascii"));
    let time: f64 = time_value.text().unwrap().trim().parse().unwrap();
    let piece = child(grid, "Piece");
    let points_n: usize = piece.attribute("NumberOfPoints").unwrap().parse().unwrap();
    let cells_n: usize = piece.attribute("NumberOfCells").unwrap().parse().unwrap();

    let point_data = child(piece, "PointData");
    let velocity = triples_of(f64s(&binary(array(point_data, "velocity", "Float64", 3))));
    let speed = f64s(&binary(array(point_data, "speed", "Float64", 1)));
    let cell_data = child(piece, "CellData");
    let kind = binary(array(cell_data, "kind", "UInt8", 1));
    let strain = f64s(&binary(array(cell_data, "strain", "Float64", 1)));
    let points_node = child(child(piece, "Points"), "DataArray");
    assert_eq!(points_node.attribute("type"), Some("Float64"));
    assert_eq!(points_node.attribute("NumberOfComponents"), Some("3"));
    let points = triples_of(f64s(&binary(points_node)));
    let cells_node = child(piece, "Cells");
    let connectivity = i64s(&binary(array(cells_node, "connectivity", "Int64", 1)));
    let offsets = i64s(&binary(array(cells_node, "offsets", "Int64", 1)));
    let types = binary(array(cells_node, "types", "UInt8", 1));

    assert_eq!(points.len(), points_n, "points");
    assert_eq!(velocity.len(), points_n, "velocity");
    assert_eq!(speed.len(), points_n, "speed");
    for len in [offsets.len(), types.len(), kind.len(), strain.len()] {
        assert_eq!(len, cells_n, "one value per cell");
    }
    assert_eq!(
        offsets.last().map_or(0, |&o| o as usize),
        connectivity.len()
    );
    let mut start = 0;
    let cells = offsets
        .iter()
        .zip(&types)
        .map(|(&end, &t)| {
            let c = connectivity[start..end as usize].to_vec();
            start = end as usize;
            (t, c)
        })
        .collect();
    Vtu {
        time,
        points,
        velocity,
        speed,
        cells,
        kind,
        strain,
    }
}

/// The (timestep, file) of every DataSet of a `.pvd`.
#[track_caller]
fn read_pvd(path: &Path) -> Vec<(f64, String)> {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let doc = roxmltree::Document::parse(&text).expect("the .pvd is XML");
    let root = doc.root_element();
    assert!(root.has_tag_name("VTKFile"));
    assert_eq!(root.attribute("type"), Some("Collection"));
    child(root, "Collection")
        .children()
        .filter(|n| n.is_element())
        .map(|n| {
            assert!(n.has_tag_name("DataSet"));
            (
                n.attribute("timestep").unwrap().parse().unwrap(),
                n.attribute("file").unwrap().to_owned(),
            )
        })
        .collect()
}

/// A PLY file read by the format's rules: a header of elements and typed properties, then a
/// little-endian binary body. Scalars come back as f64 (every type used fits), lists as
/// vectors.
#[derive(Debug)]
struct Ply {
    /// element → its properties' names, in order
    properties: HashMap<String, Vec<String>>,
    /// element → rows of values (a list property is its items in place, after its count)
    rows: HashMap<String, Vec<Vec<f64>>>,
}

impl Ply {
    fn column(&self, element: &str, property: &str) -> Vec<f64> {
        let at = self.properties[element]
            .iter()
            .position(|p| p == property)
            .unwrap_or_else(|| panic!("no property {property}"));
        self.rows[element].iter().map(|r| r[at]).collect()
    }
}

#[track_caller]
fn read_ply(path: &Path) -> Ply {
    let bytes = std::fs::read(path).unwrap();
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .expect("a PLY header")
        + end.len();
    let head = std::str::from_utf8(&bytes[..at]).expect("an ASCII header");
    let mut lines = head.lines();
    assert_eq!(lines.next(), Some("ply"));
    assert_eq!(lines.next(), Some("format binary_little_endian 1.0"));
    enum Prop {
        Scalar(String),
        List(String, String),
    }
    /// (name, count, properties)
    type Element = (String, usize, Vec<(String, Prop)>);
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["comment", ..] | ["end_header"] => {}
            ["element", name, count] => {
                elements.push((name.to_string(), count.parse().unwrap(), Vec::new()))
            }
            ["property", "list", count, item, name] => elements.last_mut().unwrap().2.push((
                name.to_string(),
                Prop::List(count.to_string(), item.to_string()),
            )),
            ["property", ty, name] => elements
                .last_mut()
                .unwrap()
                .2
                .push((name.to_string(), Prop::Scalar(ty.to_string()))),
            other => panic!("unexpected header line {other:?}"),
        }
    }
    let mut body = &bytes[at..];
    let mut take = |ty: &str| -> f64 {
        let size = match ty {
            "char" | "uchar" | "int8" | "uint8" => 1,
            "short" | "ushort" | "int16" | "uint16" => 2,
            "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
            "double" | "float64" => 8,
            other => panic!("unknown PLY type {other}"),
        };
        let (b, rest) = body.split_at(size);
        body = rest;
        match ty {
            "uchar" | "uint8" => b[0] as f64,
            "uint" | "uint32" => u32::from_le_bytes(b.try_into().unwrap()) as f64,
            "int" | "int32" => i32::from_le_bytes(b.try_into().unwrap()) as f64,
            "double" | "float64" => f64::from_le_bytes(b.try_into().unwrap()),
            other => panic!("type {other} is not expected here"),
        }
    };
    let mut ply = Ply {
        properties: HashMap::new(),
        rows: HashMap::new(),
    };
    for (name, count, props) in &elements {
        let mut rows = Vec::new();
        for _ in 0..*count {
            let mut row = Vec::new();
            for (_, p) in props {
                match p {
                    Prop::Scalar(ty) => row.push(take(ty)),
                    Prop::List(count_ty, item_ty) => {
                        let k = take(count_ty);
                        row.push(k);
                        for _ in 0..k as usize {
                            row.push(take(item_ty));
                        }
                    }
                }
            }
            rows.push(row);
        }
        ply.properties
            .insert(name.clone(), props.iter().map(|(n, _)| n.clone()).collect());
        ply.rows.insert(name.clone(), rows);
    }
    assert!(
        body.is_empty(),
        "{} bytes after the last element",
        body.len()
    );
    ply
}

// ---------------------------------------------------------------- helpers

fn scene() -> Cube {
    // dt and frame rate chosen so the times are not round decimals (as in formats.rs).
    Cube {
        integrator: "rk4",
        dt: 0.0007,
        duration: 0.03,
        frame_rate: 300.0,
        resolution: [3, 2, 4],
        ..Cube::default()
    }
}

/// Runs `softbody run scene --quiet ARGS` in the sandbox; returns the outcome.
fn run(sb: &Sandbox, scene: &Path, args: &[&str]) -> Outcome {
    let mut all = vec!["run", scene.to_str().unwrap(), "--quiet"];
    all.extend_from_slice(args);
    sb.run(&all)
}

/// The springs of the run, as the NPZ output lists them.
fn npz_springs(path: &Path) -> Vec<[i64; 2]> {
    let mut zip = zip::ZipArchive::new(std::fs::File::open(path).unwrap()).unwrap();
    let mut bytes = Vec::new();
    zip.by_name("springs.npy")
        .unwrap()
        .read_to_end(&mut bytes)
        .unwrap();
    let springs: Vec<u32> = npyz::NpyFile::new(&bytes[..]).unwrap().into_vec().unwrap();
    springs
        .chunks_exact(2)
        .map(|p| [p[0] as i64, p[1] as i64])
        .collect()
}

fn bits(v: &[[f64; 3]]) -> Vec<[u64; 3]> {
    v.iter().map(|p| p.map(f64::to_bits)).collect()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// The volume a closed triangle surface encloses (positive when its triangles turn outward
/// counter-clockwise): Σ a·(b×c)/6.
fn enclosed_volume(x: &[[f64; 3]], triangles: &[[i64; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| x[i as usize]);
            let cross = [
                b[1] * c[2] - b[2] * c[1],
                b[2] * c[0] - b[0] * c[2],
                b[0] * c[1] - b[1] * c[0],
            ];
            (a[0] * cross[0] + a[1] * cross[1] + a[2] * cross[2]) / 6.0
        })
        .sum()
}

/// Asserts that `triangles` form a closed, consistently oriented surface: every directed edge
/// once, and its reverse once.
#[track_caller]
fn assert_closed(triangles: &[[i64; 3]]) {
    let mut edges = HashMap::new();
    for t in triangles {
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    for (&(a, b), &count) in &edges {
        assert_eq!(count, 1, "edge {a}→{b} used {count} times");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}→{b} has no twin");
    }
}

/// Triangles on the outside of an nx × ny × nz lattice: two per boundary quad.
fn surface_triangles([nx, ny, nz]: [u32; 3]) -> usize {
    let (x, y, z) = (nx as usize - 1, ny as usize - 1, nz as usize - 1);
    4 * (x * y + y * z + z * x)
}

/// The particles on the outside of an nx × ny × nz lattice, ascending (particle (i, j, k) is
/// i + nx·(j + ny·k)).
fn surface_particles([nx, ny, nz]: [u32; 3]) -> Vec<i64> {
    let mut out = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1 {
                    out.push((i + nx * (j + ny * k)) as i64);
                }
            }
        }
    }
    out
}

/// Names in `dir` that are staging leftovers.
fn leftovers(dir: &Path) -> Vec<String> {
    entries(dir)
        .into_iter()
        .filter(|n| n.starts_with(".softbody-"))
        .collect()
}

// ---------------------------------------------------------------- VTK

#[test]
fn vtk_series_holds_the_jsonl_frames_springs_strains_and_surface() {
    let cube = scene();
    let n = cube.particles();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    run(&sb, &path, &["--out", "f.jsonl"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--out", "f.npz"]).expect_status(EXIT_OK);
    // The format follows the .pvd extension.
    run(&sb, &path, &["--out", "f.pvd"]).expect_status(EXIT_OK);
    assert_eq!(
        entries(sb.path()),
        ["f", "f.jsonl", "f.npz", "f.pvd", "s.toml"]
    );

    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    let springs = npz_springs(&sb.path().join("f.npz"));
    let pvd = read_pvd(&sb.path().join("f.pvd"));
    assert_eq!(pvd.len(), jsonl.frames.len());
    assert_eq!(
        pvd.len(),
        frame_schedule(cube.dt, cube.duration, cube.frame_rate).len()
    );
    let names: Vec<String> = (0..pvd.len()).map(|k| format!("f_{k:06}.vtu")).collect();
    assert_eq!(entries(&sb.path().join("f")), names, "one .vtu per frame");

    let x0 = triples(&jsonl.frames[0]["positions"]);
    let rest: Vec<f64> = springs
        .iter()
        .map(|&[a, b]| norm(sub(x0[a as usize], x0[b as usize])))
        .collect();
    let t = surface_triangles(cube.resolution);
    for (k, ((timestep, file), frame)) in pvd.iter().zip(&jsonl.frames).enumerate() {
        assert_eq!(file, &format!("f/{}", names[k]), "pvd entry {k}");
        let time = f64_of(&frame["time"]);
        assert_eq!(timestep.to_bits(), time.to_bits(), "frame {k} timestep");
        let vtu = read_vtu(&sb.path().join(file));
        assert_eq!(vtu.time.to_bits(), time.to_bits(), "frame {k} TimeValue");

        let x = triples(&frame["positions"]);
        let v = triples(&frame["velocities"]);
        assert_eq!(vtu.points.len(), n);
        assert!(bits(&vtu.points) == bits(&x), "frame {k}: points differ");
        assert!(
            bits(&vtu.velocity) == bits(&v),
            "frame {k}: velocities differ"
        );
        for (i, (&s, v)) in vtu.speed.iter().zip(&v).enumerate() {
            assert!(
                (s - norm(*v)).abs() <= 1e-15 * norm(*v),
                "frame {k} speed {i}"
            );
        }

        // Cells: the springs as lines in the NPZ's order, then the surface triangles.
        assert_eq!(vtu.cells.len(), springs.len() + t);
        assert_eq!(vtu.lines(), springs, "frame {k}: lines are the springs");
        let triangles = vtu.triangles();
        assert_eq!(triangles.len(), t);
        assert!(
            vtu.cells[..springs.len()].iter().all(|(ty, _)| *ty == 3)
                && vtu.cells[springs.len()..].iter().all(|(ty, _)| *ty == 5),
            "lines first, then triangles"
        );
        let kinds: Vec<u8> = (0..springs.len())
            .map(|_| 0)
            .chain((0..t).map(|_| 1))
            .collect();
        assert_eq!(vtu.kind, kinds);
        assert_closed(&triangles);
        let mut used: Vec<i64> = triangles.iter().flatten().copied().collect();
        used.sort_unstable();
        used.dedup();
        assert_eq!(used, surface_particles(cube.resolution));

        for (s, (&[a, b], &r)) in springs.iter().zip(&rest).enumerate() {
            let expected = (norm(sub(x[a as usize], x[b as usize])) - r) / r;
            assert!(
                (vtu.strain[s] - expected).abs() <= 1e-12,
                "frame {k} spring {s}: strain {} vs {expected}",
                vtu.strain[s]
            );
        }
        assert!(vtu.strain[springs.len()..].iter().all(|s| s.is_nan()));
        if k == 0 {
            // The cube starts at rest length, 1 m on a side, triangles turning outward.
            assert!(vtu.strain[..springs.len()].iter().all(|s| s.abs() < 1e-12));
            let volume = enclosed_volume(&x, &triangles);
            assert!((volume - 1.0).abs() < 1e-12, "enclosed volume {volume}");
        }
    }
}

// ---------------------------------------------------------------- PLY and OBJ

#[test]
fn ply_series_holds_the_surface_of_the_jsonl_frames() {
    let cube = scene();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    run(&sb, &path, &["--out", "f.jsonl"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--out", "f.pvd"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--format", "ply", "--out", "meshes"]).expect_status(EXIT_OK);
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    let frames = jsonl.frames.len();
    let names: Vec<String> = (0..frames).map(|k| format!("meshes_{k:06}.ply")).collect();
    assert_eq!(entries(&sb.path().join("meshes")), names);
    let triangles = read_vtu(&sb.path().join("f/f_000000.vtu")).triangles();
    let surface = surface_particles(cube.resolution);

    for (k, frame) in jsonl.frames.iter().enumerate() {
        let ply = read_ply(&sb.path().join("meshes").join(&names[k]));
        assert_eq!(
            ply.properties["vertex"],
            ["x", "y", "z", "vx", "vy", "vz", "particle"]
        );
        assert_eq!(ply.properties["face"], ["vertex_indices"]);
        let particle: Vec<i64> = ply
            .column("vertex", "particle")
            .iter()
            .map(|&p| p as i64)
            .collect();
        assert_eq!(
            particle, surface,
            "frame {k}: the surface particles, ascending"
        );
        let x = triples(&frame["positions"]);
        let v = triples(&frame["velocities"]);
        let column = |name: &str| ply.column("vertex", name);
        let (px, py, pz) = (column("x"), column("y"), column("z"));
        let (vx, vy, vz) = (column("vx"), column("vy"), column("vz"));
        for (row, &p) in particle.iter().enumerate() {
            let p = p as usize;
            assert_eq!(
                [px[row], py[row], pz[row]].map(f64::to_bits),
                x[p].map(f64::to_bits),
                "frame {k} vertex {row} position"
            );
            assert_eq!(
                [vx[row], vy[row], vz[row]].map(f64::to_bits),
                v[p].map(f64::to_bits),
                "frame {k} vertex {row} velocity"
            );
        }
        // Faces are the VTK triangles, through the vertex → particle map.
        let faces: Vec<[i64; 3]> = ply.rows["face"]
            .iter()
            .map(|r| {
                assert_eq!(r[0], 3.0, "a triangle");
                [r[1], r[2], r[3]].map(|i| particle[i as usize])
            })
            .collect();
        assert_eq!(faces, triangles, "frame {k} faces");
    }
}

#[test]
fn obj_series_holds_the_surface_of_the_jsonl_frames() {
    let cube = scene();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    run(&sb, &path, &["--out", "f.jsonl"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--out", "f.pvd"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--format", "obj", "--out", "meshes"]).expect_status(EXIT_OK);
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    let names: Vec<String> = (0..jsonl.frames.len())
        .map(|k| format!("meshes_{k:06}.obj"))
        .collect();
    assert_eq!(entries(&sb.path().join("meshes")), names);
    let triangles = read_vtu(&sb.path().join("f/f_000000.vtu")).triangles();

    for (k, frame) in jsonl.frames.iter().enumerate() {
        let file = sb.path().join("meshes").join(&names[k]);
        let (models, _) = tobj::load_obj(&file, &tobj::LoadOptions::default())
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        assert_eq!(models.len(), 1, "one mesh");
        let mesh = &models[0].mesh;
        assert_eq!(mesh.indices.len(), 3 * triangles.len(), "frame {k} faces");
        // tobj renumbers vertices as faces first use them: compare corner by corner.
        let x = triples(&frame["positions"]);
        let corner = |i: u32| {
            let i = 3 * i as usize;
            [
                mesh.positions[i],
                mesh.positions[i + 1],
                mesh.positions[i + 2],
            ]
        };
        for (f, t) in triangles.iter().enumerate() {
            for c in 0..3 {
                assert_eq!(
                    corner(mesh.indices[3 * f + c]).map(f64::to_bits),
                    x[t[c] as usize].map(f64::to_bits),
                    "frame {k} face {f} corner {c}"
                );
            }
        }
        let surface = surface_particles(cube.resolution);
        assert_eq!(
            mesh.positions.len(),
            3 * surface.len(),
            "surface vertices only"
        );
    }
}

#[test]
fn a_particle_set_body_is_points_in_the_meshes_and_has_no_triangles() {
    let sb = Sandbox::new();
    let cube = Cube {
        resolution: [2, 3, 2],
        ..Cube::default()
    };
    let text = cube.toml()
        + "\n[[body]]\nname = \"pair\"\nkind = \"particles\"\n\
           positions = [[3.0, 1.0, 0.0], [4.0, 1.0, 0.0], [5.0, 1.0, 0.0]]\n\
           masses = [0.1, 0.2, 0.3]\n\
           springs = [{ a = 0, b = 1, stiffness = 10.0 }]\n";
    let path = sb.write("two.toml", &text);
    run(&sb, &path, &["--out", "f.pvd"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--format", "ply", "--out", "p"]).expect_status(EXIT_OK);
    let vtu = read_vtu(&sb.path().join("f/f_000000.vtu"));
    assert_eq!(vtu.points.len(), 12 + 3);
    let triangles = vtu.triangles();
    assert_eq!(triangles.len(), surface_triangles(cube.resolution));
    assert!(
        triangles.iter().flatten().all(|&i| i < 12),
        "no triangle on the set"
    );
    assert!(
        vtu.lines().contains(&[12, 13]),
        "the set's spring is a line"
    );
    // In the PLY every particle of the 2×3×2 cube is on its surface, and the set's three
    // particles follow as lone vertices.
    let ply = read_ply(&sb.path().join("p/p_000000.ply"));
    let particles = ply.column("vertex", "particle");
    assert_eq!(particles, (0..15).map(f64::from).collect::<Vec<_>>());
    assert_eq!(ply.rows["face"].len(), triangles.len());
    assert_eq!(ply.column("vertex", "x")[14], 5.0);
}

// ---------------------------------------------------------------- placement

#[test]
fn unstable_run_leaves_series_of_exactly_the_frames_written() {
    let cube = Cube::unstable();
    let planned = frame_schedule(cube.dt, cube.duration, cube.frame_rate).len();
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &cube.toml());
    let outcomes = [
        run(&sb, &path, &["--out", "f.jsonl"]),
        run(&sb, &path, &["--out", "f.pvd"]),
        run(&sb, &path, &["--format", "ply", "--out", "p"]),
        run(&sb, &path, &["--format", "obj", "--out", "o"]),
    ];
    for o in &outcomes {
        o.expect_status(EXIT_UNSTABLE);
    }
    assert!(
        outcomes[1]
            .stderr
            .contains("the frames before it are in f.pvd"),
        "{}",
        outcomes[1].stderr
    );
    assert_eq!(
        entries(sb.path()),
        ["f", "f.jsonl", "f.pvd", "o", "p", "s.toml"],
        "everything in place, nothing staged left over"
    );
    let jsonl = read_jsonl(&sb.path().join("f.jsonl"));
    let frames = jsonl.frames.len();
    assert!(frames > 0 && frames < planned, "{frames} of {planned}");

    let pvd = read_pvd(&sb.path().join("f.pvd"));
    assert_eq!(pvd.len(), frames, "the .pvd lists the frames written");
    let vtus: Vec<String> = (0..frames).map(|k| format!("f_{k:06}.vtu")).collect();
    assert_eq!(entries(&sb.path().join("f")), vtus);
    let x0 = triples(&jsonl.frames[0]["positions"]);
    for ((timestep, file), frame) in pvd.iter().zip(&jsonl.frames) {
        let vtu = read_vtu(&sb.path().join(file));
        assert_eq!(timestep.to_bits(), f64_of(&frame["time"]).to_bits());
        let x = triples(&frame["positions"]);
        assert!(bits(&vtu.points) == bits(&x));
        // Strains against the rest lengths of frame 0 (the cube starts unstretched).
        for (&[a, b], s) in vtu.lines().iter().zip(&vtu.strain) {
            let (a, b) = (a as usize, b as usize);
            let rest = norm(sub(x0[a], x0[b]));
            let expected = (norm(sub(x[a], x[b])) - rest) / rest;
            assert!((s - expected).abs() <= 1e-12 * expected.abs().max(1.0));
        }
    }
    // The last frame before the instability is visibly deformed (strains of 0.5 %).
    let last = read_vtu(&sb.path().join(&pvd[frames - 1].1));
    let worst = last
        .strain
        .iter()
        .filter(|s| !s.is_nan())
        .fold(0.0f64, |m, s| m.max(s.abs()));
    assert!(worst > 1e-3, "largest strain {worst}");
    let plys: Vec<String> = (0..frames).map(|k| format!("p_{k:06}.ply")).collect();
    assert_eq!(entries(&sb.path().join("p")), plys);
    let last = read_ply(&sb.path().join("p").join(plys.last().unwrap()));
    assert_eq!(
        last.column("vertex", "x")[0].to_bits(),
        triples(&jsonl.frames[frames - 1]["positions"])[0][0].to_bits()
    );
    let objs: Vec<String> = (0..frames).map(|k| format!("o_{k:06}.obj")).collect();
    assert_eq!(entries(&sb.path().join("o")), objs);
    let last_obj = sb.path().join("o").join(objs.last().unwrap());
    let (models, _) =
        tobj::load_obj(&last_obj, &tobj::LoadOptions::default()).expect("a valid OBJ");
    assert_eq!(models.len(), 1);
}

#[test]
fn series_to_standard_output_is_refused_with_status_2() {
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &Cube::default().toml());
    for format in ["vtk", "ply", "obj"] {
        let o = run(&sb, &path, &["--format", format, "--out", "-"]);
        o.expect_status(EXIT_BAD_INPUT);
        assert!(o.stdout.is_empty(), "{format}: nothing on standard output");
        assert!(
            o.stderr
                .contains(&format!("--format {format} writes a series of files"))
                && o.stderr.contains("cannot go to standard output"),
            "{format}: {}",
            o.stderr
        );
    }
    // The .pvd extension alone does not make `-` usable either, and a .pvd name is needed.
    run(&sb, &path, &["--format", "vtk", "--out", "frames"]).expect_status(EXIT_BAD_INPUT);
    assert_eq!(entries(sb.path()), ["s.toml"], "nothing created");
}

#[test]
fn unwritable_destination_exits_with_status_1_and_leaves_nothing() {
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &Cube::default().toml());
    let blocker = sb.write("blocker", "a file, not a directory\n");
    for (format, out) in [
        ("vtk", blocker.join("f.pvd")),
        ("ply", blocker.join("p")),
        ("obj", blocker.join("o")),
    ] {
        let o = run(
            &sb,
            &path,
            &["--format", format, "--out", out.to_str().unwrap()],
        );
        o.expect_status(EXIT_OUTPUT);
        assert!(o.stderr.contains("cannot create") && o.stderr.contains("blocker"));
    }
    // A .pvd name that is taken by a directory.
    let taken = sb.mkdir("taken.pvd");
    let o = run(&sb, &path, &["--out", taken.to_str().unwrap()]);
    o.expect_status(EXIT_OUTPUT);
    assert!(o.stderr.contains("taken.pvd"), "{}", o.stderr);
    assert_eq!(entries(sb.path()), ["blocker", "s.toml", "taken.pvd"]);
    assert!(leftovers(sb.path()).is_empty());
}

#[test]
fn a_directory_that_is_not_a_series_is_not_replaced() {
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &Cube::default().toml());
    let precious = sb.write("meshes/thesis.tex", "precious\n");
    let o = run(&sb, &path, &["--format", "obj", "--out", "meshes"]);
    o.expect_status(EXIT_OUTPUT);
    assert!(
        o.stderr.contains("refusing to replace") && o.stderr.contains("thesis.tex"),
        "{}",
        o.stderr
    );
    assert_eq!(std::fs::read_to_string(&precious).unwrap(), "precious\n");
    assert_eq!(entries(&sb.path().join("meshes")), ["thesis.tex"]);
    assert_eq!(entries(sb.path()), ["meshes", "s.toml"]);
}

#[test]
fn default_paths_and_replacing_an_earlier_series() {
    let cube = Cube::default();
    let sb = Sandbox::new();
    let path = sb.write("jelly.toml", &cube.toml());
    let frames = frame_schedule(cube.dt, cube.duration, cube.frame_rate).len();
    run(&sb, &path, &["--format", "vtk"]).expect_status(EXIT_OK);
    let out = sb.path().join("out");
    assert_eq!(entries(&out), ["jelly", "jelly.pvd"]);
    assert_eq!(entries(&out.join("jelly")).len(), frames);
    assert_eq!(read_pvd(&out.join("jelly.pvd")).len(), frames);

    // A run with other settings gets a name of its own: the scene's own run stays.
    run(&sb, &path, &["--format", "vtk", "--duration", "0.02"]).expect_status(EXIT_OK);
    assert_eq!(
        entries(&out),
        ["jelly", "jelly-0.02s", "jelly-0.02s.pvd", "jelly.pvd"]
    );
    assert_eq!(entries(&out.join("jelly")).len(), frames);

    // A shorter run to the same name replaces the series whole: no frame of the old one is
    // left.
    let pvd = out.join("jelly.pvd");
    run(
        &sb,
        &path,
        &["--out", pvd.to_str().unwrap(), "--duration", "0.02"],
    )
    .expect_status(EXIT_OK);
    let shorter = frame_schedule(cube.dt, 0.02, cube.frame_rate).len();
    assert!(shorter < frames);
    assert_eq!(entries(&out.join("jelly")).len(), shorter);
    assert_eq!(read_pvd(&out.join("jelly.pvd")).len(), shorter);
    assert!(leftovers(&out).is_empty());

    // PLY and OBJ default to directories of their own, beside VTK's frames: each format of
    // the same scene runs without an --out, and the .vtu files the .pvd names stay.
    run(&sb, &path, &["--format", "ply"]).expect_status(EXIT_OK);
    run(&sb, &path, &["--format", "obj"]).expect_status(EXIT_OK);
    assert_eq!(
        entries(&out),
        [
            "jelly",
            "jelly-0.02s",
            "jelly-0.02s.pvd",
            "jelly-obj",
            "jelly-ply",
            "jelly.pvd"
        ]
    );
    assert_eq!(entries(&out.join("jelly")).len(), shorter);
    for ext in ["ply", "obj"] {
        let names: Vec<String> = (0..frames)
            .map(|k| format!("jelly-{ext}_{k:06}.{ext}"))
            .collect();
        assert_eq!(entries(&out.join(format!("jelly-{ext}"))), names);
    }
    // Run again: the directory of OBJ frames is replaced.
    run(&sb, &path, &["--format", "obj"]).expect_status(EXIT_OK);
    assert_eq!(entries(&out.join("jelly-obj")).len(), frames);
    assert!(leftovers(&out).is_empty());

    // An --out that names another series' directory is still refused.
    let o = run(&sb, &path, &["--format", "ply", "--out", "out/jelly"]);
    o.expect_status(EXIT_OUTPUT);
    assert!(o.stderr.contains("jelly_000000.vtu"), "{}", o.stderr);
    assert_eq!(entries(&out.join("jelly")).len(), shorter);
}

#[cfg(unix)]
#[test]
fn series_have_the_permissions_of_ordinary_files_and_directories() {
    use std::os::unix::fs::PermissionsExt;
    let sb = Sandbox::new();
    let path = sb.write("s.toml", &Cube::default().toml());
    run(&sb, &path, &["--out", "f.pvd"]).expect_status(EXIT_OK);
    let mode = |p: PathBuf| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    let file = mode(sb.write("reference.txt", "x"));
    let dir = mode(sb.mkdir("reference"));
    assert_eq!(mode(sb.path().join("f.pvd")), file);
    assert_eq!(mode(sb.path().join("f/f_000000.vtu")), file);
    assert_eq!(mode(sb.path().join("f")), dir);
}
