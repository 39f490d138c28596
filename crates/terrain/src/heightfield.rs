//! Heightfield terrain: the solid below the triangulated height surface, over the grid's
//! footprint only (the sign rule is in the crate doc), and the rule that splits a grid cell
//! into two triangles ([`CellTriangle`]), which the renderer and the tests follow too.

use glam::DVec3;
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::query::{PointQuery, PointQueryWithLocation};
use parry3d_f64::shape::{HeightField, Triangle};
use parry3d_f64::utils::Array2;

use crate::{Contact, eps_for, within};

/// One of the two triangles a heightfield cell is split into: the split rule every user of
/// heightfields follows (the queries here, the renderer's triangles;
/// `crates/gpu/shaders/shared/terrain.wgsl` states it again in WGSL).
///
/// World vertex (r, c) is `origin + (c·dx, heights[r][c], r·dz)`. Parry (default cell status,
/// no `ZIGZAG_SUBDIVISION`) splits the cell between rows r, r+1 and columns c, c+1 along the
/// diagonal from vertex (r+1, c) to vertex (r, c+1), i.e. from (x0, z1) to (x1, z0), into the
/// triangles
///
/// - (r, c), (r+1, c), (r, c+1): the one holding corner (x0, z0), where u + v ≤ 1 with
///   u = (x − x0)/dx and v = (z − z0)/dz; on the diagonal itself this one is used; and
/// - (r+1, c), (r+1, c+1), (r, c+1): where u + v > 1.
///
/// Any twin of the queries (the GPU's) and any picture of the terrain has to split cells the
/// same way, or the surfaces differ by up to half a cell's height variation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellTriangle {
    /// (r, c), (r+1, c), (r, c+1): the points with u + v ≤ 1.
    First,
    /// (r+1, c), (r+1, c+1), (r, c+1): the points with u + v > 1.
    Second,
}

impl CellTriangle {
    /// Both triangles of a cell, in parry's order (`HeightField::triangles_at`).
    pub const BOTH: [CellTriangle; 2] = [CellTriangle::First, CellTriangle::Second];

    /// The triangle holding the point at fractions u = (x − x0)/dx, v = (z − z0)/dz of its
    /// cell (each in [0, 1]).
    #[inline]
    pub fn at(u: f64, v: f64) -> CellTriangle {
        if u + v <= 1.0 {
            CellTriangle::First
        } else {
            CellTriangle::Second
        }
    }

    /// The corners, as (row, column) offsets from the cell's vertex (r, c), in parry's order:
    /// counter-clockwise seen from +y, so the triangle's normal points up, into free space.
    pub const fn corners(self) -> [[usize; 2]; 3] {
        match self {
            CellTriangle::First => [[0, 0], [1, 0], [0, 1]],
            CellTriangle::Second => [[1, 0], [1, 1], [0, 1]],
        }
    }

    /// The height of this triangle's plane at (u, v), from the cell's corner heights:
    /// `y[dr][dc]` is the height of vertex (r + dr, c + dc). Interpolated from the triangle's
    /// corner at the right angle in (u, v): (r, c) or (r+1, c+1).
    #[inline]
    pub fn height(self, u: f64, v: f64, y: [[f64; 2]; 2]) -> f64 {
        match self {
            CellTriangle::First => y[0][0] + u * (y[0][1] - y[0][0]) + v * (y[1][0] - y[0][0]),
            CellTriangle::Second => {
                y[1][1] + (1.0 - u) * (y[1][0] - y[1][1]) + (1.0 - v) * (y[0][1] - y[1][1])
            }
        }
    }
}

#[derive(Debug, Clone)]
pub(crate) struct HeightfieldGeometry {
    field: HeightField,
    /// World position of parry's local origin (the centre of the footprint at height
    /// `origin.y`).
    offset: DVec3,
    eps: f64,
}

/// The nearest triangle's contact.
struct Nearest {
    contact: Contact,
    /// |x − q|, q the nearest point.
    dist: f64,
    inside: bool,
    triangle: Triangle,
}

