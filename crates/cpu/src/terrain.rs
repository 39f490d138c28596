//! Terrain point queries: the signed distance φ and the outward unit normal N of a point
//! against one terrain shape, built once per run ([`Surface::new`]) and queried from many
//! threads ([`Surface::query`]).
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
//! - **heightfield**: the solid lies below the triangulated height surface, over the grid's
//!   footprint only. |φ| is the distance to the nearest surface triangle; φ < 0 when x is within
//!   the footprint (edges included) and strictly below the surface point directly under or above
//!   it. Beside the footprint a point is outside, whatever its height (the solid has no walls),
//!   so φ is the plain distance to the nearest triangle. N points from the nearest surface point
//!   to x (outside) or from x to it (inside).
//! - **mesh**: the side the triangles' counter-clockwise normals point to is free space. |φ| is
//!   the distance to the nearest triangle; the sign comes from parry's angle-weighted
//!   pseudo-normals (Bærentzen & Aanæs), so it is exact for closed, consistently oriented meshes.
//!   An open mesh (a ground patch) is solid on its back side, and beyond its rim the sign follows
//!   the pseudo-normal of the nearest rim edge or vertex. N as for the heightfield.
//!
//! At the exact centre of a sphere or bowl (within ε, below), where no direction is radial, N is +y.
//!
//! # Heightfield triangulation
//!
//! World vertex (r, c) is `origin + (c·dx, heights[r][c], r·dz)`. Parry (default cell status,
//! no `ZIGZAG_SUBDIVISION`) splits the cell between rows r, r+1 and columns c, c+1 along the
//! diagonal from vertex (r+1, c) to vertex (r, c+1), i.e. from (x0, z1) to (x1, z0), into the
//! triangles
//!
//! - (r, c), (r+1, c), (r, c+1): the one holding corner (x0, z0), where u + v ≤ 1 with
//!   u = (x − x0)/dx and v = (z − z0)/dz; on the diagonal itself this one is used; and
//! - (r+1, c), (r+1, c+1), (r, c+1): where u + v > 1.
//!
//! Any twin of this solver has to split cells the same way, or the surfaces differ by up to half
//! a cell's height variation.
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

use glam::{DMat3, DVec3};
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::query::{PointQuery, PointQueryWithLocation};
use parry3d_f64::shape::{Ball, Cuboid, HalfSpace, HeightField, TriMesh, TriMeshFlags, Triangle};
use parry3d_f64::utils::Array2;
use softbody_scene::{FrictionModel, Terrain, TerrainShape, rotation_from_degrees};

/// Degenerate-normal threshold, relative to the shape's coordinate magnitude.
const REL_EPS: f64 = 1e-9;
/// Degenerate-normal threshold floor, metres, for shapes near the origin.
const ABS_EPS: f64 = 1e-12;

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
    Plane {
        point: DVec3,
        half_space: HalfSpace,
    },
    Ball {
        center: DVec3,
        ball: Ball,
        bowl: bool,
        eps: f64,
    },
    Box {
        center: DVec3,
        /// Box → world; its transpose maps world offsets into box coordinates.
        rotation: DMat3,
        cuboid: Cuboid,
        eps: f64,
    },
    Heightfield {
        field: HeightField,
        /// World position of parry's local origin (the centre of the footprint at height
        /// `origin.y`).
        offset: DVec3,
        eps: f64,
    },
    Mesh {
        mesh: TriMesh,
        /// Closed, consistently oriented and enclosing positive volume: the solid then lies inside
        /// the mesh's bounding box, so anything outside that box is free space.
        bounded_solid: bool,
        eps: f64,
    },
    /// Geometry a validated scene never holds (too few heights, no triangles, a zero normal…):
    /// it touches nothing rather than panicking.
    Empty,
}

// Queries run from rayon threads.
const _: fn() = || {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<Surface>();
};

fn eps_for(magnitude: f64) -> f64 {
    (REL_EPS * magnitude).max(ABS_EPS)
}

