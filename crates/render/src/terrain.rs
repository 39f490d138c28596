//! Terrain shapes as triangles to draw.
//!
//! - plane: a square of (2n)² checkered tiles centred on the drawn content's projection onto the
//!   plane, tile edges t = 1, 2 or 5 × 10^k m with about ten tiles per half side, aligned to the
//!   plane's `point` so that the pattern stays put whatever the framing;
//! - box: its 6 faces, 2 triangles each, corners c + R(±h_x, ±h_y, ±h_z) with R from the
//!   scene's rotation (degrees about x, then y, then z);
//! - sphere: a UV sphere of [`SPHERE_SLICES`] × [`SPHERE_STACKS`] cells;
//! - bowl: the lower half (y ≤ centre) of its sphere, seen from inside, [`SPHERE_SLICES`] ×
//!   [`SPHERE_STACKS`]/2 cells: the upper half would only hide the inside;
//! - heightfield: each grid cell split into two triangles along the diagonal from vertex
//!   (r + 1, c) to (r, c + 1), by the rule the solvers' collision queries use
//!   ([`CellTriangle`]), cells checkered;
//! - mesh: its own triangles.

use glam::DVec3;
use softbody_scene::{Terrain, TerrainShape, rotation_from_degrees};
use softbody_terrain::CellTriangle;

/// Segments around a sphere's axis.
pub const SPHERE_SLICES: usize = 32;
/// Segments from pole to pole.
pub const SPHERE_STACKS: usize = 16;

/// The two ground tile colours.
const GROUND: [[u8; 3]; 2] = [[176, 184, 166], [146, 156, 138]];
const BOX: [u8; 3] = [200, 186, 158];
const SPHERE: [u8; 3] = [172, 174, 186];
const BOWL: [u8; 3] = [186, 180, 168];
const HEIGHTFIELD: [[u8; 3]; 2] = [[158, 182, 136], [138, 162, 118]];
const MESH: [u8; 3] = [180, 172, 158];

/// A terrain triangle and its unshaded colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerrainTriangle {
    /// Corners, metres.
    pub corners: [DVec3; 3],
    /// Base colour, before lighting.
    pub color: [u8; 3],
}

/// The triangles of every terrain shape; planes are sized around the content in the sphere of
/// `focus_centre` and `focus_radius`.
pub fn triangulate(
    terrain: &[Terrain],
    focus_centre: DVec3,
    focus_radius: f64,
) -> Vec<TerrainTriangle> {
    let mut out = Vec::new();
    for t in terrain {
        match &t.shape {
            TerrainShape::Plane { point, normal } => {
                plane(&mut out, *point, *normal, focus_centre, focus_radius)
            }
            TerrainShape::Box {
                center,
                half_extents,
                rotation,
            } => cuboid(&mut out, *center, *half_extents, *rotation),
            TerrainShape::Sphere { center, radius } => {
                sphere(&mut out, *center, *radius, SPHERE_STACKS, SPHERE)
            }
            TerrainShape::Bowl { center, radius } => {
                sphere(&mut out, *center, *radius, SPHERE_STACKS / 2, BOWL)
            }
            TerrainShape::Heightfield(h) => {
                let rows = h.heights.len();
                let cols = h.heights.first().map_or(0, Vec::len);
                let at = |r: usize, c: usize| {
                    h.origin
                        + DVec3::new(
                            c as f64 * h.cell_size[0],
                            h.heights[r].get(c).copied().unwrap_or(0.0),
                            r as f64 * h.cell_size[1],
                        )
                };
                for r in 0..rows.saturating_sub(1) {
                    for c in 0..cols.saturating_sub(1) {
                        let color = HEIGHTFIELD[(r + c) % 2];
                        for half in CellTriangle::BOTH {
                            out.push(TerrainTriangle {
                                corners: half.corners().map(|[dr, dc]| at(r + dr, c + dc)),
                                color,
                            });
                        }
                    }
                }
            }
            TerrainShape::Mesh(m) => {
                for tri in &m.triangles {
                    let v = |k: u32| m.vertices.get(k as usize).copied();
                    if let (Some(a), Some(b), Some(c)) = (v(tri[0]), v(tri[1]), v(tri[2])) {
                        out.push(TerrainTriangle {
                            corners: [a, b, c],
                            color: MESH,
                        });
                    }
                }
            }
        }
    }
    out
}

