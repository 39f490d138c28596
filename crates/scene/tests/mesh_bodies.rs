//! Mesh bodies (`kind = "mesh"`) from scene files: the embedded surface at rest, the lattice
//! volume's convergence, the box mesh against the cuboid, springs across gaps, and the located
//! errors of bad input.

use std::path::{Path, PathBuf};

use glam::DVec3;
use softbody_scene::topology;
use softbody_scene::voxel::{LatticeSize, Voxels, enclosed_volume};
use softbody_scene::{BodyShape, MeshBody, Model, Scene, SceneError, TriangleMesh};

/// Writes `mesh` as `name` in `dir` and returns its path.
fn write_obj(dir: &Path, name: &str, mesh: &TriangleMesh) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, mesh.to_obj("test mesh")).unwrap();
    path
}

/// A scene of one mesh body with `keys` (TOML lines), no terrain, saved beside the meshes.
fn scene_text(keys: &str) -> String {
    format!(
        "[simulation]\ndt = 0.001\nduration = 0.01\n\n[[body]]\nname = \"m\"\nkind = \"mesh\"\n\
         {keys}\n"
    )
}

fn load(dir: &Path, text: &str) -> Result<Scene, SceneError> {
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    Scene::from_file(&path)
}

/// At frame 0 every vertex of the embedded surface is the input vertex after the scene's
/// transform (scale, rotation, translation of the bounding-box centre onto `center`), to
/// 1e-12 m: the trilinear weights reproduce any affine map of the lattice.
#[test]
fn embedded_surface_is_the_input_mesh_at_frame_0() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(
        dir.path(),
        "torus.obj",
        &TriangleMesh::torus(0.5, 0.2, 48, 24),
    );
    write_obj(
        dir.path(),
        "star.obj",
        &TriangleMesh::star_prism(5, 0.5, 0.22, 0.15),
    );
    let text = scene_text(
        "file = \"torus.obj\"\ncell = 0.06\ncenter = [1.0, 2.0, -3.0]\n\
         rotation = [20.0, 35.0, -50.0]\nscale = [1.2, 0.8, 1.0]\nmass = 2.0\n\
         structural = { stiffness = 100.0 }\n\n\
         [[body]]\nname = \"star\"\nkind = \"mesh\"\nfile = \"star.obj\"\nresolution = 9\n\
         center = [0.0, 0.5, 0.0]\nrotation = [90.0, 0.0, 10.0]\nscale = 1.5\ndensity = 1000.0\n",
    );
    let scene = load(dir.path(), &text).unwrap();
    let (model, state) = Model::build(&scene);
    let surface = model.embedded.apply(&state.x);
    assert_eq!(model.embedded.meshes.len(), 2);
    assert!(
        model.surface.is_empty(),
        "mesh bodies show their mesh, not the lattice"
    );
    let mut worst = 0.0f64;
    for (b, mesh) in model.embedded.meshes.iter().enumerate() {
        let BodyShape::Mesh(m) = &scene.bodies[b].shape else {
            panic!("body {b} is a mesh body")
        };
        let input = m.voxels.mesh();
        assert_eq!(mesh.vertices as usize, input.vertices.len());
        let first = mesh.first_vertex as usize;
        for (k, &p) in input.vertices.iter().enumerate() {
            worst = worst.max((surface[first + k] - m.place(p)).length());
        }
        let tris = &model.embedded.triangles
            [mesh.first_triangle as usize..(mesh.first_triangle + mesh.triangles) as usize];
        let back: Vec<[u32; 3]> = tris
            .iter()
            .map(|t| t.map(|i| i - mesh.first_vertex))
            .collect();
        assert_eq!(back, input.triangles, "the input's faces, in its order");
    }
    println!("largest distance from the transformed input: {worst:.3e} m");
    assert!(worst <= 1e-12, "{worst:e}");
}

