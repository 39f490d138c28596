//! Voxelisation of a closed triangle mesh into a lattice of cells, for `kind = "mesh"` bodies.
//!
//! The mesh (scaled, and centred on the centre of its bounding box: the body's local frame) is
//! covered by a regular lattice of cubic cells of edge h, centred on that box, with
//! `ceil(extent / h)` cells per axis (at least one). A cell is kept ("present") when
//!
//! - a triangle of the mesh crosses the cell: meets its interior (separating-axis test,
//!   Akenine-Möller, against the cell shrunk by 10⁻⁹ h; a triangle lying in a lattice plane
//!   crosses neither neighbour, and the centre rule picks the inside one), or
//! - its centre is inside the mesh: the generalised winding number w there (the solid angles
//!   of the triangles, Van Oosterom–Strackee, summed over 4π) has |w| ≥ ½ (either orientation
//!   of the whole mesh works; an inside-out mesh has w = −1 inside).
//!
//! Every vertex a triangle uses is embedded in a kept cell holding it (on a cell boundary, the
//! first kept one of the cells that share it); if none holds it, its own cell is kept too. A
//! vertex no triangle uses is the file's too and is carried (the exports give every vertex of
//! the file at its index), but shapes nothing: it is not in the bounding box and keeps no cell.
//! It is embedded in the kept cell holding it, or else in the kept cell whose centre is
//! nearest, its trilinear weights extended beyond that cell (they still sum to 1 and give the
//! vertex back at rest; the further out, the more they magnify the cell's deformation).
//!
//! On a closed mesh (every edge, after welding vertices at identical positions, used as often in
//! each direction) w is an integer constant on each connected piece of space off the surface,
//! so it is evaluated once per 6-connected component of the cells no triangle touches (meets
//! the closed cell grown by 10⁻⁹ h: the segment between two such neighbours' centres crosses
//! no triangle), and once per cell that a triangle touches without crossing. On an open mesh
//! w is evaluated at every cell no triangle crosses, by the fast winding number (`winding.rs`:
//! a tree over the triangles, within 1e-2 of the exact sum), and the mesh is refused as "not closed
//! enough to tell inside from outside" when more than [`UNDECIDED_SHARE`] of the cells with
//! |w| > ¼ have ¼ < |w| < ¾. A lattice with no cell clearly inside (|w| ≥ ¾) is refused too.
//!
//! The lattice's particles are the corners of the present cells, numbered in lattice order
//! (x fastest, then y, then z) as a cuboid's; springs: `topology::for_each_lattice_spring`.

mod build;

use glam::DVec3;

use crate::SpringCounts;
use crate::scene::TriangleMesh;
use crate::winding::solid_angle;

/// The share of undecided cells (¼ < |w| < ¾) above which an open mesh is refused.
pub const UNDECIDED_SHARE: f64 = 0.1;

/// |w| at or above which a cell centre is clearly inside: a lattice needs one such cell (a
/// flat sheet's cells all have their centres on it, at w = ½).
pub const CLEARLY_INSIDE: f64 = 0.75;

/// Bytes the voxelisation holds per lattice point (cell flags, component labels, the particle
/// map), for the memory check made before it allocates.
pub const BYTES_PER_LATTICE_POINT: u64 = 16;

/// How the lattice spacing is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LatticeSize {
    /// The cell edge h, metres.
    Cell(f64),
    /// Cells along the longest side of the (scaled) mesh's bounding box.
    Resolution(u32),
}

/// Which scene key a voxelisation failure is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VoxelKey {
    /// The mesh file: no triangles, a bad vertex, not closed enough, no extent.
    File,
    /// The lattice size (`cell` or `resolution`): too many points, no cell inside.
    Size,
}

/// A voxelisation failure: the key it is about and a sentence for the user.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelError {
    /// The key to blame.
    pub key: VoxelKey,
    /// What is wrong.
    pub message: String,
}
/// A mesh voxelised into a lattice: immutable once made ([`Voxels::new`]), so the lattice always
/// belongs to the mesh, scale and size it holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Voxels {
    mesh: TriangleMesh,
    scale: DVec3,
    size: LatticeSize,
    /// Centre of the scaled mesh's bounding box: the point placed on the body's `center`.
    offset: DVec3,
    cell: f64,
    /// Cells per axis.
    cells: [u32; 3],
    /// Local coordinates of lattice point (0, 0, 0).
    origin: DVec3,
    present: Vec<bool>,
    /// The particle number of each lattice point, `u32::MAX` where absent.
    particle_of: Vec<u32>,
    /// Lattice coordinates of each particle, in particle order.
    points: Vec<[u32; 3]>,
    /// Springs of each family on the present cells (every family, whatever the body enables).
    springs: SpringCounts,
    /// Per mesh vertex: its cell and its coordinates in it, each in [0, 1] but for a vertex
    /// no triangle uses outside every kept cell.
    embedding: Vec<([u32; 3], DVec3)>,
    /// Present cells whose centre is clearly inside (|w| ≥ ¾).
    inside_cells: u64,
    closed: bool,
    /// The volume the scaled mesh encloses, m³, where it is closed.
    enclosed: Option<f64>,
}