impl HeightfieldGeometry {
    /// None for a grid that validation would refuse.
    pub(crate) fn new(h: &softbody_scene::Heightfield) -> Option<HeightfieldGeometry> {
        let rows = h.heights.len();
        let cols = h.heights.first().map_or(0, Vec::len);
        let [dx, dz] = h.cell_size;
        let valid = rows >= 2
            && cols >= 2
            && h.heights
                .iter()
                .all(|row| row.len() == cols && row.iter().all(|y| y.is_finite()))
            && dx.is_finite()
            && dz.is_finite()
            && dx > 0.0
            && dz > 0.0
            && h.origin.is_finite();
        if !valid {
            return None;
        }
        // Array2 is column-major: element (row i, column j) sits at i + j·nrows.
        let mut data = Vec::with_capacity(rows * cols);
        for c in 0..cols {
            for row in &h.heights {
                data.push(row[c]);
            }
        }
        let heights = Array2::new(rows, cols, data);
        // Scale y = 1 keeps heights in metres; parry centres the footprint on its local origin.
        let scale = DVec3::new(dx * (cols - 1) as f64, 1.0, dz * (rows - 1) as f64);
        let field = HeightField::new(heights, scale);
        let offset = h.origin + DVec3::new(0.5 * scale.x, 0.0, 0.5 * scale.z);
        let aabb = field.root_aabb();
        let magnitude = (aabb.mins + offset)
            .abs()
            .max((aabb.maxs + offset).abs())
            .length();
        Some(HeightfieldGeometry {
            field,
            offset,
            eps: eps_for(magnitude),
        })
    }

    pub(crate) fn query(&self, x: DVec3, reach: f64) -> Option<Contact> {
        let nearest = self.nearest(x, reach)?;
        within(nearest.contact, reach)
    }

    /// ∂N/∂x ([`crate::nearest_point_jacobian`] at the nearest triangle's nearest feature).
    pub(crate) fn normal_jacobian(&self, x: DVec3) -> glam::DMat3 {
        let Some(n) = self.nearest(x, f64::INFINITY) else {
            return glam::DMat3::ZERO;
        };
        if n.dist <= self.eps {
            return glam::DMat3::ZERO;
        }
        let (_, location) = n
            .triangle
            .project_local_point_and_get_location(x - self.offset, false);
        let along = crate::triangle_feature_projector(&n.triangle, &location);
        crate::nearest_point_jacobian(n.contact.normal, n.dist, along, n.inside)
    }