/// A Blender-style cube (`tests/data/blender-cube.obj`: 8 corners listed out of the faces'
/// order, `vt`/`vn` corners, and a ninth vertex 1 m above the top that no face uses) exports
/// its nine vertices in the file's order: at frame 0 vertex i is the file's vertex i placed,
/// to 1e-12 m. The unused vertex shapes nothing: the lattice is the cube's alone (125
/// particles at h = ¼, the same positions as the unit cube's), and the vertex rides on the
/// kept cell nearest it (the first of four equally near in lattice order, x, y ∈ [¼, ½],
/// z ∈ [¾, 1]), its trilinear weights extended beyond the cell: −4 on the corner (½, ½, ¾)
/// below it and 5 on (½, ½, 1), the line through those two particles.
#[test]
fn mesh_vertices_come_back_in_the_files_order() {
    let dir = tempfile::tempdir().unwrap();
    let blender = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/blender-cube.obj");
    std::fs::copy(&blender, dir.path().join("blender.obj")).unwrap();
    write_obj(
        dir.path(),
        "cube.obj",
        &TriangleMesh::cube(DVec3::ZERO, 1.0),
    );
    let keys = "cell = 0.25\nmass = 1.0\ncenter = [0.5, 0.5, 0.5]\n\
                structural = { stiffness = 100.0 }\n";
    let scene = load(
        dir.path(),
        &scene_text(&format!("file = \"blender.obj\"\n{keys}")),
    )
    .unwrap();
    let cube = load(
        dir.path(),
        &scene_text(&format!("file = \"cube.obj\"\n{keys}")),
    )
    .unwrap();
    let (model, state) = Model::build(&scene);
    let (cube_model, cube_state) = Model::build(&cube);
    assert_eq!(model.len(), 125);
    assert_eq!(
        state.x, cube_state.x,
        "the unused vertex leaves the lattice as it is"
    );
    assert_eq!(model.springs().len(), cube_model.springs().len());

    let file: Vec<DVec3> = [
        [1., 1., 0.],
        [1., 0., 0.],
        [1., 1., 1.],
        [1., 0., 1.],
        [0., 1., 0.],
        [0., 0., 0.],
        [0., 1., 1.],
        [0., 0., 1.],
        [0.5, 0.5, 2.],
    ]
    .map(DVec3::from)
    .to_vec();
    let surface = model.embedded.apply(&state.x);
    assert_eq!(surface.len(), 9);
    for (i, (x, p)) in surface.iter().zip(&file).enumerate() {
        assert!(
            (*x - *p).length() <= 1e-12,
            "vertex {i}: {x} is not the file's {p}"
        );
    }
    assert_eq!(model.embedded.triangles.len(), 12);
    assert_eq!(model.embedded.triangles[0], [4, 6, 2]);

    let at = |p: [f64; 3]| {
        (state.x.iter().position(|x| *x == DVec3::from(p))).expect("a particle there") as u32
    };
    let (corners, weights) = (model.embedded.corners[8], model.embedded.weights[8]);
    let used: Vec<(u32, f64)> = (0..8)
        .filter(|&c| weights[c] != 0.0)
        .map(|c| (corners[c], weights[c]))
        .collect();
    assert_eq!(
        used,
        [(at([0.5, 0.5, 0.75]), -4.0), (at([0.5, 0.5, 1.0]), 5.0)]
    );
}

/// A mesh body and a mesh terrain name their OBJ file by the same keys: `file` or `path`,
/// either on either (the scenes use `file` on bodies and `path` on terrain), and not both.
#[test]
fn file_and_path_name_the_obj_file_of_bodies_and_terrain() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_obj(d, "cube.obj", &TriangleMesh::cube(DVec3::ZERO, 1.0));
    let with = |body: &str, terrain: &str| {
        load(
            d,
            &scene_text(&format!(
                "{body} = \"cube.obj\"\nmass = 1.0\ncell = 0.5\n\n\
                 [[terrain]]\nkind = \"mesh\"\n{terrain} = \"cube.obj\"\n"
            )),
        )
    };
    let scene = with("file", "path").unwrap();
    assert_eq!(scene.bodies[0].particle_count(), 27);
    assert_eq!(with("path", "file").unwrap(), scene);
    let e = load(
        d,
        &scene_text("file = \"cube.obj\"\npath = \"cube.obj\"\nmass = 1.0\ncell = 0.5\n"),
    )
    .unwrap_err();
    let e = e.diagnostic().unwrap();
    assert_eq!(
        (e.line, e.key.to_string(), e.message.as_str()),
        (
            9,
            "body[0].path".into(),
            "give either `file` or `path`, not both"
        )
    );
    let e = with("path", "file = \"cube.obj\"\npath").unwrap_err();
    let e = e.diagnostic().unwrap();
    assert_eq!(
        (e.key.to_string(), e.message.as_str()),
        (
            "terrain[0].path".into(),
            "give either `file` or `path`, not both"
        )
    );
    let e = load(
        d,
        &scene_text("path = \"missing.obj\"\nmass = 1.0\ncell = 0.5\n"),
    )
    .unwrap_err();
    let e = e.diagnostic().unwrap();
    assert_eq!((e.line, e.key.to_string()), (8, "body[0].path".into()));
    assert!(
        e.message.ends_with("missing.obj does not exist"),
        "{}",
        e.message
    );
}