/// The box [lo, hi] holding every finite terrain shape (planes are unbounded and left out),
/// or `None` without any.
pub fn bounds(terrain: &[Terrain]) -> Option<(DVec3, DVec3)> {
    let mut lo = DVec3::INFINITY;
    let mut hi = DVec3::NEG_INFINITY;
    let mut add = |p: DVec3| {
        lo = lo.min(p);
        hi = hi.max(p);
    };
    for t in terrain {
        match &t.shape {
            TerrainShape::Plane { .. } => {}
            TerrainShape::Box {
                center,
                half_extents,
                rotation,
            } => box_corners(*center, *half_extents, *rotation)
                .into_iter()
                .for_each(&mut add),
            TerrainShape::Sphere { center, radius } => {
                add(*center - DVec3::splat(*radius));
                add(*center + DVec3::splat(*radius));
            }
            TerrainShape::Bowl { center, radius } => {
                add(*center - DVec3::splat(*radius));
                add(*center + DVec3::new(*radius, 0.0, *radius));
            }
            TerrainShape::Heightfield(h) => {
                for (r, row) in h.heights.iter().enumerate() {
                    for (c, &y) in row.iter().enumerate() {
                        add(h.origin
                            + DVec3::new(c as f64 * h.cell_size[0], y, r as f64 * h.cell_size[1]));
                    }
                }
            }
            TerrainShape::Mesh(m) => m.vertices.iter().copied().for_each(&mut add),
        }
    }
    (lo.cmple(hi).all()).then_some((lo, hi))
}

/// The nice length (1, 2 or 5 × 10^k) nearest below `x` > 0.
fn nice(x: f64) -> f64 {
    let p = 10f64.powf(x.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&v| v <= x)
        .unwrap_or(p)
}

fn plane(out: &mut Vec<TerrainTriangle>, point: DVec3, normal: DVec3, focus: DVec3, radius: f64) {
    let n = normal.normalize();
    // Tile axes: world x (else z) flattened onto the plane, so a level ground's tiles follow
    // the world axes.
    let seed = if n.cross(DVec3::X).length() > 0.1 {
        DVec3::X
    } else {
        DVec3::Z
    };
    let t1 = (seed - seed.dot(n) * n).normalize();
    let t2 = n.cross(t1);
    let half = (3.0 * radius).max(2.0);
    let tile = nice(half / 10.0);
    // (Less a hair, so that an exact multiple of the tile is not rounded up a tile.)
    let cells = (half / tile - 1e-9).ceil() as i64;
    // The focus's tile, counted from `point`.
    let d = focus - point;
    let (u0, v0) = (
        (d.dot(t1) / tile).round() as i64,
        (d.dot(t2) / tile).round() as i64,
    );
    let at = |u: i64, v: i64| point + (u as f64 * tile) * t1 + (v as f64 * tile) * t2;
    for v in v0 - cells..v0 + cells {
        for u in u0 - cells..u0 + cells {
            let color = GROUND[(u + v).rem_euclid(2) as usize];
            let (a, b, c, e) = (at(u, v), at(u + 1, v), at(u + 1, v + 1), at(u, v + 1));
            out.push(TerrainTriangle {
                corners: [a, b, c],
                color,
            });
            out.push(TerrainTriangle {
                corners: [a, c, e],
                color,
            });
        }
    }
}

/// A box's corners; bit 0 of the index picks +x, bit 1 +y, bit 2 +z (in the box's frame).
fn box_corners(center: DVec3, half: DVec3, rotation: DVec3) -> [DVec3; 8] {
    let r = rotation_from_degrees(rotation);
    std::array::from_fn(|i| {
        let s = DVec3::new(
            if i & 1 == 0 { -1.0 } else { 1.0 },
            if i & 2 == 0 { -1.0 } else { 1.0 },
            if i & 4 == 0 { -1.0 } else { 1.0 },
        );
        center + r * (s * half)
    })
}

fn cuboid(out: &mut Vec<TerrainTriangle>, center: DVec3, half: DVec3, rotation: DVec3) {
    let corners = box_corners(center, half, rotation);
    // Faces by corner index (bit 0: x, bit 1: y, bit 2: z), counter-clockwise from outside.
    const FACES: [[usize; 4]; 6] = [
        [0, 4, 6, 2], // −x
        [1, 3, 7, 5], // +x
        [0, 1, 5, 4], // −y
        [2, 6, 7, 3], // +y
        [0, 2, 3, 1], // −z
        [4, 5, 7, 6], // +z
    ];
    for f in FACES {
        let [a, b, c, d] = f.map(|i| corners[i]);
        out.push(TerrainTriangle {
            corners: [a, b, c],
            color: BOX,
        });
        out.push(TerrainTriangle {
            corners: [a, c, d],
            color: BOX,
        });
    }
}

