//! The pinhole camera.
//!
//! With eye e, forward f = (to − e)/|to − e|, right r = (f × up)/|f × up| and true up u = r × f,
//! a point p has camera coordinates (x_c, y_c, z_c) = ((p − e)·r, (p − e)·u, (p − e)·f) and is
//! seen at the pixel position
//!
//! (W/2 + F·x_c/z_c, H/2 − F·y_c/z_c),  F = (H/2) / tan(fov_y/2),
//!
//! in pixels from the image's top-left corner, x to the right and y down: pixel (i, j) covers
//! [i, i + 1) × [j, j + 1) and its centre is (i + ½, j + ½).

use glam::{DVec2, DVec3};

/// Points nearer to the eye than this (metres along the view direction) are clipped away.
pub const NEAR: f64 = 1e-3;

/// A perspective camera looking from `from` at `to`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// The eye, metres.
    pub from: DVec3,
    /// The point seen at the centre of the picture, metres.
    pub to: DVec3,
    /// Which way is up (need not be unit or perpendicular to the view; +y by default).
    pub up: DVec3,
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_y_degrees: f64,
}

/// The default vertical field of view, degrees.
pub const DEFAULT_FOV_Y_DEGREES: f64 = 40.0;

/// The direction (from the framed content towards the eye) of the automatic camera: in front
/// (+z), to the right (+x) and above (+y), about 35° above the horizontal, so that the tops of
/// boxes and the inside of a bowl are seen as well as the sides.
pub const DEFAULT_VIEW_DIRECTION: DVec3 = DVec3::new(0.5, 0.8, 1.0);

impl Camera {
    /// A camera at `from` looking at `to` with +y up and the default field of view.
    pub fn look_at(from: DVec3, to: DVec3) -> Camera {
        Camera {
            from,
            to,
            up: DVec3::Y,
            fov_y_degrees: DEFAULT_FOV_Y_DEGREES,
        }
    }

    /// The automatic camera for content inside the box [`lo`, `hi`] and a picture of
    /// `width` × `height` pixels: it looks at the box's centre from
    /// [`DEFAULT_VIEW_DIRECTION`], from just far enough that all eight corners of the box
    /// (each side widened to at least 0.5 m) are in view, plus 8 %.
    pub fn framing(lo: DVec3, hi: DVec3, width: u32, height: u32) -> Camera {
        Camera::framing_along(DEFAULT_VIEW_DIRECTION, lo, hi, width, height)
    }

    /// [`Camera::framing`] from `direction` (from the content towards the eye; not along +y).
    pub fn framing_along(
        direction: DVec3,
        lo: DVec3,
        hi: DVec3,
        width: u32,
        height: u32,
    ) -> Camera {
        let (lo, hi) = if lo.is_finite() && hi.is_finite() && lo.cmple(hi).all() {
            (lo, hi)
        } else {
            (DVec3::splat(-0.5), DVec3::splat(0.5))
        };
        let centre = 0.5 * (lo + hi);
        // At least a 0.5 m box, so that a single point still gets a view.
        let half = (0.5 * (hi - lo)).max(DVec3::splat(0.25));
        let half_y = (0.5 * DEFAULT_FOV_Y_DEGREES).to_radians();
        let aspect = f64::from(width.max(1)) / f64::from(height.max(1));
        let (tan_y, tan_x) = (half_y.tan(), half_y.tan() * aspect);
        let back = direction.normalize();
        let view = View::new(&Camera::look_at(centre + back, centre), width, height);
        // Corner o (from the centre) at eye distance d: camera coordinates (o·r, o·u, d + o·f);
        // it is in view when |o·r| ≤ (d + o·f) tan(fov_x/2) and |o·u| ≤ (d + o·f) tan(fov_y/2).
        let mut distance: f64 = 0.0;
        for i in 0..8 {
            let o = DVec3::new(
                if i & 1 == 0 { -half.x } else { half.x },
                if i & 2 == 0 { -half.y } else { half.y },
                if i & 4 == 0 { -half.z } else { half.z },
            );
            let c = view.to_camera(centre + o) - DVec3::new(0.0, 0.0, 1.0);
            distance = distance
                .max(c.x.abs() / tan_x - c.z)
                .max(c.y.abs() / tan_y - c.z)
                .max(half.length() + NEAR);
        }
        // 8 % spare around the box.
        Camera::look_at(centre + 1.08 * distance * back, centre)
    }

    /// Checks that the camera defines a view: finite, `from` ≠ `to`, the view not along `up`,
    /// and a field of view in (0°, 180°).
    pub fn validate(&self) -> Result<(), String> {
        if !(self.from.is_finite() && self.to.is_finite() && self.up.is_finite()) {
            return Err("the camera's points must be finite".into());
        }
        let forward = self.to - self.from;
        if forward.length() <= 1e-12 {
            return Err("the camera's position and target must differ".into());
        }
        if forward.normalize().cross(self.up).length() <= 1e-9 * self.up.length().max(1e-300) {
            return Err("the camera must not look straight along its up direction".into());
        }
        if !(self.fov_y_degrees > 0.0 && self.fov_y_degrees < 180.0) {
            return Err(format!(
                "the field of view must be in (0°, 180°), not {}°",
                self.fov_y_degrees
            ));
        }
        Ok(())
    }

