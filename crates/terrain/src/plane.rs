//! Plane terrain: the half-space below the plane is solid. φ = n̂·(x − point), N = n̂.
//! Planes are the common ground, so [`Surface::query`](crate::Surface::query) answers them
//! inline and [`Surface::clear_of`](crate::Surface::clear_of) lets particles in the air skip
//! them.

use glam::DVec3;
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::HalfSpace;

use crate::Contact;

/// A plane of the terrain ([`Surface::plane`](crate::Surface::plane)).
#[derive(Debug, Clone)]
pub struct PlaneGeometry {
    point: DVec3,
    half_space: HalfSpace,
}

impl PlaneGeometry {
    /// None for a zero normal or a point that is not finite.
    pub(crate) fn new(point: DVec3, normal: DVec3) -> Option<PlaneGeometry> {
        // Scenes built in code may skip validation's unit-length guarantee.
        let n = normal.normalize_or_zero();
        (n != DVec3::ZERO && point.is_finite()).then(|| PlaneGeometry {
            point,
            half_space: HalfSpace::new(n),
        })
    }

    /// Parry's half-space distance is exactly n̂·(x − point): two flops per axis.
    #[inline]
    pub(crate) fn phi(&self, x: DVec3) -> f64 {
        self.half_space
            .distance_to_local_point(x - self.point, false)
    }

    /// Whether `x` lies at least `reach` above the plane (φ ≥ reach): what
    /// [`Surface::clear_of`](crate::Surface::clear_of) answers for a plane. Small and
    /// branch-free, so that a loop over many particles vectorises.
    #[inline(always)]
    pub fn clear_of(&self, x: DVec3, reach: f64) -> bool {
        self.phi(x) >= reach
    }

    #[inline]
    pub(crate) fn contact(&self, x: DVec3) -> Contact {
        Contact {
            phi: self.phi(x),
            normal: self.half_space.normal,
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::testing::{at, close, close3, reach_threshold, surface};
    use glam::DVec3;
    use softbody_scene::TerrainShape;

    #[test]
    fn plane_tilted() {
        let point = DVec3::new(1.0, 2.0, 3.0);
        // Length 3, deliberately not unit: Surface::new normalises.
        let s = surface(TerrainShape::Plane {
            point,
            normal: DVec3::new(1.0, 2.0, 2.0),
        });
        let n = DVec3::new(1.0, 2.0, 2.0) / 3.0;
        let tangent = DVec3::new(2.0, -1.0, 0.0);
        for (offset, tol) in [(0.6, 1e-15), (-0.9, 1e-15), (0.0, 1e-15)] {
            let c = at(&s, point + offset * n + tangent);
            close(c.phi, offset, tol);
            close3(c.normal, n, 1e-16);
            assert_eq!(
                c.normal,
                at(&s, point).normal,
                "plane normal is the same everywhere"
            );
        }
        assert_eq!(at(&s, point).phi, 0.0);
        reach_threshold(&s, point + 0.6 * n + tangent);
        // Deep below, small reach: still a contact.
        close(s.query(point - 100.0 * n, 0.01).unwrap().phi, -100.0, 1e-12);
        assert_eq!(s.query(point + 100.0 * n, 0.01), None);
    }
}