/// The generalised winding number of the triangles at `p`: Σ Ω_t / 4π, Ω_t the signed solid
/// angle of triangle t (Van Oosterom & Strackee 1983). 1 inside a closed mesh wound
/// counter-clockwise seen from outside, 0 outside, ½ on a smooth part of the surface.
pub fn winding_number(vertices: &[DVec3], triangles: &[[u32; 3]], p: DVec3) -> f64 {
    let mut sum = 0.0;
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i as usize] - p);
        sum += solid_angle(a, b, c);
    }
    sum / (4.0 * std::f64::consts::PI)
}

/// The volume enclosed by a closed mesh (Σ a·(b × c)/6, the divergence theorem); negative for
/// an inside-out one.
pub fn enclosed_volume(vertices: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            a.dot(b.cross(c))
        })
        .sum::<f64>()
        / 6.0
}

/// Whether triangle `t` meets the axis-aligned box of centre `c` and half edge `e`
/// (Akenine-Möller's separating-axis test: the box's 3 axes, the triangle's normal, the 9 edge
/// cross products). Touching counts as meeting.
pub fn triangle_meets_box(t: [DVec3; 3], c: DVec3, e: DVec3) -> bool {
    let v = t.map(|p| p - c);
    let edges = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    let separated = |axis: DVec3| {
        let p = v.map(|x| x.dot(axis));
        let r = e.x * axis.x.abs() + e.y * axis.y.abs() + e.z * axis.z.abs();
        let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        lo > r || hi < -r
    };
    for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
        if separated(axis) {
            return false;
        }
    }
    if separated(edges[0].cross(edges[1])) {
        return false;
    }
    for edge in edges {
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            let a = axis.cross(edge);
            if a != DVec3::ZERO && separated(a) {
                return false;
            }
        }
    }
    true
}

/// Whether every edge of the mesh, vertices welded at identical positions, is used as often in
/// each direction: then the winding number is an integer off the surface.
fn is_closed(mesh: &TriangleMesh) -> bool {
    let mut id = std::collections::HashMap::new();
    let welded: Vec<u32> = mesh
        .vertices
        .iter()
        .map(|v| {
            let n = id.len() as u32;
            *id.entry(v.to_array().map(f64::to_bits)).or_insert(n)
        })
        .collect();
    let mut balance = std::collections::HashMap::new();
    for t in &mesh.triangles {
        for e in 0..3 {
            let (a, b) = (welded[t[e] as usize], welded[t[(e + 1) % 3] as usize]);
            if a != b {
                *balance.entry((a.min(b), a.max(b))).or_insert(0i64) += if a < b { 1 } else { -1 };
            }
        }
    }
    balance.values().all(|&b| b == 0)
}

/// Checks what the voxelisation and the terrain's queries assume of a mesh: triangles, finite
/// vertices, valid indices, and a triangle with a normal.
pub fn check_mesh(mesh: &TriangleMesh) -> Result<(), String> {
    let name = mesh.path.display();
    if mesh.triangles.is_empty() {
        return Err(format!("{name} holds no triangles"));
    }
    if let Some(v) = mesh.vertices.iter().position(|v| !v.is_finite()) {
        return Err(format!("{name}: vertex {v} is not finite"));
    }
    let n = mesh.vertices.len();
    if let Some(t) = mesh
        .triangles
        .iter()
        .position(|t| t.iter().any(|&i| i as usize >= n))
    {
        return Err(format!("{name}: triangle {t} names a missing vertex"));
    }
    // A normal is the cross product over its length: a length that is zero, subnormal or
    // infinite gives none.
    let has_area = |t: &[u32; 3]| {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let n = (b - a).cross(c - a).length();
        n.is_finite() && n >= f64::MIN_POSITIVE
    };
    if !mesh.triangles.iter().any(has_area) {
        return Err(format!(
            "{name}: every triangle has zero area (its corners on one line), or one too small \
             or too large for f64: the mesh has no surface"
        ));
    }
    Ok(())
}
impl Voxels {
    /// The mesh, in file coordinates.
    pub fn mesh(&self) -> &TriangleMesh {
        &self.mesh
    }

