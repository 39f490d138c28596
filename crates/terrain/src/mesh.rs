//! Mesh terrain: the side the triangles' counter-clockwise normals point to is free space;
//! |φ| is the distance to the nearest triangle and the sign comes from parry's angle-weighted
//! pseudo-normals (the crate doc has the rule for open meshes).

use glam::DVec3;
use parry3d_f64::query::PointQueryWithLocation;
use parry3d_f64::shape::{TriMesh, TriMeshFlags, TrianglePointLocation};

use crate::{Contact, eps_for, within};

#[derive(Debug, Clone)]
pub(crate) struct MeshGeometry {
    mesh: TriMesh,
    /// Closed, consistently oriented and enclosing positive volume: the solid then lies inside
    /// the mesh's bounding box, so anything outside that box is free space.
    bounded_solid: bool,
    eps: f64,
}

/// The nearest triangle's contact.
struct Nearest {
    contact: Contact,
    /// |x − q|, q the nearest point.
    dist: f64,
    inside: bool,
    triangle: u32,
    location: TrianglePointLocation,
}

impl MeshGeometry {
    /// None for triangles that index past the vertices, vertices that are not finite, or no
    /// triangles at all.
    pub(crate) fn new(vertices: &[DVec3], triangles: &[[u32; 3]]) -> Option<MeshGeometry> {
        let n = vertices.len();
        if triangles.is_empty()
            || vertices.iter().any(|v| !v.is_finite())
            || triangles.iter().any(|t| t.iter().any(|&k| k as usize >= n))
        {
            return None;
        }
        // Exporters of flat-shaded faces write a position once per face; pseudo-normals need
        // the triangles around a vertex to share it, hence the merge. ORIENTED computes the
        // pseudo-normals and makes parry's projection fill `is_inside` from them. No topology
        // flags: they only add failure modes (a non-manifold ground patch is still a usable
        // terrain).
        let flags = TriMeshFlags::ORIENTED | TriMeshFlags::MERGE_DUPLICATE_VERTICES;
        let mesh = match TriMesh::with_flags(vertices.to_vec(), triangles.to_vec(), flags) {
            Ok(mesh) => mesh,
            // Without pseudo-normals, queries take the sign from the nearest triangle's normal.
            Err(_) => match TriMesh::new(vertices.to_vec(), triangles.to_vec()) {
                Ok(mesh) => mesh,
                Err(_) => return None,
            },
        };
        let aabb = mesh.local_aabb();
        let magnitude = aabb.mins.abs().max(aabb.maxs.abs()).length();
        let bounded_solid = encloses_positive_volume(mesh.vertices(), mesh.indices());
        Some(MeshGeometry {
            mesh,
            bounded_solid,
            eps: eps_for(magnitude),
        })
    }

    pub(crate) fn query(&self, x: DVec3, reach: f64) -> Option<Contact> {
        self.nearest(x, reach).map(|n| n.contact)
    }

    /// ∂N/∂x ([`crate::nearest_point_jacobian`] at the nearest triangle's nearest feature).
    pub(crate) fn normal_jacobian(&self, x: DVec3) -> glam::DMat3 {
        match self.nearest(x, f64::INFINITY) {
            Some(n) if n.dist > self.eps => {
                let triangle = self.mesh.triangle(n.triangle);
                let along = crate::triangle_feature_projector(&triangle, &n.location);
                crate::nearest_point_jacobian(n.contact.normal, n.dist, along, n.inside)
            }
            _ => glam::DMat3::ZERO,
        }
    }

    /// The contact within `reach`, and where on the mesh its nearest point lies.
    fn nearest(&self, x: DVec3, reach: f64) -> Option<Nearest> {
        let MeshGeometry {
            mesh,
            bounded_solid,
            eps,
        } = self;
        let first_radius = if reach > 0.0 { reach } else { f64::INFINITY };
        let hit =
            match mesh.project_local_point_and_get_location_with_max_dist(x, false, first_radius) {
                Some(hit) => hit,
                None => {
                    // Nothing within reach: only a point deeper inside than reach is still in
                    // contact.
                    if *bounded_solid && !mesh.local_aabb().contains_local_point(x) {
                        return None;
                    }
                    mesh.project_local_point_and_get_location_with_max_dist(
                        x,
                        false,
                        f64::INFINITY,
                    )?
                }
            };
        let (proj, (triangle_id, location)) = hit;
        let diff = x - proj.point;
        let dist = diff.length();
        let face_normal = mesh.triangle_normal(triangle_id);
        let inside = if mesh.pseudo_normals_if_oriented().is_some() {
            proj.is_inside
        } else {
            face_normal.is_some_and(|n| diff.dot(n) <= 0.0)
        };
        let phi = if inside { -dist } else { dist };
        let normal = if dist > *eps {
            if inside { -diff / dist } else { diff / dist }
        } else {
            // A zero-area nearest triangle has no normal of its own; +y is as good as any there.
            face_normal.unwrap_or(DVec3::Y)
        };
        within(Contact { phi, normal }, reach).map(|contact| Nearest {
            contact,
            dist,
            inside,
            triangle: triangle_id,
            location,
        })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Geometry;
    use crate::Surface;
    use crate::testing::{
        against_reference, at, close, close3, cube_mesh, push_back_keeps_normal, reach_threshold,
        surface,
    };
    use parry3d_f64::query::PointQuery;
    use parry3d_f64::shape::Triangle;
    use softbody_scene::{TerrainShape, TriangleMesh};

    /// Whether the surface is a mesh whose solid lies inside its bounding box.
    fn bounded_solid(s: &Surface) -> Option<bool> {
        match &s.geometry {
            Geometry::Mesh(m) => Some(m.bounded_solid),
            _ => None,
        }
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
        assert_eq!(bounded_solid(&s), Some(true));
        check_cube(&s);
    }

    #[test]
    fn mesh_cube_from_obj() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/unit_cube.obj");
        let mesh = softbody_scene::mesh::load_obj(&path).unwrap();
        // The file's 8 positions, in its order: its per-face normals do not split them.
        assert_eq!(mesh.vertices.len(), 8);
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
        assert_eq!(bounded_solid(&s), Some(false));
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
        assert_eq!(bounded_solid(&s), Some(false));
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
}
