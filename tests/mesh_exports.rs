//! The exports of a mesh body give the artist's own mesh back: every frame of the OBJ, PLY and
//! VTK series, read back from the files, has the input OBJ's vertex count and its face list
//! (same faces, same order, same winding); at frame 0 the vertices are the input's after the
//! scene's transform (to 1e-12 m), later ones have moved.

use std::path::{Path, PathBuf};

use glam::DVec3;
use softbody::output::{FrameSink, ObjSink, PlySink, VtkSink};
use softbody::scene::{BodyShape, MeshBody, TriangleMesh};
use softbody::{Backend, Scene};

/// A star prism dropped 3 cm onto the ground, 0.2 s at 30 frames/s: 7 frames, the last after
/// it landed.
fn scene(dir: &Path) -> (Scene, TriangleMesh) {
    let star = TriangleMesh::star_prism(5, 0.3, 0.13, 0.1);
    std::fs::write(dir.join("star.obj"), star.to_obj("a star prism")).unwrap();
    let text = "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 5e-4\nduration = 0.2\n\
                frame_rate = 30.0\n\n[[body]]\nkind = \"mesh\"\nfile = \"star.obj\"\n\
                cell = 0.04\ncenter = [0.0, 0.1, 0.0]\nrotation = [0.0, 30.0, 0.0]\n\
                scale = 1.2\nmass = 1.0\nstructural = { stiffness = 30.0, damping = 0.05 }\n\
                shear = { stiffness = 30.0, damping = 0.05 }\n\n\
                [[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n";
    let path = dir.join("star.toml");
    std::fs::write(&path, text).unwrap();
    let scene = Scene::from_file(&path).unwrap();
    // The mesh as the scene loaded it (the file's own numbers).
    let BodyShape::Mesh(m) = &scene.bodies[0].shape else {
        panic!("a mesh body")
    };
    let input = m.voxels.mesh().clone();
    assert_eq!(input.vertices.len(), star.vertices.len());
    (scene, input)
}

fn run(scene: &Scene, sink: &mut dyn FrameSink) -> u64 {
    let mut solver = softbody::open(scene, Backend::Cpu, Some(1)).unwrap();
    let summary = softbody::run::run(solver.as_mut(), None, sink, &mut |_, _| {}).unwrap();
    sink.finish().unwrap();
    summary.frames
}

fn frames(dir: &Path, ext: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == ext))
        .collect();
    files.sort();
    files
}

/// Checks one frame's vertices against the input: frame 0 at the transformed input, later
/// frames finite and (the last) moved.
fn check_vertices(frame: usize, x: &[DVec3], body: &MeshBody, input: &TriangleMesh) -> f64 {
    assert_eq!(x.len(), input.vertices.len(), "frame {frame}: vertex count");
    assert!(x.iter().all(|p| p.is_finite()));
    let off = x
        .iter()
        .zip(&input.vertices)
        .map(|(p, q)| (*p - body.place(*q)).length())
        .fold(0.0, f64::max);
    if frame == 0 {
        assert!(off <= 1e-12, "frame 0 is {off:e} m off the input");
    }
    off
}

fn mesh_body(scene: &Scene) -> &MeshBody {
    match &scene.bodies[0].shape {
        BodyShape::Mesh(m) => m,
        _ => unreachable!(),
    }
}

#[test]
fn obj_frames_are_the_input_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, input) = scene(dir.path());
    let out = dir.path().join("obj");
    std::fs::create_dir(&out).unwrap();
    let written = run(&scene, &mut ObjSink::new(out.clone(), "s".into()));
    let files = frames(&out, "obj");
    assert_eq!(files.len() as u64, written);
    assert_eq!(written, 7);
    let mut last = 0.0;
    for (k, file) in files.iter().enumerate() {
        let text = std::fs::read_to_string(file).unwrap();
        let mut x = Vec::new();
        let mut faces = Vec::new();
        for line in text.lines() {
            let mut w = line.split_whitespace();
            match w.next() {
                Some("v") => {
                    let c: Vec<f64> = w.map(|s| s.parse().unwrap()).collect();
                    x.push(DVec3::new(c[0], c[1], c[2]));
                }
                Some("f") => {
                    let f: Vec<u32> = w.map(|s| s.parse::<u32>().unwrap() - 1).collect();
                    faces.push([f[0], f[1], f[2]]);
                }
                _ => {}
            }
        }
        last = check_vertices(k, &x, mesh_body(&scene), &input);
        assert_eq!(faces, input.triangles, "frame {k}: faces");
    }
    assert!(last > 0.01, "the last frame has moved ({last} m)");
}