    /// The scale applied to the file's coordinates (per axis).
    pub fn scale(&self) -> DVec3 {
        self.scale
    }

    /// How the lattice spacing was given.
    pub fn size(&self) -> LatticeSize {
        self.size
    }

    /// The centre of the scaled mesh's bounding box (file axes): the point the body's
    /// `center` is given for.
    pub fn offset(&self) -> DVec3 {
        self.offset
    }

    /// The cell edge h, metres.
    pub fn cell(&self) -> f64 {
        self.cell
    }

    /// Cells per axis.
    pub fn cells(&self) -> [u32; 3] {
        self.cells
    }

    /// Lattice points per axis (cells + 1).
    pub fn lattice_points(&self) -> [u32; 3] {
        self.cells.map(|c| c + 1)
    }

    /// Whether each cell is kept, x fastest.
    pub fn present(&self) -> &[bool] {
        &self.present
    }

    /// Number of kept cells.
    pub fn present_cells(&self) -> u64 {
        self.present.iter().filter(|&&p| p).count() as u64
    }

    /// Kept cells whose centre is clearly inside the mesh (|w| ≥ [`CLEARLY_INSIDE`]).
    pub fn inside_cells(&self) -> u64 {
        self.inside_cells
    }

    /// Whether the mesh is closed (edges balanced after welding).
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// The lattice's volume: kept cells × h³, m³.
    pub fn volume(&self) -> f64 {
        self.present_cells() as f64 * self.cell.powi(3)
    }

    /// The volume the scaled mesh encloses, m³ ([`enclosed_volume`], its size): `None` for a
    /// mesh that is not closed, which encloses no definite volume.
    pub fn enclosed_volume(&self) -> Option<f64> {
        self.enclosed
    }

    /// Number of particles.
    pub fn particle_count(&self) -> u64 {
        self.points.len() as u64
    }

    /// Lattice coordinates of each particle, in particle order.
    pub fn points(&self) -> &[[u32; 3]] {
        &self.points
    }

    /// The particle (within the body) at each lattice point, `u32::MAX` where there is none.
    pub fn particle_of(&self) -> &[u32] {
        &self.particle_of
    }

    /// Springs of each family on the kept cells (every family).
    pub fn spring_counts(&self) -> SpringCounts {
        self.springs
    }

    /// Local coordinates (body frame, before rotation and translation) of lattice point p.
    pub fn local(&self, p: [u32; 3]) -> DVec3 {
        self.origin + self.cell * DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }

    /// Each mesh vertex's embedding: the particles (within the body) at its cell's eight
    /// corners, corner c at offset (c & 1, c >> 1 & 1, c >> 2), and their trilinear weights.
    pub fn embedding(&self) -> Vec<([u32; 8], [f64; 8])> {
        let pn = self.lattice_points().map(|n| n as usize);
        self.embedding
            .iter()
            .map(|&(cell, t)| {
                let mut corners = [0u32; 8];
                let mut weights = [0f64; 8];
                for c in 0..8 {
                    let d = [c & 1, c >> 1 & 1, c >> 2];
                    let p: [usize; 3] = [0, 1, 2].map(|a| cell[a] as usize + d[a]);
                    corners[c] = self.particle_of[p[0] + pn[0] * (p[1] + pn[1] * p[2])];
                    weights[c] = (0..3)
                        .map(|a| if d[a] == 1 { t[a] } else { 1.0 - t[a] })
                        .product();
                }
                (corners, weights)
            })
            .collect()
    }

