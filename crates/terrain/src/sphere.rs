//! Sphere and bowl terrain: the solid ball (φ = |x − c| − R, N = (x − c)/|x − c|), or the
//! bowl whose inside is free space (φ = R − |x − c|, N = (c − x)/|x − c|); N = +y within ε
//! of the centre, where no direction is radial.

use glam::DVec3;
use parry3d_f64::shape::Ball;

use crate::{Contact, eps_for};

#[derive(Debug, Clone)]
pub(crate) struct BallGeometry {
    center: DVec3,
    ball: Ball,
    /// The inside is free space.
    bowl: bool,
    eps: f64,
}

impl BallGeometry {
    pub(crate) fn new(center: DVec3, radius: f64, bowl: bool) -> BallGeometry {
        BallGeometry {
            center,
            ball: Ball::new(radius),
            bowl,
            eps: eps_for(center.length() + radius.abs()),
        }
    }

    /// ∂N/∂x of [`BallGeometry::contact`]'s normal.
    pub(crate) fn normal_jacobian(&self, x: DVec3) -> glam::DMat3 {
        let d = x - self.center;
        let r = d.length();
        if r <= self.eps {
            return glam::DMat3::ZERO;
        }
        let u = d / r;
        let tangent =
            (glam::DMat3::IDENTITY - glam::DMat3::from_cols(u * u.x, u * u.y, u * u.z)) / r;
        if self.bowl { -tangent } else { tangent }
    }

    pub(crate) fn contact(&self, x: DVec3) -> Contact {
        let d = x - self.center;
        let r = d.length();
        // |x − c| − R loses nothing near the surface, unlike the distance to parry's
        // projected point, and the radial direction is exact there.
        let radial = if r > self.eps { d / r } else { DVec3::Y };
        if self.bowl {
            Contact {
                phi: self.ball.radius - r,
                normal: if r > self.eps { -radial } else { DVec3::Y },
            }
        } else {
            Contact {
                phi: r - self.ball.radius,
                normal: radial,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::Contact;
    use crate::testing::{
        at, close, close3, push_back_keeps_normal, reach_threshold, surface, unit,
    };
    use glam::DVec3;
    use softbody_scene::TerrainShape;

    /// ∂N/∂x against central differences of the normal: N is smooth off the centre, so the
    /// difference's error is O(δ²·|∂³N|) ≈ δ²/r³, 1e-8 at δ = 1e-4 and r ≥ 0.5, over a rounding
    /// error of 1e-16/δ.
    #[test]
    fn normal_jacobians_are_the_normals_derivatives() {
        let center = DVec3::new(1.0, -2.0, 0.5);
        for shape in [
            TerrainShape::Sphere {
                center,
                radius: 2.0,
            },
            TerrainShape::Bowl {
                center,
                radius: 2.0,
            },
            TerrainShape::Plane {
                point: center,
                normal: DVec3::new(0.3, 1.0, -0.2),
            },
        ] {
            let s = surface(shape.clone());
            for x in [
                center + DVec3::new(0.4, 0.3, -0.2),
                center + DVec3::new(-2.5, 1.0, 0.7),
            ] {
                let j = s.normal_jacobian(x);
                let delta = 1e-4;
                for k in 0..3 {
                    let e = DVec3::AXES[k] * delta;
                    let fd = (at(&s, x + e).normal - at(&s, x - e).normal) / (2.0 * delta);
                    assert!(
                        (j.col(k) - fd).length() < 1e-7,
                        "{shape:?} {x} {k}: {} {fd}",
                        j.col(k)
                    );
                }
            }
        }
    }

    #[test]
    fn sphere_and_bowl() {
        let center = DVec3::new(1.0, -2.0, 0.5);
        let radius = 2.0;
        let sphere = surface(TerrainShape::Sphere { center, radius });
        let bowl = surface(TerrainShape::Bowl { center, radius });
        let dir = DVec3::new(2.0, -3.0, 6.0) / 7.0;
        for r in [3.0, 0.5, 2.0] {
            let x = center + r * dir;
            let s = at(&sphere, x);
            let b = at(&bowl, x);
            close(s.phi, r - radius, 1e-15);
            close(b.phi, radius - r, 1e-15);
            close3(s.normal, dir, 1e-15);
            close3(b.normal, -dir, 1e-15);
            unit(s.normal);
        }
        // The centre: deepest point of the ball, farthest from the bowl's wall.
        assert_eq!(
            at(&sphere, center),
            Contact {
                phi: -radius,
                normal: DVec3::Y
            }
        );
        assert_eq!(at(&bowl, center).phi, radius);
        push_back_keeps_normal(&sphere, center + 2.3 * dir, 1e-15);
        push_back_keeps_normal(&bowl, center + 1.7 * dir, 1e-15);
        reach_threshold(&sphere, center + 3.0 * dir);
        reach_threshold(&bowl, center + 0.5 * dir);
        // Exact φ = 1: the threshold on representable numbers.
        let unit_ball = surface(TerrainShape::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
        });
        let x = DVec3::new(2.0, 0.0, 0.0);
        assert_eq!(unit_ball.query(x, 1.0), None);
        assert_eq!(unit_ball.query(x, 1.0f64.next_up()).unwrap().phi, 1.0);
        // A point outside the bowl is deep in its solid.
        close(
            bowl.query(center + 10.0 * dir, 0.01).unwrap().phi,
            -8.0,
            1e-14,
        );
    }
}
