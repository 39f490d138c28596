//! Terrain geometry of `softbody`, shared by the CPU solver, the GPU solver and the renderer:
//! point queries against one terrain shape in f64 ([`Surface`], built on parry3d-f64), the
//! one rule that splits a heightfield cell into triangles ([`CellTriangle`]), and the
//! signed-distance grid that mesh terrain is baked into for the GPU ([`sdf`]).
//!
//! # Point queries
//!
//! The signed distance φ and the outward unit normal N of a point against one terrain shape,
//! built once per run ([`Surface::new`]) and queried from many threads ([`Surface::query`]).
//!
//! φ > 0 in free space, φ < 0 inside the solid, and N points into free space, so the contact
//! response `x ← x − φ·N` puts a particle back on the surface. Per kind:
//!
//! - **plane**: the solid is the half-space below the plane; φ = n̂·(x − point) with n̂ the
//!   scene normal normalised here, and N = n̂ everywhere.
//! - **box**: the solid box. Outside, φ is the Euclidean distance to the box (to a face, an edge
//!   or a corner) and N points from the closest box point to x; inside, φ = −(distance to the
//!   nearest face) and N is that face's normal.
//! - **sphere**: the solid ball; φ = |x − c| − R, N = (x − c)/|x − c|.
//! - **bowl**: the inside of the sphere is free space; φ = R − |x − c|, N = (c − x)/|x − c|.
//! - **heightfield**: the solid lies below the triangulated height surface (cells split as
//!   [`CellTriangle`] states), over the grid's footprint only. |φ| is the distance to the
//!   nearest surface triangle; φ < 0 when x is within the footprint (edges included) and
//!   strictly below the surface point directly under or above it. Beside the footprint a point
//!   is outside, whatever its height (the solid has no walls), so φ is the plain distance to
//!   the nearest triangle. N points from the nearest surface point to x (outside) or from x to
//!   it (inside).
//! - **mesh**: the side the triangles' counter-clockwise normals point to is free space. |φ| is
//!   the distance to the nearest triangle; the sign comes from parry's angle-weighted
//!   pseudo-normals (Bærentzen & Aanæs), so it is exact for closed, consistently oriented meshes.
//!   An open mesh (a ground patch) is solid on its back side, and beyond its rim the sign follows
//!   the pseudo-normal of the nearest rim edge or vertex. N as for the heightfield.
//!
//! At the exact centre of a sphere or bowl (within ε, below), where no direction is radial, N is +y.
//!
//! # Normals of points on the surface
//!
//! Particles are projected exactly onto surfaces, so the common query has |φ| ≈ 1e-17 m, where
//! the direction between x and its closest surface point is rounding noise. When that distance is
//! at most ε = max(1e-12 m, 1e-9 · M), with M the magnitude of the shape's world coordinates
//! (its placement plus its extent), N comes from the geometry instead: the box face with the
//! largest signed distance |p| − h in box coordinates (the lowest axis on ties), or the
//! geometric normal of the nearest heightfield or mesh triangle (the heightfield triangle under
//! the point when several are equally near). M includes the placement because the rounding of
//! world → shape coordinates grows with |x|: 1e-9 · M leaves seven orders of magnitude over that
//! noise, and a direction computed just above ε is still good to about 1e-7 rad. Planes, spheres
//! and bowls always use their analytic normal, which has no such noise.
//!
//! Queries allocate nothing, are deterministic (same point and reach → same bits), and a point
//! or reach that is not a number never makes contact.
#![warn(missing_docs)]

mod cuboid;
mod heightfield;
mod mesh;
mod plane;
pub mod sdf;
mod sphere;
#[cfg(test)]
mod testing;

use glam::DVec3;
use softbody_scene::{FrictionModel, Terrain, TerrainShape};

pub use heightfield::CellTriangle;
pub use plane::PlaneGeometry;

use cuboid::BoxGeometry;
use heightfield::HeightfieldGeometry;
use mesh::MeshGeometry;
use sphere::BallGeometry;

/// Degenerate-normal threshold, relative to the shape's coordinate magnitude.
const REL_EPS: f64 = 1e-9;
/// Degenerate-normal threshold floor, metres, for shapes near the origin.
const ABS_EPS: f64 = 1e-12;

/// ε of a shape whose world coordinates have magnitude `magnitude` (see the crate doc).
fn eps_for(magnitude: f64) -> f64 {
    (REL_EPS * magnitude).max(ABS_EPS)
}

