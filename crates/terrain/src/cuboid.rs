//! Box terrain: the solid, oriented box. Outside, φ is the Euclidean distance to the box and N
//! points from the closest box point to x; inside, φ = −(distance to the nearest face) and N is
//! that face's normal; within ε of the surface, N is the face the point is closest to lying on.

use glam::{DMat3, DVec3};
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::Cuboid;
use softbody_scene::rotation_from_degrees;

use crate::{Contact, eps_for, nearest_point_jacobian};

#[derive(Debug, Clone)]
pub(crate) struct BoxGeometry {
    center: DVec3,
    /// Box → world; its transpose maps world offsets into box coordinates.
    rotation: DMat3,
    cuboid: Cuboid,
    eps: f64,
}

impl BoxGeometry {
    /// The box of the scene: `rotation` in degrees, as `rotation_from_degrees` reads it.
    pub(crate) fn new(center: DVec3, half_extents: DVec3, rotation: DVec3) -> BoxGeometry {
        BoxGeometry {
            center,
            rotation: DMat3::from_quat(rotation_from_degrees(rotation)),
            cuboid: Cuboid::new(half_extents),
            eps: eps_for(center.length() + half_extents.length()),
        }
    }

    /// ∂N/∂x: outside, N = (p − q)/|p − q| with q the clamp of p into the box, so ∂q/∂p keeps
    /// the axes p is within and the Jacobian turns N only at edges and corners (zero over a
    /// face); inside and on the surface N is a face's, fixed.
    pub(crate) fn normal_jacobian(&self, x: DVec3) -> DMat3 {
        let p = self.rotation.transpose() * (x - self.center);
        let proj = self.cuboid.project_local_point(p, false);
        let diff = p - proj.point;
        let dist = diff.length();
        if proj.is_inside || dist <= self.eps {
            return DMat3::ZERO;
        }
        let half = self.cuboid.half_extents;
        let within = DVec3::select(p.abs().cmpgt(half), DVec3::ZERO, DVec3::ONE);
        let local = nearest_point_jacobian(diff / dist, dist, DMat3::from_diagonal(within), false);
        self.rotation * local * self.rotation.transpose()
    }

    pub(crate) fn contact(&self, x: DVec3) -> Contact {
        let &BoxGeometry {
            center,
            rotation,
            cuboid,
            eps,
        } = self;
        let p = rotation.transpose() * (x - center);
        let proj = cuboid.project_local_point(p, false);
        let diff = p - proj.point;
        let dist = diff.length();
        let phi = if proj.is_inside { -dist } else { dist };
        let local_normal = if dist > eps {
            // Inside, parry moves the point along one axis only, so this is an exact unit axis.
            if proj.is_inside {
                -diff / dist
            } else {
                diff / dist
            }
        } else {
            // On the surface: the face the point is closest to lying on. Parry's own feature id
            // gives `Unknown` for points exactly on a face of a box with h ≥ 2 (its epsilon test
            // rounds away), so the face is read from the coordinates.
            let excess = p.abs() - cuboid.half_extents;
            let mut k = 0;
            for axis in 1..3 {
                if excess[axis] > excess[k] {
                    k = axis;
                }
            }
            let mut n = DVec3::ZERO;
            n[k] = if p[k] < 0.0 { -1.0 } else { 1.0 };
            n
        };
        Contact {
            phi,
            normal: rotation * local_normal,
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::Contact;
    use crate::testing::{
        at, close, close3, push_back_keeps_normal, reach_threshold, surface, unit,
    };
    use glam::{DMat3, DVec3};
    use softbody_scene::{TerrainShape, rotation_from_degrees};

    #[test]
    fn rotated_box() {
        let center = DVec3::new(1.0, 2.0, 3.0);
        let half = DVec3::new(1.0, 0.5, 2.0);
        let rotation = DVec3::new(30.0, 45.0, 60.0);
        let s = surface(TerrainShape::Box {
            center,
            half_extents: half,
            rotation,
        });
        let r = DMat3::from_quat(rotation_from_degrees(rotation));
        let world = |p: DVec3| center + r * p;
        let tol = 1e-14;

        // Outside a face.
        let c = at(&s, world(DVec3::new(1.3, 0.1, -0.5)));
        close(c.phi, 0.3, tol);
        close3(c.normal, r * DVec3::X, tol);
        // Outside an edge: Euclidean distance to the edge.
        let c = at(&s, world(DVec3::new(1.3, 0.9, 0.0)));
        close(c.phi, 0.5, tol);
        close3(c.normal, r * DVec3::new(0.6, 0.8, 0.0), tol);
        // Outside a corner.
        let c = at(&s, world(DVec3::new(1.2, -0.8, 2.6)));
        close(c.phi, 0.7, tol);
        close3(c.normal, r * DVec3::new(0.2, -0.3, 0.6) / 0.7, tol);
        // Inside: nearest face is +y at 0.2 (x at 0.8, z at 0.5).
        let c = at(&s, world(DVec3::new(0.2, 0.3, -1.5)));
        close(c.phi, -0.2, tol);
        close3(c.normal, r * DVec3::Y, tol);
        unit(c.normal);
        // Exactly on a face (up to the rotation's rounding): that face's normal, from geometry.
        let c = at(&s, world(DVec3::new(0.3, -0.5, 1.0)));
        close(c.phi, 0.0, 1e-15);
        assert_eq!(
            c.normal,
            r * DVec3::NEG_Y,
            "on-face normal is the exact face column"
        );
        // On an edge and a corner, the normal is still one of the adjacent faces'.
        let c = at(&s, world(DVec3::new(1.0, 0.5, 0.0)));
        close(c.phi, 0.0, 1e-15);
        assert!(c.normal == r * DVec3::X || c.normal == r * DVec3::Y);
        push_back_keeps_normal(&s, world(DVec3::new(1.3, 0.1, -0.5)), 1e-15);
        push_back_keeps_normal(&s, world(DVec3::new(0.2, 0.3, -1.5)), 1e-15);
        // Pushed back onto an edge, the normal may switch to either face; it must be one.
        let x = world(DVec3::new(1.3, 0.9, 0.0));
        let c = at(&s, x);
        let d = at(&s, x - c.phi * c.normal);
        close(d.phi, 0.0, 1e-14);
        assert!(
            d.normal == r * DVec3::X || d.normal == r * DVec3::Y,
            "{}",
            d.normal
        );
        reach_threshold(&s, world(DVec3::new(1.2, -0.8, 2.6)));
        reach_threshold(&s, world(DVec3::new(0.2, 0.3, -1.5)));
        // Axis-aligned: exact φ, exact threshold.
        let aligned = surface(TerrainShape::Box {
            center: DVec3::ZERO,
            half_extents: DVec3::ONE,
            rotation: DVec3::ZERO,
        });
        let x = DVec3::new(0.0, 1.25, 0.0);
        assert_eq!(
            at(&aligned, x),
            Contact {
                phi: 0.25,
                normal: DVec3::Y
            }
        );
        assert_eq!(aligned.query(x, 0.25), None);
        // A big box exactly on a face: parry's feature id says Unknown there; ours does not.
        let big = surface(TerrainShape::Box {
            center: DVec3::ZERO,
            half_extents: DVec3::new(4.0, 3.0, 5.0),
            rotation: DVec3::ZERO,
        });
        assert_eq!(
            at(&big, DVec3::new(1.0, 3.0, -2.0)),
            Contact {
                phi: 0.0,
                normal: DVec3::Y
            }
        );
    }
}
