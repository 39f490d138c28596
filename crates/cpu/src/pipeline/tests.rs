//! Every route and thread count against the gather, bit for bit, on cuboids, thin and several
//! lattices, and mesh bodies.

use std::path::Path;

use softbody_scene::{Scene, TriangleMesh};

use super::plan::{Route, RouteKind};
use super::*;
use crate::spring_forces::stencil::Stencil;
use crate::spring_forces::{Isa, gather, spring_force};

/// Cuboids of `resolutions` side by side (one body each), with every particle moved and
/// moving differently, and one spring crushed to zero length.
fn perturbed_bodies(resolutions: &[[u32; 3]]) -> (Model, Vec<DVec3>, Vec<DVec3>) {
    let mut text = String::new();
    for (b, [nx, ny, nz]) in resolutions.iter().enumerate() {
        text += &format!(
            "[[body]]\nname = \"b{b}\"\nkind = \"cuboid\"\ncenter = [{x}, 1.0, 0.0]\n\
             size = [1.2, 1.0, 1.6]\nresolution = [{nx}, {ny}, {nz}]\nmass = 2.0\n\
             structural = {{ stiffness = 2000.0, damping = 5.0 }}\n\
             shear = {{ stiffness = 1500.0, damping = 4.0 }}\n\
             bending = {{ stiffness = 700.0, damping = 3.0 }}\n",
            x = 3.0 * b as f64,
        );
    }
    perturbed(&text)
}

/// The bodies of `bodies` (TOML, beside the example scenes: mesh bodies may name their
/// meshes), with every particle moved and moving differently, and one spring crushed to
/// zero length.
fn perturbed(bodies: &str) -> (Model, Vec<DVec3>, Vec<DVec3>) {
    perturbed_in(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes"),
        bodies,
    )
}

/// [`perturbed`], mesh files named from `dir`.
fn perturbed_in(dir: &Path, bodies: &str) -> (Model, Vec<DVec3>, Vec<DVec3>) {
    let text = format!(
        "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 1e-5\nduration = 0.0\n{bodies}"
    );
    let scene = Scene::from_toml(&text, &dir.join("test.toml")).expect("valid scene");
    let (model, state) = Model::build(&scene);
    let wobble = |i: usize, a: f64, b: f64, c: f64| {
        let t = i as f64;
        DVec3::new((a * t).sin(), (b * t).cos(), (c * t).sin())
    };
    let mut x: Vec<DVec3> = (state.x.iter().enumerate())
        .map(|(i, &p)| p + 0.01 * wobble(i, 1.3, 0.7, 2.1))
        .collect();
    let v: Vec<DVec3> = (0..model.len()).map(|i| wobble(i, 0.9, 0.3, 1.7)).collect();
    let s = model.springs().len() / 2;
    x[model.springs().b[s] as usize] = x[model.springs().a[s] as usize];
    (model, x, v)
}

/// A 13×11×17 cube (2431 particles, up to 9 chunks), perturbed.
fn perturbed_cube() -> (Model, Vec<DVec3>, Vec<DVec3>) {
    perturbed_bodies(&[[13, 11, 17]])
}

/// Every spring's force by the scalar definition, `spring_force`.
fn scalar_forces(model: &Model, x: &[DVec3], v: &[DVec3]) -> Vec<DVec3> {
    let s = model.springs();
    (0..s.len())
        .map(|k| {
            let (a, b) = (s.a[k] as usize, s.b[k] as usize);
            spring_force(
                x[a],
                x[b],
                v[a],
                v[b],
                s.rest[k],
                s.stiffness[k],
                s.damping[k],
            )
        })
        .collect()
}

/// Per-particle sums by the scalar definition: `spring_force` per spring, `gather` per
/// particle.
fn reference(model: &Model, x: &[DVec3], v: &[DVec3]) -> Vec<DVec3> {
    let per_spring = scalar_forces(model, x, v);
    (0..model.len())
        .map(|i| gather(model.adjacency(), &per_spring, i))
        .collect()
}

fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
    v.iter()
        .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
        .collect()
}

