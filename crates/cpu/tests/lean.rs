//! The lean model: a model of lattice bodies (cuboids, mesh bodies) keeps its springs as
//! stencils only, and the explicit integrators step it, and report its energies, without ever
//! building a spring list. The
//! result is the list's, bit for bit, and the solver holds what the memory estimate promises
//! (implicit Euler's too).

use glam::DVec3;
use softbody_cpu::CpuSolver;
use softbody_cpu::stable_step::stable_dt_estimate;
use softbody_scene::model::lean_bytes_per_particle;
use softbody_scene::{Integrator, Model, Scene, Solver, SpringParams, State};
use softbody_testkit::Rng;
use softbody_testkit::scenes::*;

const EXPLICIT: [Integrator; 4] = [
    Integrator::ExplicitEuler,
    Integrator::SymplecticEuler,
    Integrator::Midpoint,
    Integrator::Rk4,
];

/// A 12×9×`nz` column of 0.1 m cells lying along z, dropped at a slant onto the ground,
/// pinned at one corner, its positions and velocities disturbed so that every spring is
/// stretched or compressed.
fn column(integrator: Integrator, nz: u32) -> (Model, State) {
    let params = SpringParams {
        stiffness: 800.0,
        damping: 0.4,
    };
    let size = DVec3::new(1.1, 0.8, 0.1 * f64::from(nz - 1));
    let c = cuboid(
        size,
        [12, 9, nz],
        DVec3::new(0.0, 0.45, 0.0),
        0.01 * f64::from(108 * nz),
        params,
    );
    let mut body = cuboid_body(c);
    body.pinned = vec![0];
    let (model, mut state) = Model::build(&scene(
        simulation(integrator, 2e-4),
        vec![body],
        vec![plane(
            DVec3::ZERO,
            DVec3::new(0.1, 1.0, 0.0).normalize(),
            0.3,
            0.4,
        )],
    ));
    let mut rng = Rng::new(11);
    for i in 1..model.len() {
        state.x[i] += rng.vec(0.01);
        state.v[i] = rng.vec(0.5);
    }
    (model, state)
}

fn bits(x: &[DVec3]) -> Vec<[u64; 3]> {
    x.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
}

/// The stencil's steps are the listed springs' steps bit for bit (two slabs of 20 planes:
/// several windows each), with no list built.
#[test]
fn a_lean_cube_steps_as_its_spring_list() {
    for integrator in EXPLICIT {
        let (lean, state) = column(integrator, 40);
        let mut listed = lean.clone();
        listed.springs_mut();
        assert!(lean.lattices().len() == 1 && listed.lattices().is_empty());
        assert_eq!(lean.spring_count(), listed.springs().len());

        let mut a = CpuSolver::new(lean, state.clone(), Some(2)).unwrap();
        let mut b = CpuSolver::new(listed, state, Some(2)).unwrap();
        a.advance(40).unwrap();
        b.advance(40).unwrap();
        let (ea, eb) = (a.energies().unwrap(), b.energies().unwrap());
        let (sa, sb) = (a.state().unwrap().clone(), b.state().unwrap().clone());
        assert_eq!(bits(&sa.x), bits(&sb.x), "{integrator:?}: positions");
        assert_eq!(bits(&sa.v), bits(&sb.v), "{integrator:?}: velocities");
        // The same terms, summed plane by plane instead of in chunks of the list.
        assert_eq!(ea.kinetic.to_bits(), eb.kinetic.to_bits());
        assert!(
            (ea.elastic - eb.elastic).abs() <= 1e-13 * eb.elastic,
            "{integrator:?}: elastic {} against {}",
            ea.elastic,
            eb.elastic
        );
        // The list holds 32 B per spring and its adjacency 8 more: 14 springs per particle.
        let n = a.model().len() as u64;
        assert!(
            b.memory_bytes() > a.memory_bytes() + 400 * n,
            "{integrator:?}"
        );
    }
}