    /// Where `p` is seen in a `width` × `height` picture, in pixels from the top-left corner
    /// (x right, y down), or `None` when it is not in front of the eye.
    pub fn project(&self, p: DVec3, width: u32, height: u32) -> Option<DVec2> {
        let view = View::new(self, width, height);
        let c = view.to_camera(p);
        (c.z > NEAR).then(|| view.to_screen(c))
    }
}

/// A camera's basis and focal length, ready to transform points.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View {
    pub eye: DVec3,
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    focal: f64,
    cx: f64,
    cy: f64,
}

impl View {
    /// The view of a validated camera.
    pub fn new(camera: &Camera, width: u32, height: u32) -> View {
        let forward = (camera.to - camera.from).normalize();
        let right = forward.cross(camera.up).normalize();
        let up = right.cross(forward);
        let cy = 0.5 * f64::from(height);
        View {
            eye: camera.from,
            right,
            up,
            forward,
            focal: cy / (0.5 * camera.fov_y_degrees.to_radians()).tan(),
            cx: 0.5 * f64::from(width),
            cy,
        }
    }

    /// The focal length F, pixels.
    pub fn focal(&self) -> f64 {
        self.focal
    }

    /// The picture's centre, x.
    pub fn cx(&self) -> f64 {
        self.cx
    }

    /// The picture's centre, y.
    pub fn cy(&self) -> f64 {
        self.cy
    }

    /// Camera coordinates (x right, y up, z along the view).
    pub fn to_camera(self, p: DVec3) -> DVec3 {
        let d = p - self.eye;
        DVec3::new(d.dot(self.right), d.dot(self.up), d.dot(self.forward))
    }

    /// The world point of camera coordinates `c`.
    pub fn to_world(self, c: DVec3) -> DVec3 {
        self.eye + c.x * self.right + c.y * self.up + c.z * self.forward
    }

    /// The pixel position of camera coordinates `c` with `c.z > 0`.
    pub fn to_screen(self, c: DVec3) -> DVec2 {
        DVec2::new(
            self.cx + self.focal * c.x / c.z,
            self.cy - self.focal * c.y / c.z,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed form: a camera at (0, 0, 5) looking at the origin along −z with a 90° field
    /// of view has F = H/2, so (x, y, 0) lands at (W/2 + (H/2)·x/5, H/2 − (H/2)·y/5).
    #[test]
    fn projection_matches_the_pinhole_formula() {
        let camera = Camera {
            from: DVec3::new(0.0, 0.0, 5.0),
            to: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_degrees: 90.0,
        };
        let (w, h) = (640, 480);
        let close = |a: DVec2, b: DVec2| (a - b).length() < 1e-9;
        assert!(close(
            camera.project(DVec3::ZERO, w, h).unwrap(),
            DVec2::new(320.0, 240.0)
        ));
        // x = 1 m at 5 m: 240 · 1/5 = 48 px right of the centre.
        assert!(close(
            camera.project(DVec3::new(1.0, 0.0, 0.0), w, h).unwrap(),
            DVec2::new(368.0, 240.0)
        ));
        // y = 2.5 m: 240 · 2.5/5 = 120 px up, so row 120.
        assert!(close(
            camera.project(DVec3::new(0.0, 2.5, 0.0), w, h).unwrap(),
            DVec2::new(320.0, 120.0)
        ));
        // The top-left corner of the view at depth 5: (−5·4/3, 5, 0) → (0, 0).
        assert!(close(
            camera
                .project(DVec3::new(-5.0 * 4.0 / 3.0, 5.0, 0.0), w, h)
                .unwrap(),
            DVec2::new(0.0, 0.0)
        ));
        // Twice as far, half the offset: (1, 0, −5) is 10 m away → 24 px.
        assert!(close(
            camera.project(DVec3::new(1.0, 0.0, -5.0), w, h).unwrap(),
            DVec2::new(344.0, 240.0)
        ));
        // Behind the eye: not seen.
        assert_eq!(camera.project(DVec3::new(0.0, 0.0, 6.0), w, h), None);
    }

    #[test]
    fn framing_sees_every_corner_of_the_box() {
        let (lo, hi) = (DVec3::new(-2.0, 0.0, -1.0), DVec3::new(3.0, 1.0, 0.5));
        let camera = Camera::framing(lo, hi, 320, 240);
        camera.validate().unwrap();
        assert_eq!(camera.to, 0.5 * (lo + hi));
        for i in 0..8 {
            let corner = DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let p = camera.project(corner, 320, 240).unwrap();
            assert!(
                (0.0..=320.0).contains(&p.x) && (0.0..=240.0).contains(&p.y),
                "{p}"
            );
        }
    }

    #[test]
    fn degenerate_cameras_are_refused() {
        assert!(Camera::look_at(DVec3::ONE, DVec3::ONE).validate().is_err());
        assert!(Camera::look_at(DVec3::Y, DVec3::ZERO).validate().is_err());
        assert!(
            Camera::look_at(DVec3::new(f64::NAN, 0.0, 0.0), DVec3::ZERO)
                .validate()
                .is_err()
        );
        assert!(Camera::look_at(DVec3::Z, DVec3::ZERO).validate().is_ok());
    }
}
