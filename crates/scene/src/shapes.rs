//! Closed triangle meshes made in code: a torus and a star prism (non-convex shapes for mesh
//! bodies: the scenes' `torus.obj` and `star.obj` are written from these by
//! `examples/mesh_shapes.rs`, and the tests voxelise them), besides [`TriangleMesh::cube`].
//!
//! Every mesh is closed, with its triangles counter-clockwise seen from outside, and the
//! y axis up.

use std::f64::consts::TAU;

use glam::DVec3;

use crate::scene::TriangleMesh;

impl TriangleMesh {
    /// A torus lying flat (its axis along y, centred on the origin): the tube of radius
    /// `minor` around the circle of radius `major` in the xz-plane, `around` segments along
    /// the ring and `across` around the tube; vertex (i, j) is `i·across + j`, quads split
    /// along the same diagonal. Volume 2π²Rr² in the limit (the polygon's is smaller).
    pub fn torus(major: f64, minor: f64, around: u32, across: u32) -> TriangleMesh {
        let (around, across) = (around.max(3), across.max(3));
        let mut vertices = Vec::with_capacity((around * across) as usize);
        for i in 0..around {
            let u = TAU * f64::from(i) / f64::from(around);
            for j in 0..across {
                let v = TAU * f64::from(j) / f64::from(across);
                let rho = major + minor * v.cos();
                vertices.push(DVec3::new(rho * u.cos(), minor * v.sin(), rho * u.sin()));
            }
        }
        let at = |i: u32, j: u32| (i % around) * across + j % across;
        let mut triangles = Vec::with_capacity(2 * vertices.len());
        for i in 0..around {
            for j in 0..across {
                // ∂P/∂u × ∂P/∂v points into the tube (at u = v = 0: z × y = −x), so each
                // quad (a, b, c, d) = (u, v), (u + du, v), (u + du, v + dv), (u, v + dv)
                // is wound the other way.
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                triangles.push([a, c, b]);
                triangles.push([a, d, c]);
            }
        }
        TriangleMesh {
            path: "torus.obj".into(),
            vertices,
            triangles,
        }
    }

    /// A star prism: the star polygon of `points` tips at radius `outer` and notches at radius
    /// `inner` in the xz-plane (the first tip on +x), extruded from y = −thickness/2 to
    /// +thickness/2. Caps are fans from their centre vertex (the star is star-shaped about it);
    /// vertices: the bottom centre, the top centre, then the outline's bottom and top rings.
    pub fn star_prism(points: u32, outer: f64, inner: f64, thickness: f64) -> TriangleMesh {
        let n = 2 * points.max(2);
        let half = 0.5 * thickness;
        let mut vertices = vec![DVec3::new(0.0, -half, 0.0), DVec3::new(0.0, half, 0.0)];
        for k in 0..n {
            let a = TAU * f64::from(k) / f64::from(n);
            let r = if k % 2 == 0 { outer } else { inner };
            vertices.push(DVec3::new(r * a.cos(), -half, r * a.sin()));
        }
        for k in 0..n {
            let p = vertices[2 + k as usize];
            vertices.push(DVec3::new(p.x, half, p.z));
        }
        let bottom = |k: u32| 2 + k % n;
        let top = |k: u32| 2 + n + k % n;
        let mut triangles = Vec::with_capacity(4 * n as usize);
        for k in 0..n {
            // The outline runs counter-clockwise seen from −y (x towards z), so the bottom fan
            // (seen from below) keeps its order and the top fan reverses it.
            triangles.push([0, bottom(k), bottom(k + 1)]);
            triangles.push([1, top(k + 1), top(k)]);
            triangles.push([bottom(k), top(k), top(k + 1)]);
            triangles.push([bottom(k), top(k + 1), bottom(k + 1)]);
        }
        TriangleMesh {
            path: "star.obj".into(),
            vertices,
            triangles,
        }
    }

    /// The mesh as Wavefront OBJ text: `v` lines in shortest round-trip form, then 1-based `f`
    /// lines, after a `#` comment line.
    pub fn to_obj(&self, comment: &str) -> String {
        let mut out = String::new();
        for line in comment.lines() {
            out.push_str(&format!("# {line}\n"));
        }
        for v in &self.vertices {
            out.push_str(&format!("v {:?} {:?} {:?}\n", v.x, v.y, v.z));
        }
        for [a, b, c] in &self.triangles {
            out.push_str(&format!("f {} {} {}\n", a + 1, b + 1, c + 1));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxel::{enclosed_volume, winding_number};

    /// Both are closed and wound outwards: positive volume (the torus's close to 2π²Rr², the
    /// star's its area × thickness), w = 1 inside, 0 in the torus's hole and between the tips.
    #[test]
    fn shapes_are_closed_outward_and_measure_as_they_should() {
        let t = TriangleMesh::torus(1.0, 0.25, 96, 48);
        let v = enclosed_volume(&t.vertices, &t.triangles);
        let smooth = 2.0 * std::f64::consts::PI.powi(2) * 0.25f64.powi(2);
        assert!(
            v > 0.0 && (v - smooth).abs() < 0.005 * smooth,
            "{v} vs {smooth}"
        );
        let w = |p: DVec3| winding_number(&t.vertices, &t.triangles, p);
        assert!((w(DVec3::new(1.0, 0.0, 0.0)) - 1.0).abs() < 1e-9);
        assert!(w(DVec3::ZERO).abs() < 1e-9);

        let s = TriangleMesh::star_prism(5, 1.0, 0.5, 0.2);
        // The star is 10 triangles (centre, tip, notch) of area ½·1·0.5·sin 36°.
        let area = 10.0 * 0.5 * 0.5 * 36f64.to_radians().sin();
        let v = enclosed_volume(&s.vertices, &s.triangles);
        assert!((v - area * 0.2).abs() < 1e-12, "{v} vs {}", area * 0.2);
        let w = |p: DVec3| winding_number(&s.vertices, &s.triangles, p);
        assert!((w(DVec3::new(0.9, 0.0, 0.0)) - 1.0).abs() < 1e-9);
        let between = 0.8 * DVec3::new(36f64.to_radians().cos(), 0.0, 36f64.to_radians().sin());
        assert!(w(between).abs() < 1e-9);
    }
}