    /// The outer faces of the kept cells (each face of a kept cell whose neighbour across it
    /// is not kept), two triangles each over particles within the body, counter-clockwise seen
    /// from outside; cells in lattice order, faces −x, +x, −y, +y, −z, +z.
    pub fn lattice_surface(&self) -> Vec<[u32; 3]> {
        let [nx, ny, nz] = self.cells.map(|c| c as i64);
        let pn = self.lattice_points().map(|n| n as i64);
        let kept = |i: i64, j: i64, k: i64| {
            (0..nx).contains(&i)
                && (0..ny).contains(&j)
                && (0..nz).contains(&k)
                && self.present[(i + nx * (j + ny * k)) as usize]
        };
        let particle =
            |p: [i64; 3]| self.particle_of[(p[0] + pn[0] * (p[1] + pn[1] * p[2])) as usize];
        let mut out = Vec::new();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if !kept(i, j, k) {
                        continue;
                    }
                    for axis in 0..3 {
                        // (axis, u, w) cyclic, so e_u × e_w = e_axis.
                        let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                        for side in [0, 1] {
                            let mut next = [i, j, k];
                            next[axis] += 2 * side - 1;
                            if kept(next[0], next[1], next[2]) {
                                continue;
                            }
                            let corner = |du: i64, dw: i64| {
                                let mut p = [i, j, k];
                                p[axis] += side;
                                p[u] += du;
                                p[w] += dw;
                                particle(p)
                            };
                            let (p00, p10, p11, p01) =
                                (corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1));
                            if side == 1 {
                                out.extend([[p00, p10, p11], [p00, p11, p01]]);
                            } else {
                                out.extend([[p00, p11, p10], [p00, p01, p11]]);
                            }
                        }
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topology;

    fn unit_cube() -> TriangleMesh {
        TriangleMesh::cube(DVec3::ZERO, 1.0)
    }

    /// w = 1 inside the unit cube, 0 outside, ½ on a face, −1 inside the cube turned inside out.
    #[test]
    fn winding_numbers_of_a_cube() {
        let m = unit_cube();
        let w = |p: DVec3| winding_number(&m.vertices, &m.triangles, p);
        assert!((w(DVec3::splat(0.5)) - 1.0).abs() < 1e-12);
        assert!((w(DVec3::new(0.9, 0.1, 0.3)) - 1.0).abs() < 1e-12);
        assert!(w(DVec3::new(1.5, 0.5, 0.5)).abs() < 1e-12);
        assert!(w(DVec3::new(-3.0, 7.0, 2.0)).abs() < 1e-12);
        assert!((w(DVec3::new(0.5, 0.5, 1.0)) - 0.5).abs() < 1e-12);
        let inverted: Vec<[u32; 3]> = m.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect();
        assert!((winding_number(&m.vertices, &inverted, DVec3::splat(0.5)) + 1.0).abs() < 1e-12);
        assert!((enclosed_volume(&m.vertices, &m.triangles) - 1.0).abs() < 1e-15);
        assert!(is_closed(&m));
    }

    #[test]
    fn triangle_box_overlap_by_separating_axes() {
        let e = DVec3::splat(0.5);
        let t = [
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ];
        assert!(triangle_meets_box(t, DVec3::ZERO, e));
        // Beside the box along z: separated by the z axis.
        assert!(!triangle_meets_box(t, DVec3::new(0.0, 0.0, 0.6), e));
        // Touching the face z = 0.5 counts.
        assert!(triangle_meets_box(t, DVec3::new(0.0, 0.0, 0.5), e));
        // A triangle whose bounding box overlaps the box but which passes beside it diagonally
        // (separated by its normal, the plane x + y + z = 3).
        let d = [
            DVec3::new(3.0, 0.0, 0.0),
            DVec3::new(0.0, 3.0, 0.0),
            DVec3::new(0.0, 0.0, 3.0),
        ];
        assert!(!triangle_meets_box(d, DVec3::ZERO, e));
        assert!(triangle_meets_box(d, DVec3::splat(0.8), e));
    }

    /// The unit cube at h = ¼: 4³ cells, all kept, 5³ particles, the cuboid's springs.
    #[test]
    fn a_cube_fills_its_lattice() {
        let v = Voxels::new(unit_cube(), DVec3::ONE, LatticeSize::Cell(0.25)).unwrap();
        assert_eq!(v.cells(), [4, 4, 4]);
        assert_eq!(v.present_cells(), 64);
        assert_eq!(v.inside_cells(), 64);
        assert_eq!(v.particle_count(), 125);
        assert_eq!(v.spring_counts(), topology::grid_spring_counts([5, 5, 5]));
        assert!((v.volume() - 1.0).abs() < 1e-15);
        // The lattice surface is the cube's: 6 faces × 16 squares × 2 triangles.
        assert_eq!(v.lattice_surface().len(), 6 * 16 * 2);
        // Resolution 4 along the longest side is the same lattice.
        let r = Voxels::new(unit_cube(), DVec3::ONE, LatticeSize::Resolution(4)).unwrap();
        assert_eq!((r.cells(), r.cell()), ([4, 4, 4], 0.25));
    }

    /// Weights sum to 1 and reproduce the vertex: Σ w_c x_c = x.
    #[test]
    fn embedding_weights_reproduce_the_vertices() {
        let v = Voxels::new(
            unit_cube(),
            DVec3::new(1.0, 2.0, 0.5),
            LatticeSize::Cell(0.3),
        )
        .unwrap();
        let x: Vec<DVec3> = v.points().iter().map(|&p| v.local(p)).collect();
        for ((corners, weights), p) in v.embedding().iter().zip(&v.mesh().vertices) {
            assert!((weights.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            let sum: DVec3 = (0..8).map(|c| weights[c] * x[corners[c] as usize]).sum();
            assert!(
                (sum - (*p * v.scale() - v.offset())).length() < 1e-15,
                "{sum} {p}"
            );
        }
    }

    /// A torus of 4,608 triangles less one, at cells an eighth of its tube's radius (50,176
    /// cells): the winding numbers of its uncrossed cells come from the tree, and it keeps
    /// the closed torus's cells (whose come from the exact sum once per region).
    #[test]
    fn an_open_torus_keeps_the_closed_ones_cells() {
        let closed = TriangleMesh::torus(0.2, 0.08, 96, 24);
        let mut open = closed.clone();
        open.triangles.remove(2000);
        let at = LatticeSize::Cell(0.01);
        let a = Voxels::new(closed, DVec3::ONE, at).unwrap();
        let b = Voxels::new(open, DVec3::ONE, at).unwrap();
        assert!(a.is_closed() && !b.is_closed());
        assert!(
            a.cells().iter().product::<u32>() == 50_176,
            "{:?}",
            a.cells()
        );
        assert_eq!(a.present(), b.present());
        assert_eq!(a.inside_cells(), b.inside_cells());
    }

    #[test]
    fn bad_meshes_are_refused_with_the_key() {
        let mut m = unit_cube();
        m.triangles.clear();
        let e = Voxels::new(m, DVec3::ONE, LatticeSize::Cell(0.1)).unwrap_err();
        assert_eq!(e.key, VoxelKey::File);
        assert!(e.message.ends_with("holds no triangles"), "{}", e.message);

        // Half the cube's faces: an open box with w near ½ everywhere inside.
        let mut m = unit_cube();
        m.triangles.truncate(6);
        let e = Voxels::new(m, DVec3::ONE, LatticeSize::Cell(0.1)).unwrap_err();
        assert_eq!(e.key, VoxelKey::File);
        assert!(e.message.contains("not closed enough"), "{}", e.message);

        // One triangle missing: still voxelised as the cube.
        let mut m = unit_cube();
        m.triangles.remove(3);
        let v = Voxels::new(m, DVec3::ONE, LatticeSize::Cell(0.25)).unwrap();
        assert!(!v.is_closed());
        assert_eq!(v.present_cells(), 64);

        // A flat square (two triangles): every cell meets it, no centre is inside.
        let m = TriangleMesh {
            path: "flat.obj".into(),
            vertices: vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let e = Voxels::new(m, DVec3::ONE, LatticeSize::Cell(0.25)).unwrap_err();
        assert_eq!(e.key, VoxelKey::Size);
        assert!(
            e.message.starts_with("no cell of the 4 × 4 × 1 lattice"),
            "{}",
            e.message
        );

        // A vertex no face uses, farther out than the lattice is long: its extended weights
        // would magnify the lattice's rounding beyond use.
        let mut m = unit_cube();
        m.vertices.push(DVec3::new(0.5, 0.5, 1e6));
        let e = Voxels::new(m, DVec3::ONE, LatticeSize::Cell(0.25)).unwrap_err();
        assert_eq!(e.key, VoxelKey::File);
        assert_eq!(
            e.message,
            "cube.obj: vertex 24, which no face uses, is farther from the lattice than the \
             lattice is long (4 cells): it cannot ride on it; remove it or bring it nearer"
        );
        let mut m = unit_cube();
        m.vertices.push(DVec3::new(0.5, 0.5, 2.0));
        assert!(Voxels::new(m, DVec3::ONE, LatticeSize::Cell(0.25)).is_ok());

        let e = Voxels::new(unit_cube(), DVec3::ONE, LatticeSize::Cell(1e-7)).unwrap_err();
        assert_eq!(e.key, VoxelKey::Size);
        assert!(e.message.contains("particles supported"), "{}", e.message);
    }
}