/// The torus of `scenes/torus-on-stairs.toml` as a mesh body at 3 cm cells (a masked
/// lattice: rows of two runs around the hole, points without a particle), tilted, thrown onto
/// the ground, one particle pinned.
fn torus(integrator: Integrator) -> (Model, State) {
    let text = format!(
        "[simulation]\nintegrator = \"{integrator}\"\ndt = 2e-4\nduration = 0.1\n\
         [[body]]\nname = \"torus\"\nkind = \"mesh\"\nfile = \"torus.obj\"\ncell = 0.03\n\
         center = [0.0, 0.1, 0.0]\nrotation = [30.0, 0.0, 10.0]\nvelocity = [0.5, -2.0, 0.0]\n\
         density = 300.0\npinned = [7]\n\
         structural = {{ stiffness = 600.0, damping = 2.0 }}\n\
         shear = {{ stiffness = 500.0, damping = 2.0 }}\n\
         bending = {{ stiffness = 300.0, damping = 1.0 }}\n\
         [[terrain]]\nkind = \"plane\"\nnormal = [0.1, 1.0, 0.0]\nrestitution = 0.5\nfriction = 0.4\n"
    );
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/test.toml");
    let scene = Scene::from_toml(&text, path.as_ref()).expect("test scene is valid");
    Model::build(&scene)
}

/// A mesh body steps on its masked lattice's stencil as its spring list does, bit for bit,
/// through its landing (contact, friction, a pin), with no list built.
#[test]
fn a_lean_mesh_body_steps_as_its_spring_list() {
    for integrator in EXPLICIT {
        let (lean, state) = torus(integrator);
        assert!(lean.lattices().iter().all(|l| l.mask.is_some()));
        let lean_model_bytes = lean.memory_bytes();
        let mut listed = lean.clone();
        listed.springs_mut();
        let mut a = CpuSolver::new(lean, state.clone(), Some(3)).unwrap();
        let mut b = CpuSolver::new(listed, state, Some(3)).unwrap();
        assert!(a.statistics().kernel.starts_with("stencil"));
        assert!(b.statistics().kernel.starts_with("sweep"));
        let normal = DVec3::new(0.1, 1.0, 0.0).normalize();
        let mut closest = f64::INFINITY;
        for _ in 0..5 {
            a.advance(40).unwrap();
            b.advance(40).unwrap();
            let (sa, sb) = (a.state().unwrap().clone(), b.state().unwrap().clone());
            assert_eq!(bits(&sa.x), bits(&sb.x), "{integrator:?}: positions");
            assert_eq!(bits(&sa.v), bits(&sb.v), "{integrator:?}: velocities");
            closest = sa.x.iter().map(|x| x.dot(normal)).fold(closest, f64::min);
        }
        assert!(
            closest < 0.01,
            "{integrator:?}: the torus met the ground ({closest} m)"
        );
        // The lean model built no list on the way (the listed one holds its 32 B a spring).
        assert_eq!(a.model().memory_bytes(), lean_model_bytes, "{integrator:?}");
        let list = 32 * a.model().spring_count() as u64;
        assert!(b.model().memory_bytes() >= lean_model_bytes + list);
        assert!(b.memory_bytes() > a.memory_bytes(), "{integrator:?}");
    }
}

/// Implicit Euler on a mesh body runs its system on the masked lattice (`matrix-free-lattice`)
/// through its landing to rest on the ground, and nothing builds the spring list on the way.
#[test]
fn implicit_euler_on_a_mesh_body_builds_no_list() {
    let text = "[simulation]\nintegrator = \"implicit-euler\"\ndt = 0.004\nduration = 1.0\n\
                [[body]]\nkind = \"mesh\"\nfile = \"torus.obj\"\ncell = 0.03\n\
                center = [0.0, 0.6, 0.0]\nrotation = [30.0, 0.0, 10.0]\ndensity = 300.0\n\
                structural = { stiffness = 600.0, damping = 2.0 }\n\
                shear = { stiffness = 500.0, damping = 2.0 }\n\
                bending = { stiffness = 300.0, damping = 1.0 }\n\
                [[terrain]]\nkind = \"plane\"\nnormal = [0.1, 1.0, 0.0]\nfriction = 0.4\n";
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/test.toml");
    let (lean, state) = Model::build(&Scene::from_toml(text, path.as_ref()).expect("valid"));
    let lean_model_bytes = lean.memory_bytes();
    let mut solver = CpuSolver::new(lean, state, Some(2)).unwrap();
    let normal = DVec3::new(0.1, 1.0, 0.0).normalize();
    let closest = |solver: &mut CpuSolver| {
        (solver.state().unwrap().x.iter())
            .map(|x| x.dot(normal))
            .fold(f64::INFINITY, f64::min)
    };
    assert!(closest(&mut solver) > 0.1);
    solver.advance(250).unwrap();
    assert_eq!(solver.statistics().kernel, "matrix-free-lattice");
    let closest = closest(&mut solver);
    assert!(
        closest.abs() < 0.01,
        "the torus rests on the ground ({closest} m)"
    );
    assert_eq!(solver.model().memory_bytes(), lean_model_bytes);
}