    /// The contact with the nearest triangle, and which it is, or `None` where nothing is
    /// within `reach` (the search stops there).
    fn nearest(&self, x: DVec3, reach: f64) -> Option<Nearest> {
        let HeightfieldGeometry { field, offset, eps } = self;
        let p = x - *offset;

        // The surface point straight above or below p (p clamped into the footprint): it decides
        // inside/outside, and its distance bounds the search for the nearest triangle.
        let (i, j) = field.closest_cell_at_point(p);
        let (x_lo, x_hi) = (field.x_at(0), field.x_at(field.ncols()));
        let (z_lo, z_hi) = (field.z_at(0), field.z_at(field.nrows()));
        let in_footprint = p.x >= x_lo && p.x <= x_hi && p.z >= z_lo && p.z <= z_hi;
        let xc = p.x.clamp(x_lo, x_hi);
        let zc = p.z.clamp(z_lo, z_hi);
        let (x0, x1) = (field.x_at(j), field.x_at(j + 1));
        let (z0, z1) = (field.z_at(i), field.z_at(i + 1));
        // Parry locates the cell by dividing, x_at multiplies: clamp away the last-bit
        // disagreement.
        let u = ((xc - x0) / (x1 - x0)).clamp(0.0, 1.0);
        let v = ((zc - z0) / (z1 - z0)).clamp(0.0, 1.0);
        let hs = field.heights();
        let y = [
            [hs[(i, j)], hs[(i, j + 1)]],
            [hs[(i + 1, j)], hs[(i + 1, j + 1)]],
        ];
        let half = CellTriangle::at(u, v);
        let height = half.height(u, v, y);
        let (t_first, t_second) = field.triangles_at(i, j);
        let under = match half {
            CellTriangle::First => t_first,
            CellTriangle::Second => t_second,
        }?;
        let inside = in_footprint && p.y < height;

        if !inside {
            // Distances outside are >= 0, and the box around the surface bounds them from below:
            // cheap refusals for particles high above the terrain.
            if reach <= 0.0 || field.root_aabb().distance_to_local_point(p, true) >= reach {
                return None;
            }
        }

        let below = DVec3::new(xc, height, zc);
        let mut best_sq = (p - below).length_squared();
        let mut best_point = below;
        let mut best_triangle = under;
        // Inside, the true distance is at most the vertical one, however deep, so the search
        // stays bounded and deep points still get their exact φ. Outside, nothing beyond reach
        // matters.
        let radius = if inside {
            best_sq.sqrt()
        } else {
            best_sq.sqrt().min(reach)
        };
        let window = Aabb::new(p - DVec3::splat(radius), p + DVec3::splat(radius));
        field.map_elements_in_local_aabb(&window, &mut |_, triangle: &Triangle| {
            let proj = triangle.project_local_point(p, false);
            let sq = (p - proj.point).length_squared();
            // Strict: on ties the triangle under the point keeps its place, for a stable normal.
            if sq < best_sq {
                best_sq = sq;
                best_point = proj.point;
                best_triangle = *triangle;
            }
        });

        let dist = best_sq.sqrt();
        let phi = if inside { -dist } else { dist };
        let normal = if dist > *eps {
            if inside {
                (best_point - p) / dist
            } else {
                (p - best_point) / dist
            }
        } else {
            // Cells have positive width and depth, so every triangle has a normal, pointing up.
            best_triangle.normal().unwrap_or(DVec3::Y)
        };
        Some(Nearest {
            contact: Contact { phi, normal },
            dist,
            inside,
            triangle: best_triangle,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{
        Rng, against_reference, at, close, close3, flat_field, push_back_keeps_normal,
        reach_threshold, surface, unit,
    };
    use softbody_scene::{Heightfield, TerrainShape};

    #[test]
    fn heightfield_flat() {
        // Surface at y = −0.5 over x ∈ [10, 12], z ∈ [20, 24].
        let s = flat_field();
        let tol = 1e-14;
        let c = at(&s, DVec3::new(11.0, 0.5, 21.0));
        close(c.phi, 1.0, tol);
        close3(c.normal, DVec3::Y, tol);
        let c = at(&s, DVec3::new(10.5, -1.0, 23.0));
        close(c.phi, -0.5, tol);
        close3(c.normal, DVec3::Y, tol);
        let c = at(&s, DVec3::new(11.3, -0.5, 22.2));
        assert_eq!(c.phi, 0.0);
        close3(c.normal, DVec3::Y, 1e-15);
        // Beside the footprint: outside, distance to the rim.
        let c = at(&s, DVec3::new(13.0, -0.5, 22.0));
        close(c.phi, 1.0, tol);
        close3(c.normal, DVec3::X, tol);
        let c = at(&s, DVec3::new(13.0, -3.0, 22.0));
        close(c.phi, (1.0f64 + 2.5 * 2.5).sqrt(), tol);
        let c = at(&s, DVec3::new(9.0, 0.5, 22.0));
        close(c.phi, 2f64.sqrt(), tol);
        close3(c.normal, DVec3::new(-1.0, 1.0, 0.0) / 2f64.sqrt(), tol);
        // On the footprint's rim and corner.
        let c = at(&s, DVec3::new(12.0, -0.5, 24.0));
        close(c.phi, 0.0, tol);
        close3(c.normal, DVec3::Y, tol);
        // Small reach: far above is None (even inside the bounding box's footprint), deep below
        // is Some with its full depth.
        assert_eq!(s.query(DVec3::new(11.0, 5.0, 21.0), 1.0), None);
        close(
            s.query(DVec3::new(11.0, 5.0, 21.0), 6.0).unwrap().phi,
            5.5,
            tol,
        );
        let c = s.query(DVec3::new(11.0, -30.0, 21.0), 0.01).unwrap();
        close(c.phi, -29.5, tol);
        close3(c.normal, DVec3::Y, tol);
        reach_threshold(&s, DVec3::new(11.0, 0.5, 21.0));
        reach_threshold(&s, DVec3::new(9.0, 0.5, 22.0));
        reach_threshold(&s, DVec3::new(10.5, -1.0, 23.0));
    }

    #[test]
    fn heightfield_slope() {
        // h = a·(x − ox) + b·(z − oz): one plane, so both triangles of every cell lie in it.
        let (a, b) = (0.3, -0.2);
        let (dx, dz) = (0.5, 0.25);
        let origin = DVec3::new(-1.0, 2.0, 3.0);
        let heights: Vec<Vec<f64>> = (0..4)
            .map(|r| {
                (0..5)
                    .map(|c| a * c as f64 * dx + b * r as f64 * dz)
                    .collect()
            })
            .collect();
        let s = surface(TerrainShape::Heightfield(Heightfield {
            heights,
            cell_size: [dx, dz],
            origin,
        }));
        let surface_y = |x: f64, z: f64| origin.y + a * (x - origin.x) + b * (z - origin.z);
        let n = DVec3::new(-a, 1.0, -b).normalize();
        let cos = 1.0 / (1.0 + a * a + b * b).sqrt();
        for (px, pz) in [(-0.3, 3.4), (0.6, 3.6), (0.1, 3.15)] {
            for delta in [0.1, -0.1, 0.0] {
                let x = DVec3::new(px, surface_y(px, pz) + delta, pz);
                let c = at(&s, x);
                close(c.phi, delta * cos, 1e-14);
                close3(c.normal, n, 1e-12);
                unit(c.normal);
            }
            push_back_keeps_normal(&s, DVec3::new(px, surface_y(px, pz) + 0.05, pz), 1e-12);
            reach_threshold(&s, DVec3::new(px, surface_y(px, pz) + 0.1, pz));
            reach_threshold(&s, DVec3::new(px, surface_y(px, pz) - 0.1, pz));
        }
    }

    #[test]
    fn heightfield_diagonal() {
        // One cell, corner (r+1, c+1) raised: the split from (r+1, c) to (r, c+1) leaves the
        // triangle holding (x0, z0) flat and lifts the other to a ridge-free ramp.
        let s = surface(TerrainShape::Heightfield(Heightfield {
            heights: vec![vec![0.0, 0.0], vec![0.0, 1.0]],
            cell_size: [1.0, 1.0],
            origin: DVec3::ZERO,
        }));
        // Centre of the cell lies on the diagonal, at height 0 (the other split gives 0.5).
        let c = at(&s, DVec3::new(0.5, 0.0, 0.5));
        close(c.phi, 0.0, 1e-15);
        let c = at(&s, DVec3::new(0.25, 0.0, 0.25));
        close(c.phi, 0.0, 1e-15);
        close3(c.normal, DVec3::Y, 1e-15);
        // In the raised triangle h = u + v − 1.
        let c = at(&s, DVec3::new(0.75, 0.5, 0.75));
        close(c.phi, 0.0, 1e-15);
        close3(c.normal, DVec3::new(-1.0, 1.0, -1.0) / 3f64.sqrt(), 1e-15);
        let c = at(&s, DVec3::new(0.75, 0.0, 0.75));
        assert!(c.phi < 0.0, "below the ramp is inside: {}", c.phi);
        close(c.phi, -0.5 / 3f64.sqrt(), 1e-15);
        // A point on the diagonal takes the (x0, z0) triangle's normal.
        close3(at(&s, DVec3::new(0.5, 0.0, 0.5)).normal, DVec3::Y, 1e-15);
    }

    #[test]
    fn split_rule_is_parrys() {
        let mut rng = Rng::new(5);
        let (rows, cols) = (3, 4);
        let h = Heightfield {
            heights: (0..rows)
                .map(|_| (0..cols).map(|_| rng.range(-0.6, 0.6)).collect())
                .collect(),
            cell_size: [0.4, 0.7],
            origin: DVec3::new(-1.0, 0.3, 2.0),
        };
        let g = HeightfieldGeometry::new(&h).unwrap();
        let vertex = |r: usize, c: usize| {
            h.origin
                + DVec3::new(
                    c as f64 * h.cell_size[0],
                    h.heights[r][c],
                    r as f64 * h.cell_size[1],
                )
        };
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                let (first, second) = g.field.triangles_at(r, c);
                for (half, parry) in CellTriangle::BOTH.into_iter().zip([first, second]) {
                    let parry = parry.unwrap();
                    let ours = half.corners().map(|[dr, dc]| vertex(r + dr, c + dc));
                    for (p, q) in [parry.a, parry.b, parry.c].into_iter().zip(ours) {
                        close3(p + g.offset, q, 1e-12);
                    }
                    let [a, b, t] = ours;
                    assert!((b - a).cross(t - a).y > 0.0, "counter-clockwise from +y");
                }
            }
        }
        // Corners and the diagonal belong where the rule says.
        assert_eq!(CellTriangle::at(0.0, 0.0), CellTriangle::First);
        assert_eq!(CellTriangle::at(0.5, 0.5), CellTriangle::First);
        assert_eq!(CellTriangle::at(0.5, 0.501), CellTriangle::Second);
        assert_eq!(CellTriangle::at(1.0, 1.0), CellTriangle::Second);
        let y = [[1.0, 2.0], [3.0, 5.0]];
        for half in CellTriangle::BOTH {
            for [dr, dc] in half.corners() {
                assert_eq!(half.height(dc as f64, dr as f64, y), y[dr][dc]);
            }
        }
    }

    #[test]
    fn heightfield_matches_brute_force() {
        let mut rng = Rng::new(7);
        let (rows, cols) = (4, 6);
        let heights: Vec<Vec<f64>> = (0..rows)
            .map(|_| (0..cols).map(|_| rng.range(-0.6, 0.6)).collect())
            .collect();
        let (dx, dz) = (0.4, 0.7);
        let origin = DVec3::new(-1.0, 0.3, 2.0);
        let s = surface(TerrainShape::Heightfield(Heightfield {
            heights: heights.clone(),
            cell_size: [dx, dz],
            origin,
        }));
        // The split rule's triangulation, in world coordinates, built without parry's grid code.
        let vertex =
            |r: usize, c: usize| origin + DVec3::new(c as f64 * dx, heights[r][c], r as f64 * dz);
        let mut triangles = Vec::new();
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                for half in CellTriangle::BOTH {
                    let [a, b, t] = half.corners().map(|[dr, dc]| vertex(r + dr, c + dc));
                    triangles.push(Triangle::new(a, b, t));
                }
            }
        }
        let reference = |x: DVec3| {
            let dist = triangles
                .iter()
                .map(|t| (x - t.project_local_point(x, false).point).length())
                .fold(f64::INFINITY, f64::min);
            let (u, v) = ((x.x - origin.x) / dx, (x.z - origin.z) / dz);
            let in_footprint =
                (0.0..=(cols - 1) as f64).contains(&u) && (0.0..=(rows - 1) as f64).contains(&v);
            if !in_footprint {
                return dist;
            }
            let (c, r) = (
                (u.floor() as usize).min(cols - 2),
                (v.floor() as usize).min(rows - 2),
            );
            let (fu, fv) = (u - c as f64, v - r as f64);
            let y = |r: usize, c: usize| origin.y + heights[r][c];
            let h = if fu + fv <= 1.0 {
                y(r, c) + fu * (y(r, c + 1) - y(r, c)) + fv * (y(r + 1, c) - y(r, c))
            } else {
                y(r + 1, c + 1)
                    + (1.0 - fu) * (y(r + 1, c) - y(r + 1, c + 1))
                    + (1.0 - fv) * (y(r, c + 1) - y(r + 1, c + 1))
            };
            if x.y < h { -dist } else { dist }
        };
        against_reference(
            &s,
            reference,
            DVec3::new(-1.8, -1.5, 1.2),
            DVec3::new(1.8, 1.5, 5.0),
            11,
        );
    }
}