/// Signed distance and outward normal of a point against one surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Signed distance, metres: > 0 in free space, < 0 inside the solid.
    pub phi: f64,
    /// Outward unit normal, pointing into free space.
    pub normal: DVec3,
}

/// One terrain shape, ready for queries (built once per run).
#[derive(Debug, Clone)]
pub struct Surface {
    geometry: Geometry,
    /// Coefficient of restitution k_r in [0, 1].
    pub restitution: f64,
    /// Friction coefficient (μ for Coulomb, k_f for viscous).
    pub friction: f64,
    /// Friction law.
    pub friction_model: FrictionModel,
}

#[derive(Debug, Clone)]
enum Geometry {
    Plane(PlaneGeometry),
    Ball(BallGeometry),
    Box(BoxGeometry),
    Heightfield(HeightfieldGeometry),
    Mesh(MeshGeometry),
    /// Geometry a validated scene never holds (too few heights, no triangles, a zero normal…):
    /// it touches nothing rather than panicking.
    Empty,
}

// Queries run from rayon threads.
const _: fn() = || {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<Surface>();
};

impl Surface {
    /// Builds the query structure of one terrain shape. Expects a validated terrain; shapes that
    /// validation would refuse become a surface that never reports contact.
    pub fn new(t: &Terrain) -> Surface {
        let geometry = match &t.shape {
            TerrainShape::Plane { point, normal } => {
                PlaneGeometry::new(*point, *normal).map(Geometry::Plane)
            }
            TerrainShape::Sphere { center, radius } | TerrainShape::Bowl { center, radius } => {
                let bowl = matches!(t.shape, TerrainShape::Bowl { .. });
                Some(Geometry::Ball(BallGeometry::new(*center, *radius, bowl)))
            }
            TerrainShape::Box {
                center,
                half_extents,
                rotation,
            } => Some(Geometry::Box(BoxGeometry::new(
                *center,
                *half_extents,
                *rotation,
            ))),
            TerrainShape::Heightfield(h) => HeightfieldGeometry::new(h).map(Geometry::Heightfield),
            TerrainShape::Mesh(m) => {
                MeshGeometry::new(&m.vertices, &m.triangles).map(Geometry::Mesh)
            }
        };
        Surface {
            geometry: geometry.unwrap_or(Geometry::Empty),
            restitution: t.restitution,
            friction: t.friction,
            friction_model: t.friction_model,
        }
    }

    /// Some(contact) when the point's signed distance φ < `reach` (this includes every
    /// penetrating point, however deep); None when the point is at least `reach` away in free
    /// space. `reach` may be `f64::INFINITY` (then always Some, for a finite point).
    #[inline]
    pub fn query(&self, x: DVec3, reach: f64) -> Option<Contact> {
        // Planes, the common ground, are answered inline: the same expressions as below.
        if let Geometry::Plane(plane) = &self.geometry {
            if !x.is_finite() || reach.is_nan() {
                return None;
            }
            return within(plane.contact(x), reach);
        }
        self.query_shape(x, reach)
    }

    /// True only when [`Surface::query`] would answer None: the point lies at least `reach`
    /// above a plane (φ ≥ reach, computed as `query` computes it). Other shapes, and points
    /// this cannot vouch for, answer false. The explicit integrators test this first, so that
    /// a particle in the air costs one dot product per plane instead of a contact check and a
    /// collision response: the skip changes no bits, since `query` would return None.
    #[inline]
    pub fn clear_of(&self, x: DVec3, reach: f64) -> bool {
        match &self.geometry {
            Geometry::Plane(plane) => plane.clear_of(x, reach),
            _ => false,
        }
    }

    /// The plane, when this surface is one: its [`PlaneGeometry::clear_of`] is this surface's
    /// [`Surface::clear_of`].
    pub fn plane(&self) -> Option<&PlaneGeometry> {
        match &self.geometry {
            Geometry::Plane(plane) => Some(plane),
            _ => None,
        }
    }

