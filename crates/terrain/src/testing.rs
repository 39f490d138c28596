//! Fixtures and checks the unit tests of every terrain kind share.

use glam::DVec3;
use softbody_scene::{FrictionModel, Heightfield, Terrain, TerrainShape, TriangleMesh};

use crate::{Contact, Surface};

pub(crate) use softbody_testkit::Rng;

pub(crate) fn terrain(shape: TerrainShape) -> Terrain {
    Terrain {
        shape,
        restitution: 0.5,
        friction: 0.3,
        friction_model: FrictionModel::Coulomb,
    }
}

pub(crate) fn surface(shape: TerrainShape) -> Surface {
    Surface::new(&terrain(shape))
}

pub(crate) fn at(s: &Surface, x: DVec3) -> Contact {
    s.query(x, f64::INFINITY)
        .unwrap_or_else(|| panic!("no contact at {x} with infinite reach"))
}

#[track_caller]
pub(crate) fn close(a: f64, b: f64, tol: f64) {
    assert!((a - b).abs() <= tol, "{a} vs {b} (tol {tol})");
}

#[track_caller]
pub(crate) fn close3(a: DVec3, b: DVec3, tol: f64) {
    assert!((a - b).abs().max_element() <= tol, "{a} vs {b} (tol {tol})");
}

#[track_caller]
pub(crate) fn unit(n: DVec3) {
    close(n.length(), 1.0, 1e-14);
}

/// φ, then the push-back `x − φN` lands on the surface, where the normal must not change.
#[track_caller]
pub(crate) fn push_back_keeps_normal(s: &Surface, x: DVec3, tol: f64) {
    let c = at(s, x);
    let y = x - c.phi * c.normal;
    let d = at(s, y);
    close(d.phi, 0.0, 1e-14);
    close3(d.normal, c.normal, tol);
}

/// None iff φ >= reach, checked at the representable neighbours of φ.
#[track_caller]
pub(crate) fn reach_threshold(s: &Surface, x: DVec3) {
    let c = at(s, x);
    assert_eq!(s.query(x, c.phi), None, "reach = phi must give None");
    assert_eq!(s.query(x, c.phi.next_down()), None);
    assert_eq!(
        s.query(x, c.phi.next_up()),
        Some(c),
        "bounded search changed the answer"
    );
    assert_eq!(s.query(x, c.phi + 1.0), Some(c));
}

/// Surface at y = −0.5 over x ∈ [10, 12], z ∈ [20, 24].
pub(crate) fn flat_field() -> Surface {
    surface(TerrainShape::Heightfield(Heightfield {
        heights: vec![vec![0.5; 3]; 3],
        cell_size: [1.0, 2.0],
        origin: DVec3::new(10.0, -1.0, 20.0),
    }))
}

/// The unit cube [0, 1]³ as an OBJ loader delivers it: four vertices per face.
pub(crate) fn cube_mesh() -> TriangleMesh {
    TriangleMesh::cube(DVec3::ZERO, 1.0)
}

/// Checks `s` against an independent φ at random points: the value, the push-back landing
/// on the surface, and bit-identical answers for every reach that lets the contact through.
pub(crate) fn against_reference(
    s: &Surface,
    reference: impl Fn(DVec3) -> f64,
    lo: DVec3,
    hi: DVec3,
    seed: u64,
) {
    let mut rng = Rng::new(seed);
    for _ in 0..3000 {
        let x = rng.in_box(lo, hi);
        let c = at(s, x);
        close(c.phi, reference(x), 1e-12);
        unit(c.normal);
        if c.phi.abs() > 1e-6 {
            close(at(s, x - c.phi * c.normal).phi, 0.0, 1e-12);
        }
        for reach in [rng.range(-0.5, 2.0), c.phi.next_up(), c.phi] {
            let expected = (c.phi < reach).then_some(c);
            assert_eq!(s.query(x, reach), expected, "x = {x}, reach = {reach}");
        }
    }
}