/// The lattice keeps every cell a triangle meets and every cell whose centre is inside, so its
/// volume V_h is at least the mesh's V and exceeds it by a band of cells along the surface:
/// V_h − V = O(A h), first order in the cell. Measured on a torus (R = 1 m, r = 0.4 m, 96 × 48
/// quads; V is the polygon's exact volume, Σ a·(b × c)/6) at h = r/4 … r/32: the fitted order
/// lies within 0.1 of 1, and the error is between 0.2 and 1 times A·h (A the mesh's area).
#[test]
fn lattice_volume_converges_at_first_order() {
    let mesh = TriangleMesh::torus(1.0, 0.4, 96, 48);
    let volume = enclosed_volume(&mesh.vertices, &mesh.triangles);
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
            0.5 * (b - a).cross(c - a).length()
        })
        .sum();
    let mut rows = Vec::new();
    for k in 2..=5 {
        let h = 0.4 / f64::from(1u32 << k);
        let v = Voxels::new(mesh.clone(), DVec3::ONE, LatticeSize::Cell(h)).unwrap();
        let error = v.volume() - volume;
        println!(
            "h = {h:.4} m: {} cells kept, V_h = {:.5} m³, V_h − V = {error:.5} m³ = {:.3} A·h",
            v.present_cells(),
            v.volume(),
            error / (area * h)
        );
        assert!(error > 0.0, "the lattice covers the mesh");
        assert!((0.2..=1.0).contains(&(error / (area * h))), "h = {h}");
        rows.push((h.ln(), error.ln()));
    }
    // Least-squares slope of ln(error) against ln(h).
    let n = rows.len() as f64;
    let (mx, my) = rows
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let slope = rows.iter().map(|(x, y)| (x - mx) * (y - my)).sum::<f64>()
        / rows.iter().map(|(x, _)| (x - mx).powi(2)).sum::<f64>();
    println!("V = {volume:.5} m³, A = {area:.4} m², fitted order {slope:.3}");
    assert!((slope - 1.0).abs() <= 0.1, "order {slope}");
}

/// A box mesh voxelised at a cell that divides it is the cuboid of the same lattice: the same
/// particles (positions to 1e-12 m, masses), the same springs in the same order (ends, rest
/// lengths to 1e-12 m, parameters), the same adjacency, contact data and spring counts, and,
/// with `surface = "lattice"`, the cuboid's surface triangles.
#[test]
fn a_box_mesh_is_the_cuboid_of_its_lattice() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(
        dir.path(),
        "box.obj",
        &TriangleMesh::cube(DVec3::new(3.0, -1.0, 2.0), 1.0),
    );
    let springs = "structural = { stiffness = 100.0, damping = 0.5 }\n\
                   shear = { stiffness = 80.0, damping = 0.25 }\n\
                   bending = { stiffness = 60.0, damping = 0.125 }\n";
    let place = "center = [0.5, 1.0, -0.25]\nrotation = [10.0, 20.0, 30.0]\n\
                 velocity = [0.5, 0.0, -1.0]\nmass = 2.0\n";
    let mesh = load(
        dir.path(),
        &scene_text(&format!(
            "file = \"box.obj\"\nscale = [0.4, 0.3, 0.2]\ncell = 0.05\nsurface = \"lattice\"\n\
             {place}{springs}"
        )),
    )
    .unwrap();
    let cuboid = load(
        dir.path(),
        &scene_text(&format!(
            "size = [0.4, 0.3, 0.2]\nresolution = [9, 7, 5]\n{place}{springs}"
        ))
        .replace("kind = \"mesh\"", "kind = \"cuboid\""),
    )
    .unwrap();
    let (a, sa) = Model::build(&mesh);
    let (b, sb) = Model::build(&cuboid);
    assert_eq!(a.len(), 9 * 7 * 5);
    assert_eq!(a.len(), b.len());
    let dx =
        sa.x.iter()
            .zip(&sb.x)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0, f64::max);
    println!("largest particle distance: {dx:.3e} m");
    assert!(dx <= 1e-12, "{dx:e}");
    assert_eq!(sa.v, sb.v);
    assert_eq!(a.mass, b.mass);
    assert_eq!(a.inv_mass, b.inv_mass);
    assert_eq!(a.springs().a, b.springs().a);
    assert_eq!(a.springs().b, b.springs().b);
    assert_eq!(a.springs().stiffness, b.springs().stiffness);
    assert_eq!(a.springs().damping, b.springs().damping);
    let dr = a
        .springs()
        .rest
        .iter()
        .zip(&b.springs().rest)
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max);
    assert!(dr <= 1e-12, "{dr:e}");
    assert_eq!(a.adjacency(), b.adjacency());
    assert_eq!(a.spring_counts, b.spring_counts);
    assert_eq!(a.spring_counts, topology::grid_spring_counts([9, 7, 5]));
    // The contact radius is half the cell, 0.05/2, against half of 0.3/6: equal to 1e-17.
    assert_eq!(a.contact.lattice, b.contact.lattice);
    assert_eq!(a.contact.body, b.contact.body);
    assert!(
        a.contact
            .radius
            .iter()
            .zip(&b.contact.radius)
            .all(|(p, q)| (p - q).abs() < 1e-17)
    );
    let sorted = |t: &[[u32; 3]]| {
        let mut t = t.to_vec();
        t.sort();
        t
    };
    assert_eq!(sorted(&a.surface), sorted(&b.surface));
    assert!(a.embedded.is_empty());
}