    /// The Jacobian ∂N/∂x of the outward normal [`Surface::query`] answers at `x` (the Hessian
    /// of φ), where the gradients of a run are built: zero for a plane (and for a ball at its
    /// centre, where the normal is fixed), ±(I − N Nᵀ)/|x − c| for a sphere (+) or a bowl (−);
    /// for a box, a heightfield and a mesh, whose N points from the nearest point q of a face,
    /// an edge or a corner, ±(I − N Nᵀ)(I − ∂q/∂x)/|x − q| (zero over a face's interior, where N
    /// is the face's: N turns only past edges and corners). Within ε of the surface, where N is
    /// the face's, it is zero.
    pub fn normal_jacobian(&self, x: DVec3) -> glam::DMat3 {
        match &self.geometry {
            Geometry::Plane(_) | Geometry::Empty => glam::DMat3::ZERO,
            Geometry::Ball(ball) => ball.normal_jacobian(x),
            Geometry::Box(cuboid) => cuboid.normal_jacobian(x),
            Geometry::Heightfield(field) => field.normal_jacobian(x),
            Geometry::Mesh(mesh) => mesh.normal_jacobian(x),
        }
    }

    /// [`Surface::query`] for every kind of shape.
    #[inline(never)]
    fn query_shape(&self, x: DVec3, reach: f64) -> Option<Contact> {
        if !x.is_finite() || reach.is_nan() {
            return None;
        }
        match &self.geometry {
            Geometry::Plane(plane) => within(plane.contact(x), reach),
            Geometry::Ball(ball) => within(ball.contact(x), reach),
            Geometry::Box(cuboid) => within(cuboid.contact(x), reach),
            // These two bound their search by the reach, so they apply it themselves.
            Geometry::Heightfield(field) => field.query(x, reach),
            Geometry::Mesh(mesh) => mesh.query(x, reach),
            Geometry::Empty => None,
        }
    }
}

/// ∂N/∂x for N = s (x − q)/|x − q| (s = +1 outside, −1 inside), q(x) the nearest point of a
/// feature with ∂q/∂x = `along` (a face's plane projector, an edge's line projector, zero at a
/// corner): s (I − N Nᵀ)(I − along)/|x − q|.
pub(crate) fn nearest_point_jacobian(
    normal: DVec3,
    dist: f64,
    along: glam::DMat3,
    inside: bool,
) -> glam::DMat3 {
    let nn = glam::DMat3::from_cols(normal * normal.x, normal * normal.y, normal * normal.z);
    let j = (glam::DMat3::IDENTITY - nn) * (glam::DMat3::IDENTITY - along) / dist;
    if inside { -j } else { j }
}

/// ∂q/∂x of the nearest point q of `triangle` at `location`: the projector onto its plane on
/// the face, onto the edge's line on an edge, zero at a vertex.
pub(crate) fn triangle_feature_projector(
    triangle: &parry3d_f64::shape::Triangle,
    location: &parry3d_f64::shape::TrianglePointLocation,
) -> glam::DMat3 {
    use parry3d_f64::shape::TrianglePointLocation as At;
    let outer = |u: DVec3| glam::DMat3::from_cols(u * u.x, u * u.y, u * u.z);
    let (a, b, c) = (triangle.a, triangle.b, triangle.c);
    match location {
        At::OnVertex(_) => glam::DMat3::ZERO,
        // Edge 0 is AB, 1 is BC, 2 is AC (parry's numbering for locations).
        At::OnEdge(i, _) => {
            let e = match i {
                0 => b - a,
                1 => c - b,
                _ => c - a,
            };
            outer(e.normalize_or_zero())
        }
        At::OnFace(..) | At::OnSolid => {
            glam::DMat3::IDENTITY - outer((b - a).cross(c - a).normalize_or_zero())
        }
    }
}