/// Every spring kernel (uniform or per-spring parameters, vector or scalar path) computes
/// the bits of `spring_force`, including no force for the crushed spring.
#[test]
fn kernels_are_spring_force_bit_for_bit() {
    let (model, x, v) = perturbed_cube();
    let s = model.springs();
    let expected = scalar_forces(&model, &x, &v);
    assert_eq!(expected[s.len() / 2], DVec3::ZERO);
    assert!(expected.iter().filter(|f| **f != DVec3::ZERO).count() == s.len() - 1);
    for kernel in [Kernel::new(s), Kernel::per_spring()] {
        let mut out = vec![DVec3::splat(f64::NAN); s.len()];
        kernel.compute(s, &x, &v, &mut out);
        assert_eq!(bits(&out), bits(&expected), "{kernel:?}");
    }
}

/// Sums of a pass over `model` at (x, v) by `route` (the stencil on the path of `isa`, if
/// given, else on the widest the CPU runs), on `threads` threads.
fn pass_sums(
    model: &Model,
    x: &[DVec3],
    v: &[DVec3],
    (route, isa): (RouteKind, Option<Isa>),
    threads: usize,
) -> Vec<DVec3> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    pool.install(|| {
        let mut plan = Plan::with_route(model, route);
        assert_eq!(plan.route(), route);
        if let (Route::Stencil { stencils, .. }, Some(isa)) = (&mut plan.route, isa) {
            stencils.iter_mut().for_each(|s| s.with_isa(isa));
        }
        let n = model.len();
        let (mut sums, mut seen) = (vec![DVec3::NAN; n], vec![DVec3::NAN; n]);
        let bad = pass(
            &mut plan,
            Kernel::new(model.springs()),
            model,
            (x, v),
            (&mut sums[..], &mut seen[..]),
            |i, f, (sum, at)| {
                (*sum, *at) = (f, x[i]);
                true
            },
        );
        assert_eq!(bad, None);
        assert_eq!(bits(&seen), bits(x), "every particle updated once");
        sums
    })
}

/// Every route (the stencil and the fused sweep for models of lattices, the plain route for
/// any) hands every particle the bits of the scalar gather, for any number of threads and
/// so of chunks.
#[test]
fn pass_sums_are_the_gather_for_any_thread_count() {
    let (forward, x, v) = perturbed_cube();
    assert_eq!(Plan::new(&forward).route(), RouteKind::Stencil);
    // The same springs with every third one reversed: no longer forward.
    let mut plain = forward.clone();
    let s = plain.springs_mut();
    for k in (0..s.len()).step_by(3) {
        (s.a[k], s.b[k]) = (s.b[k], s.a[k]);
    }
    assert_eq!(Plan::new(&plain).route(), RouteKind::Gather);
    let cases = [
        (&forward, RouteKind::Stencil),
        (&forward, RouteKind::Sweep),
        (&forward, RouteKind::Gather),
        (&plain, RouteKind::Gather),
    ];
    for (model, route) in cases {
        let expected = bits(&reference(model, &x, &v));
        for threads in [1, 2, 3, 4, 7] {
            let got = pass_sums(model, &x, &v, (route, None), threads);
            assert_eq!(bits(&got), expected, "{route:?}, {threads} threads");
        }
    }
}

/// The stencil (each of its paths that the CPU runs: scalar, AVX2, AVX-512) equals the
/// scalar definition on lattices two and three particles wide along each axis (where
/// bending springs are missing or single), on several bodies at once, and on a slab of
/// several windows of planes, for 1 to 7 threads.
#[test]
fn the_stencil_is_the_gather_on_thin_and_several_lattices() {
    let shapes: [&[[u32; 3]]; 6] = [
        &[[3, 4, 29]],
        &[[2, 2, 2]],
        &[[3, 2, 5], [2, 3, 4]],
        &[[5, 3, 2], [2, 7, 3], [4, 4, 4]],
        &[[9, 2, 6]],
        &[[6, 5, 12], [3, 3, 3]],
    ];
    // A path the CPU lacks is skipped: it cannot run here.
    let isas = [Isa::Scalar, Isa::Avx2, Isa::Avx512];
    let isas: Vec<Isa> = isas.into_iter().filter(|isa| isa.runs()).collect();
    eprintln!("stencil paths tested: {isas:?}");
    for resolutions in shapes {
        let (model, x, v) = perturbed_bodies(resolutions);
        assert_eq!(model.lattices().len(), resolutions.len());
        let expected = bits(&reference(&model, &x, &v));
        for threads in 1..=7 {
            for &isa in &isas {
                let route = (RouteKind::Stencil, Some(isa));
                let got = pass_sums(&model, &x, &v, route, threads);
                let what = format!("{resolutions:?}, {isa:?}, {threads} threads");
                assert_eq!(bits(&got), expected, "{what}");
            }
        }
    }
}