/// Two boxes one cell apart in one file: the particles facing each other across the gap are
/// present (corners of kept cells) and one cell apart, but no spring joins the two boxes — a
/// spring is kept only inside kept cells.
#[test]
fn springs_do_not_bridge_a_gap() {
    let dir = tempfile::tempdir().unwrap();
    let mut two = TriangleMesh::cube(DVec3::ZERO, 0.4);
    let other = TriangleMesh::cube(DVec3::new(0.5, 0.0, 0.0), 0.4);
    let n = two.vertices.len() as u32;
    two.vertices.extend(other.vertices);
    two.triangles
        .extend(other.triangles.iter().map(|t| t.map(|i| i + n)));
    write_obj(dir.path(), "two.obj", &two);
    let scene = load(
        dir.path(),
        &scene_text(
            "file = \"two.obj\"\ncell = 0.1\nmass = 1.0\nstructural = { stiffness = 1.0 }\n\
             shear = { stiffness = 1.0 }\nbending = { stiffness = 1.0 }\n",
        ),
    )
    .unwrap();
    let (model, state) = Model::build(&scene);
    // 9 × 4 × 4 cells, the middle column of 16 empty: 2 × 5³ particles.
    assert_eq!(model.len(), 250);
    let side = |p: u32| state.x[p as usize].x > 0.0;
    let crossing = (0..model.springs().len())
        .filter(|&s| side(model.springs().a[s]) != side(model.springs().b[s]))
        .count();
    assert_eq!(crossing, 0);
    // Each box has the springs of a 5³ cuboid.
    let one = topology::grid_spring_counts([5, 5, 5]);
    assert_eq!(model.spring_counts, one + one);
}

/// The mesh body of a scene of one.
fn mesh_body(scene: &Scene) -> &MeshBody {
    match &scene.bodies[0].shape {
        BodyShape::Mesh(m) => m,
        other => panic!("not a mesh body: {other:?}"),
    }
}