/// The UV sphere's cells from the south pole up `stacks` of [`SPHERE_STACKS`] rows.
fn sphere(out: &mut Vec<TerrainTriangle>, c: DVec3, radius: f64, stacks: usize, color: [u8; 3]) {
    let at = |i: usize, j: usize| {
        // Latitude from −90° (j = 0) to +90° (j = SPHERE_STACKS).
        let lat =
            -std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * j as f64 / SPHERE_STACKS as f64;
        let lon = std::f64::consts::TAU * i as f64 / SPHERE_SLICES as f64;
        c + radius * DVec3::new(lat.cos() * lon.cos(), lat.sin(), lat.cos() * lon.sin())
    };
    for j in 0..stacks {
        for i in 0..SPHERE_SLICES {
            let (a, b, cc, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            // The poles' rows have one degenerate triangle each; leave it out.
            if j > 0 {
                out.push(TerrainTriangle {
                    corners: [a, b, cc],
                    color,
                });
            }
            if j + 1 < SPHERE_STACKS {
                out.push(TerrainTriangle {
                    corners: [a, cc, d],
                    color,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::{FrictionModel, Heightfield};

    fn terrain(shape: TerrainShape) -> Terrain {
        Terrain {
            shape,
            restitution: 0.0,
            friction: 0.0,
            friction_model: FrictionModel::Coulomb,
        }
    }

    fn area(t: &TerrainTriangle) -> f64 {
        let [a, b, c] = t.corners;
        0.5 * (b - a).cross(c - a).length()
    }

    #[test]
    fn a_box_is_twelve_triangles_with_its_surface_area() {
        let b = terrain(TerrainShape::Box {
            center: DVec3::new(1.0, 2.0, 3.0),
            half_extents: DVec3::new(0.5, 1.0, 2.0),
            rotation: DVec3::new(10.0, 20.0, 30.0),
        });
        let tris = triangulate(std::slice::from_ref(&b), DVec3::ZERO, 1.0);
        assert_eq!(tris.len(), 12);
        let total: f64 = tris.iter().map(area).sum();
        // 2(1·2 + 1·4 + 2·4) = 28 m².
        assert!((total - 28.0).abs() < 1e-9, "{total}");
        // Outward: each face's normal points away from the centre.
        for t in &tris {
            let [a, b, c] = t.corners;
            assert!((b - a).cross(c - a).dot(a - DVec3::new(1.0, 2.0, 3.0)) > 0.0);
        }
        let (lo, hi) = bounds(&[b]).unwrap();
        assert!(
            lo.cmplt(DVec3::new(1.0, 2.0, 3.0)).all() && hi.cmpgt(DVec3::new(1.0, 2.0, 3.0)).all()
        );
    }

    #[test]
    fn spheres_bowls_and_heightfields() {
        let s = triangulate(
            &[terrain(TerrainShape::Sphere {
                center: DVec3::ZERO,
                radius: 2.0,
            })],
            DVec3::ZERO,
            1.0,
        );
        // Two triangles per cell, less one at each pole per slice.
        assert_eq!(
            s.len(),
            2 * SPHERE_SLICES * SPHERE_STACKS - 2 * SPHERE_SLICES
        );
        let total: f64 = s.iter().map(area).sum();
        let exact = 4.0 * std::f64::consts::PI * 4.0;
        assert!(total < exact && total > 0.97 * exact, "{total}");
        let bowl = triangulate(
            &[terrain(TerrainShape::Bowl {
                center: DVec3::new(0.0, 1.0, 0.0),
                radius: 1.0,
            })],
            DVec3::ZERO,
            1.0,
        );
        // The lower half only: no corner above the centre, the lowest at the origin.
        assert!(
            bowl.iter()
                .flat_map(|t| t.corners)
                .all(|p| p.y <= 1.0 + 1e-12)
        );
        let lowest = bowl
            .iter()
            .flat_map(|t| t.corners)
            .map(|p| p.y)
            .fold(f64::INFINITY, f64::min);
        assert!(lowest.abs() < 1e-12);
        let h = terrain(TerrainShape::Heightfield(Heightfield {
            heights: vec![vec![0.0, 1.0, 0.0], vec![0.0, 0.0, 0.0]],
            cell_size: [0.5, 2.0],
            origin: DVec3::new(1.0, 0.0, 0.0),
        }));
        let tris = triangulate(std::slice::from_ref(&h), DVec3::ZERO, 1.0);
        assert_eq!(tris.len(), 4);
        assert_eq!(
            bounds(&[h]),
            Some((DVec3::new(1.0, 0.0, 0.0), DVec3::new(2.0, 1.0, 2.0)))
        );
    }

    #[test]
    fn a_plane_is_a_checkered_square_around_the_focus() {
        let p = terrain(TerrainShape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::Y,
        });
        let tris = triangulate(std::slice::from_ref(&p), DVec3::new(3.0, 1.0, 0.0), 0.5);
        // Half side max(3·0.5, 2) = 2 m, tiles of 0.2 m: 20 × 20 tiles.
        assert_eq!(tris.len(), 2 * 20 * 20);
        assert!(tris.iter().flat_map(|t| t.corners).all(|c| c.y == 0.0));
        let xs = tris.iter().flat_map(|t| t.corners).map(|c| c.x);
        let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
            (l.min(x), h.max(x))
        });
        assert!(
            (lo - 1.0).abs() < 1e-9 && (hi - 5.0).abs() < 1e-9,
            "{lo} {hi}"
        );
        assert_eq!(bounds(&[p]), None);
        assert_eq!(nice(0.2), 0.2);
        assert_eq!(nice(0.73), 0.5);
        assert_eq!(nice(3.0), 2.0);
    }
}