/// Mesh bodies' masked lattices on the stencil (each path the CPU runs for them: scalar,
/// AVX2) equal the scalar definition: rows of several runs (the torus's hole, the star's
/// points), rows and planes without particles (three cubes apart in one mesh: empty planes
/// between them, slabs of one cube or of none), next to a cuboid, for 1 to 7 threads.
#[test]
fn the_stencil_is_the_gather_on_mesh_bodies() {
    let mesh = |name: &str, file: &str, cell: f64, x: f64, rotation: [f64; 3]| {
        format!(
            "[[body]]\nname = \"{name}\"\nkind = \"mesh\"\nfile = \"{file}\"\ncell = {cell}\n\
             center = [{x}, 1.0, 0.0]\nrotation = {rotation:?}\nmass = 3.0\n\
             structural = {{ stiffness = 2000.0, damping = 5.0 }}\n\
             shear = {{ stiffness = 1500.0, damping = 4.0 }}\n\
             bending = {{ stiffness = 700.0, damping = 3.0 }}\n"
        )
    };
    let cuboid = "[[body]]\nname = \"c\"\nkind = \"cuboid\"\ncenter = [3.0, 1.0, 0.0]\n\
                  size = [0.5, 0.4, 0.3]\nresolution = [5, 4, 3]\nmass = 2.0\n\
                  structural = { stiffness = 900.0, damping = 2.0 }\n";
    let bodies = [
        mesh("torus", "torus.obj", 0.05, 0.0, [0.0, 0.0, 0.0]),
        mesh("torus", "torus.obj", 0.04, 0.0, [30.0, 20.0, 10.0])
            + &mesh("star", "star.obj", 0.06, 1.5, [10.0, 0.0, 70.0])
            + cuboid,
    ];
    // Three 0.3 m cubes, 0.3 m apart along z, as one mesh.
    let dir = tempfile::tempdir().expect("a temporary directory");
    let mut cubes = TriangleMesh::cube(DVec3::ZERO, 0.3);
    for lo in [DVec3::new(0.0, 0.05, 0.6), DVec3::new(0.0, 0.1, 1.2)] {
        let cube = TriangleMesh::cube(lo, 0.3);
        let first = cubes.vertices.len() as u32;
        cubes.vertices.extend(cube.vertices);
        (cubes.triangles).extend(cube.triangles.iter().map(|t| t.map(|v| v + first)));
    }
    let obj = cubes.to_obj("three cubes apart");
    std::fs::write(dir.path().join("cubes.obj"), obj).expect("written");
    let cubes = mesh("cubes", "cubes.obj", 0.05, 0.0, [0.0, 0.0, 10.0]);
    let isas = [Isa::Scalar, Isa::Avx2];
    let isas: Vec<Isa> = isas.into_iter().filter(|isa| isa.runs()).collect();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let cases = bodies
        .iter()
        .map(|text| (scenes.as_path(), text))
        .chain([(dir.path(), &cubes)]);
    for (dir, text) in cases {
        let (model, x, v) = perturbed_in(dir, text);
        assert!(model.lattices().iter().any(|l| l.mask.is_some()));
        if text == &cubes {
            let stencil = Stencil::new(&model.lattices()[0]);
            let empty = |k: usize| stencil.plane_start(k) == stencil.plane_start(k + 1);
            assert!((0..stencil.planes()).any(empty), "planes without particles");
        }
        assert_eq!(Plan::new(&model).route(), RouteKind::Stencil);
        let expected = bits(&reference(&model, &x, &v));
        for threads in 1..=7 {
            for &isa in &isas {
                let route = (RouteKind::Stencil, Some(isa));
                let got = pass_sums(&model, &x, &v, route, threads);
                let what = format!("{} particles, {isa:?}, {threads} threads", model.len());
                assert_eq!(bits(&got), expected, "{what}");
            }
        }
    }
}