/// A density weighs the volume the mesh encloses, whatever the cell: a box scaled to
/// 0.4 × 0.3 × 0.2 m at a cell that does not divide it (its kept cells hold more), and a torus,
/// whose lattice holds half again its volume; the particles share that mass evenly. A mesh that
/// is not closed (a cube less one triangle) encloses no definite volume and weighs its kept
/// cells. Two shells one inside the other, both wound outwards, enclose 1.125 m³ in 1 m³ of
/// cells: refused, naming both volumes.
#[test]
fn density_weighs_the_volume_the_mesh_encloses() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_obj(
        d,
        "box.obj",
        &TriangleMesh::cube(DVec3::new(3.0, -1.0, 2.0), 1.0),
    );
    let torus = TriangleMesh::torus(0.2, 0.08, 32, 16);
    write_obj(d, "torus.obj", &torus);
    let mut open = TriangleMesh::cube(DVec3::ZERO, 1.0);
    open.triangles.pop();
    write_obj(d, "open.obj", &open);
    let mut nested = TriangleMesh::cube(DVec3::ZERO, 1.0);
    let inner = TriangleMesh::cube(DVec3::splat(0.25), 0.5);
    let base = nested.vertices.len() as u32;
    nested.vertices.extend(inner.vertices);
    (nested.triangles).extend(inner.triangles.iter().map(|t| t.map(|i| i + base)));
    write_obj(d, "nested.obj", &nested);
    let rho = 500.0;
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b;

    let boxed = load(
        d,
        &scene_text(&format!(
            "file = \"box.obj\"\nscale = [0.4, 0.3, 0.2]\ncell = 0.07\ndensity = {rho}\n"
        )),
    )
    .unwrap();
    let m = mesh_body(&boxed);
    // 6 × 5 × 3 cells of 7 cm hold 0.0309 m³ around the box's 0.024.
    assert!(
        close(m.voxels.volume(), 90.0 * 0.07f64.powi(3)),
        "{}",
        m.voxels.volume()
    );
    assert!(
        close(m.total_mass(), rho * 0.4 * 0.3 * 0.2),
        "{}",
        m.total_mass()
    );
    let (model, _) = Model::build(&boxed);
    let each = m.total_mass() / model.len() as f64;
    assert!(model.mass.iter().all(|&mass| mass == each));

    let ring = load(
        d,
        &scene_text(&format!(
            "file = \"torus.obj\"\ncell = 0.04\ndensity = {rho}\n"
        )),
    )
    .unwrap();
    let m = mesh_body(&ring);
    let v = enclosed_volume(&torus.vertices, &torus.triangles);
    assert!(
        close(m.total_mass(), rho * v),
        "{} against {}",
        m.total_mass(),
        rho * v
    );
    assert!(
        m.voxels.volume() > 1.4 * v,
        "{} against {v}",
        m.voxels.volume()
    );

    let open = load(
        d,
        &scene_text(&format!(
            "file = \"open.obj\"\ncell = 0.25\ndensity = {rho}\n"
        )),
    )
    .unwrap();
    let m = mesh_body(&open);
    assert_eq!(m.voxels.enclosed_volume(), None);
    assert_eq!(m.total_mass(), rho * m.voxels.volume());
    assert_eq!(m.voxels.volume(), 1.0);

    let e = error(
        d,
        &format!("file = \"nested.obj\"\ncell = 0.25\ndensity = {rho}\n"),
    );
    assert_eq!(
        e,
        "10: body[0].density: the mesh encloses 1.125 m³, more than the 1 m³ of the cells that \
         hold it: parts of it are wound more than once (nested or overlapping shells); give \
         `mass` instead"
    );
    // With a mass there is no volume to weigh.
    let nested = load(
        d,
        &scene_text("file = \"nested.obj\"\ncell = 0.25\nmass = 2.0\n"),
    )
    .unwrap();
    assert_eq!(mesh_body(&nested).total_mass(), 2.0);
}

/// The located error of a scene, as `line: key: message`.
fn error(dir: &Path, keys: &str) -> String {
    let e = load(dir, &scene_text(keys)).unwrap_err();
    let d = e.diagnostic().expect("a located error");
    format!("{}: {}: {}", d.line, d.key, d.message)
}