/// What a lean solver holds grows by at most [`lean_bytes_per_particle`] per particle: the
/// bytes of two columns, 80 and 160 planes long, differ by that times the particles between
/// them (the slabs' windows and rings are a few planes each, whatever the length), for every
/// integrator.
#[test]
fn a_lean_solver_holds_the_estimate_per_particle() {
    for integrator in EXPLICIT.into_iter().chain([Integrator::ImplicitEuler]) {
        let held = |nz| {
            let (model, state) = column(integrator, nz);
            let mut solver = CpuSolver::new(model, state, Some(2)).unwrap();
            solver.advance(2).unwrap();
            solver.energies().unwrap();
            (solver.model().len() as f64, solver.memory_bytes() as f64)
        };
        let ((n0, b0), (n1, b1)) = (held(80), held(160));
        let per_particle = (b1 - b0) / (n1 - n0);
        let bound = lean_bytes_per_particle(integrator) as f64;
        eprintln!("{integrator:?}: {per_particle:.1} B per particle (bound {bound})");
        assert!(
            per_particle <= bound,
            "{integrator:?}: {per_particle} B per particle"
        );
    }
    // A column has more surface than a cube: implicit Euler's springs and multigrid blocks per
    // particle are a cube's in its bulk. A 40³ cube holds at most the figure in all, the
    // dense factor of its coarsest level included.
    let c = cuboid(
        DVec3::splat(1.0),
        [40; 3],
        DVec3::new(0.0, 0.6, 0.0),
        64.0,
        SpringParams {
            stiffness: 1e4,
            damping: 1.0,
        },
    );
    let (model, state) = Model::build(&scene(
        simulation(Integrator::ImplicitEuler, 1.0 / 60.0),
        vec![cuboid_body(c)],
        vec![plane(DVec3::ZERO, DVec3::Y, 0.3, 0.4)],
    ));
    let mut solver = CpuSolver::new(model, state, Some(2)).unwrap();
    solver.advance(2).unwrap();
    let per_particle = solver.memory_bytes() as f64 / solver.model().len() as f64;
    let bound = lean_bytes_per_particle(Integrator::ImplicitEuler) as f64;
    eprintln!("ImplicitEuler, 40³ cube: {per_particle:.1} B per particle (bound {bound})");
    assert!(per_particle <= bound, "40³: {per_particle} B per particle");
}

/// What the model visits without a list is the list: the same springs in the same order, and
/// the stable steps computed from them are the same bits.
#[test]
fn for_each_spring_is_the_list_in_order() {
    let (lean, state) = column(Integrator::SymplecticEuler, 10);
    let mut visited = Vec::new();
    lean.for_each_spring(|a, b, r, k, d| {
        visited.push((a, b, r.to_bits(), k.to_bits(), d.to_bits()))
    });
    let mut listed = lean.clone();
    let s = listed.springs_mut().clone();
    let list: Vec<_> = (0..s.len())
        .map(|k| {
            (
                s.a[k],
                s.b[k],
                s.rest[k].to_bits(),
                s.stiffness[k].to_bits(),
                s.damping[k].to_bits(),
            )
        })
        .collect();
    assert_eq!(visited, list);
    assert_eq!(
        lean.stable_dt().map(f64::to_bits),
        listed.stable_dt().map(f64::to_bits)
    );
    assert_eq!(
        stable_dt_estimate(&lean, &state.x).map(f64::to_bits),
        stable_dt_estimate(&listed, &state.x).map(f64::to_bits)
    );
}