/// The contact if it is within reach (φ < reach), as [`Surface::query`] answers.
#[inline]
fn within(contact: Contact, reach: f64) -> Option<Contact> {
    (contact.phi < reach).then_some(contact)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{at, flat_field, surface, terrain};
    use softbody_scene::{Heightfield, TriangleMesh};

    /// ∂N/∂x of the shapes whose normal turns at edges and corners, against central
    /// differences of the normal, at points outside over a face (zero), past an edge, past a
    /// corner and inside, each at least 0.05 m from the boundaries of its feature's region, so
    /// that x ± δ stays in it: the difference's error is O(δ²/d³) ≈ 1e-6 at δ = 1e-5 and
    /// d ≥ 0.05 m, over a rounding error of 1e-16/δ.
    #[test]
    fn normal_jacobians_turn_the_normal_past_edges_and_corners() {
        let rotation = DVec3::new(30.0, 45.0, 60.0);
        let (center, r) = (
            DVec3::new(1.0, 2.0, 3.0),
            glam::DMat3::from_quat(softbody_scene::rotation_from_degrees(rotation)),
        );
        let cuboid = surface(TerrainShape::Box {
            center,
            half_extents: DVec3::new(1.0, 0.5, 2.0),
            rotation,
        });
        let in_box = |p: DVec3| center + r * p;
        // A tent: one raised vertex at (1, 1, 1) over a 3 × 3 grid.
        let tent = surface(TerrainShape::Heightfield(Heightfield {
            heights: vec![vec![0.0; 3], vec![0.0, 1.0, 0.0], vec![0.0; 3]],
            cell_size: [1.0, 1.0],
            origin: DVec3::ZERO,
        }));
        let cube = surface(TerrainShape::Mesh(TriangleMesh::cube(DVec3::ZERO, 1.0)));
        let cases = [
            (
                "box over a face",
                &cuboid,
                in_box(DVec3::new(0.2, 0.6, 0.3)),
                false,
            ),
            (
                "box past an edge",
                &cuboid,
                in_box(DVec3::new(1.1, 0.6, 0.3)),
                true,
            ),
            (
                "box past a corner",
                &cuboid,
                in_box(DVec3::new(1.1, 0.6, 2.1)),
                true,
            ),
            (
                "box inside",
                &cuboid,
                in_box(DVec3::new(0.2, 0.1, 0.3)),
                false,
            ),
            ("tent over its peak", &tent, DVec3::new(1.0, 1.3, 1.0), true),
            ("mesh over a face", &cube, DVec3::new(0.5, 1.2, 0.4), false),
            ("mesh past an edge", &cube, DVec3::new(1.1, 1.2, 0.4), true),
            (
                "mesh past a corner",
                &cube,
                DVec3::new(1.1, 1.2, 1.15),
                true,
            ),
            ("mesh inside", &cube, DVec3::new(0.5, 0.7, 0.45), false),
        ];
        for (what, s, x, turns) in cases {
            let j = s.normal_jacobian(x);
            let delta = 1e-5;
            for k in 0..3 {
                let e = DVec3::AXES[k] * delta;
                let fd = (at(s, x + e).normal - at(s, x - e).normal) / (2.0 * delta);
                assert!(
                    (j.col(k) - fd).length() < 1e-5,
                    "{what} {k}: {} {fd}",
                    j.col(k)
                );
            }
            // The cases are what they say: N turns past edges and corners only.
            let size = (0..3).map(|k| j.col(k).length()).sum::<f64>();
            assert_eq!(size > 1.0, turns, "{what}: |J| = {size}");
        }
    }

    #[test]
    fn deterministic_and_not_a_number() {
        let s = surface(TerrainShape::Box {
            center: DVec3::new(0.1, 0.2, 0.3),
            half_extents: DVec3::new(0.7, 0.8, 0.9),
            rotation: DVec3::new(10.0, 20.0, 30.0),
        });
        let x = DVec3::new(0.9, 1.1, -0.4);
        let c = at(&s, x);
        let d = at(&s, x);
        assert_eq!(c.phi.to_bits(), d.phi.to_bits());
        assert_eq!(
            c.normal.to_array().map(f64::to_bits),
            d.normal.to_array().map(f64::to_bits)
        );
        assert_eq!(s.query(DVec3::new(f64::NAN, 0.0, 0.0), f64::INFINITY), None);
        assert_eq!(s.query(x, f64::NAN), None);
        assert_eq!(
            flat_field().query(DVec3::new(0.0, f64::INFINITY, 0.0), f64::INFINITY),
            None
        );
    }

    #[test]
    fn invalid_geometry_touches_nothing() {
        let s = surface(TerrainShape::Heightfield(Heightfield {
            heights: vec![vec![0.0]],
            cell_size: [1.0, 1.0],
            origin: DVec3::ZERO,
        }));
        assert_eq!(s.query(DVec3::ZERO, f64::INFINITY), None);
        let s = surface(TerrainShape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::ZERO,
        });
        assert_eq!(s.query(DVec3::NEG_Y, f64::INFINITY), None);
        let s = surface(TerrainShape::Mesh(TriangleMesh {
            path: "bad.obj".into(),
            vertices: vec![DVec3::ZERO],
            triangles: vec![[0, 1, 2]],
        }));
        assert_eq!(s.query(DVec3::ZERO, f64::INFINITY), None);
    }

    #[test]
    fn surface_keeps_contact_parameters() {
        let mut t = terrain(TerrainShape::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
        });
        t.friction_model = FrictionModel::Viscous;
        let s = Surface::new(&t);
        assert_eq!(
            (s.restitution, s.friction, s.friction_model),
            (0.5, 0.3, FrictionModel::Viscous)
        );
    }
}