/// Bad input is refused with the line and key it is about, never a panic.
#[test]
fn bad_input_is_located() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_obj(d, "cube.obj", &TriangleMesh::cube(DVec3::ZERO, 1.0));
    let mut open = TriangleMesh::cube(DVec3::ZERO, 1.0);
    open.triangles.truncate(6);
    write_obj(d, "open.obj", &open);
    std::fs::write(d.join("points.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    std::fs::write(d.join("broken.obj"), "v 0 0 0\nv 1 0 0\nf 1 2 x\n").unwrap();
    let flat = TriangleMesh {
        path: "flat.obj".into(),
        vertices: vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 0.0, 1.0), DVec3::Z],
        triangles: vec![[0, 2, 1], [0, 3, 2]],
    };
    write_obj(d, "flat.obj", &flat);
    let ok = "mass = 1.0\ncell = 0.25\n";

    let e = error(d, &format!("file = \"missing.obj\"\n{ok}"));
    assert!(e.starts_with("8: body[0].file: mesh file "), "{e}");
    assert!(e.ends_with("missing.obj does not exist"), "{e}");
    let e = error(d, &format!("file = \"broken.obj\"\n{ok}"));
    assert!(e.starts_with("8: body[0].file: mesh file "), "{e}");
    assert!(e.contains("is not a valid OBJ file"), "{e}");
    let e = error(d, &format!("file = \"points.obj\"\n{ok}"));
    assert!(
        e.starts_with("8: body[0].file: ") && e.ends_with("holds no triangles"),
        "{e}"
    );
    let e = error(d, &format!("file = \"open.obj\"\n{ok}"));
    assert!(e.starts_with("8: body[0].file: "), "{e}");
    assert!(
        e.contains("is not closed enough to tell inside from outside"),
        "{e}"
    );
    let e = error(d, &format!("file = \"flat.obj\"\n{ok}"));
    assert!(
        e.starts_with("10: body[0].cell: no cell of the 4 × 1 × 4 lattice"),
        "{e}"
    );
    let e = error(d, "file = \"cube.obj\"\nmass = 1.0\ncell = 1e-4\n");
    assert!(
        e.starts_with("10: body[0].cell: a lattice of 10000 × 10000 × 10000 cells"),
        "{e}"
    );
    assert!(e.ends_with("particles supported"), "{e}");
    let e = error(d, "file = \"cube.obj\"\nmass = 1.0\nresolution = 0\n");
    assert_eq!(
        e,
        "10: body[0].resolution: must be a number of cells from 1 to 4294967295, not 0"
    );
    let e = error(
        d,
        "file = \"cube.obj\"\nmass = 1.0\nresolution = [2, 2, 2]\n",
    );
    assert_eq!(
        e,
        "10: body[0].resolution: a mesh body's resolution is one number: cells along the \
         longest side"
    );
    let e = error(
        d,
        "file = \"cube.obj\"\nmass = 1.0\ncell = 0.5\nresolution = 4\n",
    );
    assert_eq!(
        e,
        "11: body[0].resolution: give either `cell` or `resolution`, not both"
    );
    let e = error(d, "file = \"cube.obj\"\ncell = 0.5\n");
    assert!(e.contains("needs the key `mass` (kg) or `density`"), "{e}");
    let e = error(d, "file = \"cube.obj\"\nmass = 1.0\ncell = -0.5\n");
    assert_eq!(e, "10: body[0].cell: must be greater than zero, not -0.5");
    let e = error(
        d,
        &format!("file = \"cube.obj\"\n{ok}scale = [1.0, 0.0, 1.0]\n"),
    );
    assert_eq!(e, "11: body[0].scale[1]: must be greater than zero, not 0");
    let e = error(
        d,
        &format!("file = \"cube.obj\"\n{ok}contact_radius = 0.3\n"),
    );
    assert!(
        e.starts_with("11: body[0].contact_radius: 0.3 m is more than the mesh body's cell"),
        "{e}"
    );
    let e = error(
        d,
        &format!("file = \"cube.obj\"\n{ok}size = [1.0, 1.0, 1.0]\n"),
    );
    assert_eq!(e, "11: body[0].size: `size` is not a key of a `mesh body`");
    let e = error(d, &format!("file = \"cube.obj\"\n{ok}pinned = [125]\n"));
    assert_eq!(
        e,
        "11: body[0].pinned[0]: particle 125 does not exist: the body has 125 particles"
    );
    let e = error(
        d,
        &format!("file = \"cube.obj\"\n{ok}surface = \"voxels\"\n"),
    );
    assert!(
        e.starts_with("11: body[0].surface: unknown variant `voxels`"),
        "{e}"
    );
    // A cuboid's resolution stays three numbers.
    let text = scene_text("size = [1.0, 1.0, 1.0]\nresolution = 3\nmass = 1.0\n")
        .replace("kind = \"mesh\"", "kind = \"cuboid\"");
    let e = load(d, &text).unwrap_err();
    let d = e.diagnostic().unwrap();
    assert_eq!(
        (d.line, d.key.to_string(), d.message.as_str()),
        (
            9,
            "body[0].resolution".to_owned(),
            "a cuboid's resolution is three particle counts, [nx, ny, nz]"
        )
    );
}