impl Surface {
    /// Builds the query structure of one terrain shape. Expects a validated terrain; shapes that
    /// validation would refuse become a surface that never reports contact.
    pub fn new(t: &Terrain) -> Surface {
        let geometry = match &t.shape {
            TerrainShape::Plane { point, normal } => {
                // Scenes built in code may skip validation's unit-length guarantee.
                let n = normal.normalize_or_zero();
                if n == DVec3::ZERO || !point.is_finite() {
                    Geometry::Empty
                } else {
                    Geometry::Plane {
                        point: *point,
                        half_space: HalfSpace::new(n),
                    }
                }
            }
            TerrainShape::Sphere { center, radius } | TerrainShape::Bowl { center, radius } => {
                Geometry::Ball {
                    center: *center,
                    ball: Ball::new(*radius),
                    bowl: matches!(t.shape, TerrainShape::Bowl { .. }),
                    eps: eps_for(center.length() + radius.abs()),
                }
            }
            TerrainShape::Box {
                center,
                half_extents,
                rotation,
            } => Geometry::Box {
                center: *center,
                rotation: DMat3::from_quat(rotation_from_degrees(*rotation)),
                cuboid: Cuboid::new(*half_extents),
                eps: eps_for(center.length() + half_extents.length()),
            },
            TerrainShape::Heightfield(h) => build_heightfield(h),
            TerrainShape::Mesh(m) => build_mesh(&m.vertices, &m.triangles),
        };
        Surface {
            geometry,
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
        if let Geometry::Plane { point, half_space } = &self.geometry {
            if !x.is_finite() || reach.is_nan() {
                return None;
            }
            let phi = half_space.distance_to_local_point(x - *point, false);
            return (phi < reach).then_some(Contact {
                phi,
                normal: half_space.normal,
            });
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
            Geometry::Plane { point, half_space } => {
                half_space.distance_to_local_point(x - *point, false) >= reach
            }
            _ => false,
        }
    }

    /// [`Surface::query`] for every kind of shape.
    #[inline(never)]
    fn query_shape(&self, x: DVec3, reach: f64) -> Option<Contact> {
        if !x.is_finite() || reach.is_nan() {
            return None;
        }
        let contact = match &self.geometry {
            Geometry::Plane { point, half_space } => Contact {
                // Parry's half-space distance is exactly n̂·(x − point): two flops per axis.
                phi: half_space.distance_to_local_point(x - *point, false),
                normal: half_space.normal,
            },
            &Geometry::Ball {
                center,
                ball,
                bowl,
                eps,
            } => {
                let d = x - center;
                let r = d.length();
                // |x − c| − R loses nothing near the surface, unlike the distance to parry's
                // projected point, and the radial direction is exact there.
                let radial = if r > eps { d / r } else { DVec3::Y };
                if bowl {
                    Contact {
                        phi: ball.radius - r,
                        normal: if r > eps { -radial } else { DVec3::Y },
                    }
                } else {
                    Contact {
                        phi: r - ball.radius,
                        normal: radial,
                    }
                }
            }
            &Geometry::Box {
                center,
                rotation,
                cuboid,
                eps,
            } => box_contact(center, rotation, cuboid, eps, x),
            Geometry::Heightfield { field, offset, eps } => {
                return heightfield_query(field, *offset, *eps, x, reach);
            }
            Geometry::Mesh {
                mesh,
                bounded_solid,
                eps,
            } => return mesh_query(mesh, *bounded_solid, *eps, x, reach),
            Geometry::Empty => return None,
        };
        (contact.phi < reach).then_some(contact)
    }
}

fn box_contact(center: DVec3, rotation: DMat3, cuboid: Cuboid, eps: f64, x: DVec3) -> Contact {
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

fn build_heightfield(h: &softbody_scene::Heightfield) -> Geometry {
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
        return Geometry::Empty;
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
    Geometry::Heightfield {
        field,
        offset,
        eps: eps_for(magnitude),
    }
}

fn heightfield_query(
    field: &HeightField,
    offset: DVec3,
    eps: f64,
    x: DVec3,
    reach: f64,
) -> Option<Contact> {
    let p = x - offset;

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
    // Parry locates the cell by dividing, x_at multiplies: clamp away the last-bit disagreement.
    let u = ((xc - x0) / (x1 - x0)).clamp(0.0, 1.0);
    let v = ((zc - z0) / (z1 - z0)).clamp(0.0, 1.0);
    let hs = field.heights();
    let (y00, y10, y01, y11) = (
        hs[(i, j)],
        hs[(i + 1, j)],
        hs[(i, j + 1)],
        hs[(i + 1, j + 1)],
    );
    let first = u + v <= 1.0;
    let height = if first {
        y00 + u * (y01 - y00) + v * (y10 - y00)
    } else {
        y11 + (1.0 - u) * (y10 - y11) + (1.0 - v) * (y01 - y11)
    };
    let (t_first, t_second) = field.triangles_at(i, j);
    let under = if first { t_first } else { t_second }?;
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
    // Inside, the true distance is at most the vertical one, however deep, so the search stays
    // bounded and deep points still get their exact φ. Outside, nothing beyond reach matters.
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
    let normal = if dist > eps {
        if inside {
            (best_point - p) / dist
        } else {
            (p - best_point) / dist
        }
    } else {
        // Cells have positive width and depth, so every triangle has a normal, pointing up.
        best_triangle.normal().unwrap_or(DVec3::Y)
    };
    (phi < reach).then_some(Contact { phi, normal })
}

fn build_mesh(vertices: &[DVec3], triangles: &[[u32; 3]]) -> Geometry {
    let n = vertices.len();
    if triangles.is_empty()
        || vertices.iter().any(|v| !v.is_finite())
        || triangles.iter().any(|t| t.iter().any(|&k| k as usize >= n))
    {
        return Geometry::Empty;
    }
    // OBJ loading duplicates a vertex per (position, normal, uv) triple; pseudo-normals need the
    // triangles around a vertex to share it, hence the merge. ORIENTED computes the
    // pseudo-normals and makes parry's projection fill `is_inside` from them. No topology flags:
    // they only add failure modes (a non-manifold ground patch is still a usable terrain).
    let flags = TriMeshFlags::ORIENTED | TriMeshFlags::MERGE_DUPLICATE_VERTICES;
    let mesh = match TriMesh::with_flags(vertices.to_vec(), triangles.to_vec(), flags) {
        Ok(mesh) => mesh,
        // Without pseudo-normals, queries take the sign from the nearest triangle's normal.
        Err(_) => match TriMesh::new(vertices.to_vec(), triangles.to_vec()) {
            Ok(mesh) => mesh,
            Err(_) => return Geometry::Empty,
        },
    };
    let aabb = mesh.local_aabb();
    let magnitude = aabb.mins.abs().max(aabb.maxs.abs()).length();
    let bounded_solid = encloses_positive_volume(mesh.vertices(), mesh.indices());
    Geometry::Mesh {
        mesh,
        bounded_solid,
        eps: eps_for(magnitude),
    }
}

/// Whether every edge is shared by exactly two triangles that traverse it in opposite directions
/// (closed, consistently oriented), with outward normals (positive signed volume).
fn encloses_positive_volume(vertices: &[DVec3], indices: &[[u32; 3]]) -> bool {
    let mut edges: Vec<(u32, u32)> = indices
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .collect();
    edges.sort_unstable();
    let closed = edges.windows(2).all(|w| w[0] != w[1])
        && edges
            .iter()
            .all(|&(a, b)| a != b && edges.binary_search(&(b, a)).is_ok());
    if !closed {
        return false;
    }
    // Relative to a vertex, to keep the determinants well-conditioned far from the origin.
    let o = vertices[indices[0][0] as usize];
    let volume: f64 = indices
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|k| vertices[k as usize] - o);
            a.dot(b.cross(c))
        })
        .sum();
    volume > 0.0
}