#[test]
fn ply_frames_are_the_input_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, input) = scene(dir.path());
    let out = dir.path().join("ply");
    std::fs::create_dir(&out).unwrap();
    let written = run(&scene, &mut PlySink::new(out.clone(), "s".into()));
    let files = frames(&out, "ply");
    assert_eq!(files.len() as u64, written);
    let v = input.vertices.len();
    for (k, file) in files.iter().enumerate() {
        let bytes = std::fs::read(file).unwrap();
        let end = b"end_header\n";
        let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let head = std::str::from_utf8(&bytes[..at]).unwrap();
        assert!(head.contains(&format!("element vertex {v}\n")), "{head}");
        let f = input.triangles.len();
        assert!(head.contains(&format!("element face {f}\n")), "{head}");
        let body = &bytes[at..];
        assert_eq!(body.len(), v * 52 + f * 13);
        let f64_at = |o: usize| f64::from_le_bytes(body[o..o + 8].try_into().unwrap());
        let u32_at = |o: usize| u32::from_le_bytes(body[o..o + 4].try_into().unwrap());
        let x: Vec<DVec3> = (0..v)
            .map(|i| DVec3::new(f64_at(52 * i), f64_at(52 * i + 8), f64_at(52 * i + 16)))
            .collect();
        check_vertices(k, &x, mesh_body(&scene), &input);
        assert!(
            (0..v).all(|i| u32_at(52 * i + 48) == u32::MAX),
            "no particle numbers"
        );
        let faces: Vec<[u32; 3]> = (0..f)
            .map(|t| {
                let o = 52 * v + 13 * t;
                assert_eq!(body[o], 3);
                [u32_at(o + 1), u32_at(o + 5), u32_at(o + 9)]
            })
            .collect();
        assert_eq!(faces, input.triangles, "frame {k}: faces");
    }
}

/// Decodes RFC 4648 base64 (padded).
fn base64(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let mut out = Vec::new();
    for chunk in text.as_bytes().chunks(4) {
        let pads = chunk.iter().filter(|&&c| c == b'=').count();
        let n = chunk.iter().fold(0u32, |n, &c| {
            (n << 6) | u32::from(if c == b'=' { 0 } else { value(c) })
        });
        out.extend(&n.to_be_bytes()[1..4 - pads]);
    }
    out
}

/// The values of the `<DataArray ... Name="name" ...>` of `xml`, without the byte count.
fn data_array(xml: &str, name: &str) -> Vec<u8> {
    let at = xml.find(&format!("Name=\"{name}\"")).unwrap();
    let start = at + xml[at..].find('>').unwrap() + 1;
    let end = start + xml[start..].find('<').unwrap();
    base64(&xml[start..end])[8..].to_vec()
}

#[test]
fn vtk_frames_carry_the_input_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, input) = scene(dir.path());
    let out = dir.path().join("vtk");
    std::fs::create_dir(&out).unwrap();
    let pvd = Box::new(std::fs::File::create(dir.path().join("s.pvd")).unwrap());
    let written = run(
        &scene,
        &mut VtkSink::new(out.clone(), "s".into(), "vtk/".into(), pvd),
    );
    let files = frames(&out, "vtu");
    assert_eq!(files.len() as u64, written);
    let (model, _) = softbody::Model::build(&scene);
    let n = model.len();
    let v = input.vertices.len();
    for (k, file) in files.iter().enumerate() {
        let xml = std::fs::read_to_string(file).unwrap();
        let cells = model.springs().len() + input.triangles.len();
        assert!(
            xml.contains(&format!(
                "NumberOfPoints=\"{}\" NumberOfCells=\"{cells}\"",
                n + v
            )),
            "frame {k}"
        );
        let points: Vec<f64> = data_array(&xml, "Points")
            .chunks(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let x: Vec<DVec3> = points[3 * n..]
            .chunks(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect();
        check_vertices(k, &x, mesh_body(&scene), &input);
        let connectivity: Vec<i64> = data_array(&xml, "connectivity")
            .chunks(8)
            .map(|b| i64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let kind = data_array(&xml, "kind");
        assert_eq!(kind.len(), cells);
        assert!(kind[model.springs().len()..].iter().all(|&k| k == 1));
        let faces: Vec<[u32; 3]> = connectivity[2 * model.springs().len()..]
            .chunks(3)
            .map(|t| [0, 1, 2].map(|c| (t[c] - n as i64) as u32))
            .collect();
        assert_eq!(faces, input.triangles, "frame {k}: faces");
    }
}