fn mesh_query(
    mesh: &TriMesh,
    bounded_solid: bool,
    eps: f64,
    x: DVec3,
    reach: f64,
) -> Option<Contact> {
    let first_radius = if reach > 0.0 { reach } else { f64::INFINITY };
    let hit = match mesh.project_local_point_and_get_location_with_max_dist(x, false, first_radius)
    {
        Some(hit) => hit,
        None => {
            // Nothing within reach: only a point deeper inside than reach is still in contact.
            if bounded_solid && !mesh.local_aabb().contains_local_point(x) {
                return None;
            }
            mesh.project_local_point_and_get_location_with_max_dist(x, false, f64::INFINITY)?
        }
    };
    let (proj, (triangle_id, _)) = hit;
    let diff = x - proj.point;
    let dist = diff.length();
    let face_normal = mesh.triangle_normal(triangle_id);
    let inside = if mesh.pseudo_normals_if_oriented().is_some() {
        proj.is_inside
    } else {
        face_normal.is_some_and(|n| diff.dot(n) <= 0.0)
    };
    let phi = if inside { -dist } else { dist };
    let normal = if dist > eps {
        if inside { -diff / dist } else { diff / dist }
    } else {
        // A zero-area nearest triangle has no normal of its own; +y is as good as any there.
        face_normal.unwrap_or(DVec3::Y)
    };
    (phi < reach).then_some(Contact { phi, normal })
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::{Heightfield, TriangleMesh};

    fn terrain(shape: TerrainShape) -> Terrain {
        Terrain {
            shape,
            restitution: 0.5,
            friction: 0.3,
            friction_model: FrictionModel::Coulomb,
        }
    }

    fn surface(shape: TerrainShape) -> Surface {
        Surface::new(&terrain(shape))
    }

    fn at(s: &Surface, x: DVec3) -> Contact {
        s.query(x, f64::INFINITY)
            .unwrap_or_else(|| panic!("no contact at {x} with infinite reach"))
    }

    #[track_caller]
    fn close(a: f64, b: f64, tol: f64) {
        assert!((a - b).abs() <= tol, "{a} vs {b} (tol {tol})");
    }

    #[track_caller]
    fn close3(a: DVec3, b: DVec3, tol: f64) {
        assert!((a - b).abs().max_element() <= tol, "{a} vs {b} (tol {tol})");
    }

    #[track_caller]
    fn unit(n: DVec3) {
        close(n.length(), 1.0, 1e-14);
    }

    /// φ, then the push-back `x − φN` lands on the surface, where the normal must not change.
    #[track_caller]
    fn push_back_keeps_normal(s: &Surface, x: DVec3, tol: f64) {
        let c = at(s, x);
        let y = x - c.phi * c.normal;
        let d = at(s, y);
        close(d.phi, 0.0, 1e-14);
        close3(d.normal, c.normal, tol);
    }

    /// None iff φ >= reach, checked at the representable neighbours of φ.
    #[track_caller]
    fn reach_threshold(s: &Surface, x: DVec3) {
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

    fn flat_field() -> Surface {
        surface(TerrainShape::Heightfield(Heightfield {
            heights: vec![vec![0.5; 3]; 3],
            cell_size: [1.0, 2.0],
            origin: DVec3::new(10.0, -1.0, 20.0),
        }))
    }

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

    /// The unit cube [0, 1]³ as an OBJ loader delivers it: four vertices per face.
    fn cube_mesh() -> TriangleMesh {
        TriangleMesh::cube(DVec3::ZERO, 1.0)
    }

    fn check_cube(s: &Surface) {
        let tol = 1e-14;
        let c = at(s, DVec3::new(0.5, 0.5, 1.3));
        close(c.phi, 0.3, tol);
        close3(c.normal, DVec3::Z, tol);
        let c = at(s, DVec3::new(0.5, 0.2, 0.6));
        close(c.phi, -0.2, tol);
        close3(c.normal, DVec3::NEG_Y, tol);
        let c = at(s, DVec3::new(0.3, 1.0, 0.7));
        assert_eq!(c.phi.abs(), 0.0);
        assert_eq!(c.normal, DVec3::Y);
        let c = at(s, DVec3::new(1.3, 1.4, 0.5));
        close(c.phi, 0.5, tol);
        close3(c.normal, DVec3::new(0.6, 0.8, 0.0), tol);
        // Deep inside with a small reach; far outside with a small reach.
        close(
            s.query(DVec3::new(0.5, 0.5, 0.45), 0.01).unwrap().phi,
            -0.45,
            tol,
        );
        assert_eq!(s.query(DVec3::new(3.0, 0.5, 0.5), 0.01), None);
        assert_eq!(s.query(DVec3::new(0.5, 1.5, 0.5), 0.01), None);
        push_back_keeps_normal(s, DVec3::new(0.4, 0.5, 1.2), 1e-15);
        push_back_keeps_normal(s, DVec3::new(0.4, 0.5, 0.9), 1e-15);
        reach_threshold(s, DVec3::new(0.5, 0.5, 1.3));
        reach_threshold(s, DVec3::new(0.5, 0.2, 0.6));
        reach_threshold(s, DVec3::new(1.3, 1.4, 0.5));
    }

    #[test]
    fn mesh_cube() {
        let s = surface(TerrainShape::Mesh(cube_mesh()));
        assert!(matches!(
            s.geometry,
            Geometry::Mesh {
                bounded_solid: true,
                ..
            }
        ));
        check_cube(&s);
    }

    #[test]
    fn mesh_cube_from_obj() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/unit_cube.obj");
        let mesh = softbody_scene::mesh::load_obj(&path).unwrap();
        // Per-face normals in the file: the loader splits every corner into its own vertex.
        assert_eq!(mesh.vertices.len(), 24);
        let s = surface(TerrainShape::Mesh(mesh));
        check_cube(&s);
    }

    #[test]
    fn mesh_inside_out_cube_is_a_room() {
        let mut mesh = cube_mesh();
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
        let s = surface(TerrainShape::Mesh(mesh));
        assert!(matches!(
            s.geometry,
            Geometry::Mesh {
                bounded_solid: false,
                ..
            }
        ));
        let c = at(&s, DVec3::new(0.5, 0.5, 0.8));
        close(c.phi, 0.2, 1e-14);
        close3(c.normal, DVec3::NEG_Z, 1e-14);
        // Outside the room's bounding box is deep in its solid, even with a small reach.
        close(
            s.query(DVec3::new(0.5, 0.5, 5.0), 0.01).unwrap().phi,
            -4.0,
            1e-14,
        );
    }

    #[test]
    fn mesh_open_ground_quad() {
        let s = surface(TerrainShape::Mesh(TriangleMesh {
            path: "quad.obj".into(),
            vertices: vec![
                DVec3::new(-1.0, 0.0, -1.0),
                DVec3::new(1.0, 0.0, -1.0),
                DVec3::new(1.0, 0.0, 1.0),
                DVec3::new(-1.0, 0.0, 1.0),
            ],
            // Counter-clockwise seen from +y.
            triangles: vec![[0, 3, 2], [0, 2, 1]],
        }));
        assert!(matches!(
            s.geometry,
            Geometry::Mesh {
                bounded_solid: false,
                ..
            }
        ));
        let c = at(&s, DVec3::new(0.2, 0.5, 0.3));
        close(c.phi, 0.5, 1e-15);
        close3(c.normal, DVec3::Y, 1e-15);
        let c = at(&s, DVec3::new(0.2, -0.5, 0.3));
        close(c.phi, -0.5, 1e-15);
        close3(c.normal, DVec3::Y, 1e-15);
        let c = at(&s, DVec3::new(0.2, 0.0, 0.3));
        close(c.phi, 0.0, 1e-15);
        assert_eq!(c.normal, DVec3::Y);
        // On the shared diagonal.
        assert_eq!(at(&s, DVec3::new(0.5, 0.0, 0.5)).normal, DVec3::Y);
        // Deep below, small reach: Some with the full depth. Far above: None.
        close(
            s.query(DVec3::new(0.0, -50.0, 0.0), 0.1).unwrap().phi,
            -50.0,
            1e-13,
        );
        assert_eq!(s.query(DVec3::new(0.0, 50.0, 0.0), 0.1), None);
        // Beyond the rim, above the plane: outside, distance to the rim edge.
        let c = at(&s, DVec3::new(2.0, 0.5, 0.0));
        close(c.phi, 1.25f64.sqrt(), 1e-15);
        push_back_keeps_normal(&s, DVec3::new(0.3, 0.7, -0.2), 1e-15);
        reach_threshold(&s, DVec3::new(0.2, 0.5, 0.3));
        reach_threshold(&s, DVec3::new(0.2, -0.5, 0.3));
    }

    /// xorshift64*: reproducible pseudo-random numbers in [0, 1) without a dependency.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }
        fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.next()
        }
    }

    /// Checks `s` against an independent φ at random points: the value, the push-back landing
    /// on the surface, and bit-identical answers for every reach that lets the contact through.
    fn against_reference(
        s: &Surface,
        reference: impl Fn(DVec3) -> f64,
        lo: DVec3,
        hi: DVec3,
        seed: u64,
    ) {
        let mut rng = Rng(seed);
        for _ in 0..3000 {
            let x = DVec3::new(
                rng.range(lo.x, hi.x),
                rng.range(lo.y, hi.y),
                rng.range(lo.z, hi.z),
            );
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

    #[test]
    fn heightfield_matches_brute_force() {
        let mut rng = Rng(7);
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
        // The documented triangulation, in world coordinates, built without parry's grid code.
        let vertex =
            |r: usize, c: usize| origin + DVec3::new(c as f64 * dx, heights[r][c], r as f64 * dz);
        let mut triangles = Vec::new();
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                let (v00, v10) = (vertex(r, c), vertex(r + 1, c));
                let (v01, v11) = (vertex(r, c + 1), vertex(r + 1, c + 1));
                triangles.push(Triangle::new(v00, v10, v01));
                triangles.push(Triangle::new(v10, v11, v01));
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

    #[test]
    fn mesh_matches_brute_force() {
        let mesh = cube_mesh();
        let s = surface(TerrainShape::Mesh(mesh.clone()));
        let triangles: Vec<Triangle> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|k| mesh.vertices[k as usize]);
                Triangle::new(a, b, c)
            })
            .collect();
        let reference = |x: DVec3| {
            let dist = triangles
                .iter()
                .map(|t| (x - t.project_local_point(x, false).point).length())
                .fold(f64::INFINITY, f64::min);
            let inside = x.cmpgt(DVec3::ZERO).all() && x.cmplt(DVec3::ONE).all();
            if inside { -dist } else { dist }
        };
        against_reference(&s, reference, DVec3::splat(-0.7), DVec3::splat(1.7), 13);
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
