//! Input meshes carried by their lattices: each vertex the trilinear sum
//! x_v = Σ_k w_k x_{c_k} over the eight corners c_k of its cell.

use glam::DVec3;

/// Surfaces whose vertices are not particles but weighted sums of particles: the input meshes
/// of mesh bodies, each vertex a trilinear combination of the eight corners of its cell, so
/// that the artist's mesh (its vertex order, its faces) comes back deformed in every frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Embedded {
    /// Per vertex: the particles (global indices) its position is a weighted sum of.
    pub corners: Vec<[u32; 8]>,
    /// Per vertex: the weights of `corners`, summing to 1.
    pub weights: Vec<[f64; 8]>,
    /// Triangles over vertex numbers (0-based, all meshes numbered together), in each input
    /// file's order and winding.
    pub triangles: Vec<[u32; 3]>,
    /// The meshes, in body order.
    pub meshes: Vec<EmbeddedMesh>,
}

/// One body's embedded mesh: its vertices and triangles within [`Embedded`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EmbeddedMesh {
    /// The body (an index into `Model::bodies`).
    pub body: u32,
    /// Its first vertex.
    pub first_vertex: u32,
    /// Its vertex count (the input file's).
    pub vertices: u32,
    /// Its first triangle.
    pub first_triangle: u32,
    /// Its triangle count (the input file's, faces of more than three corners split).
    pub triangles: u32,
}

impl Embedded {
    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.corners.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.corners.is_empty()
    }

    /// Whether body `b` shows an embedded mesh.
    pub fn has_body(&self, b: u32) -> bool {
        self.meshes.iter().any(|m| m.body == b)
    }

    /// Each vertex's value from the particles' `values` (positions, or velocities: the weights
    /// are constant, so the vertex velocity is the same sum of particle velocities). The
    /// corners are summed in corner order: the same bits every time.
    pub fn apply(&self, values: &[DVec3]) -> Vec<DVec3> {
        let mut out = Vec::with_capacity(self.len());
        self.apply_into(values, &mut out);
        out
    }

    /// [`Embedded::apply`], appending to `out`.
    pub fn apply_into(&self, values: &[DVec3], out: &mut Vec<DVec3>) {
        out.extend(self.corners.iter().zip(&self.weights).map(|(c, w)| {
            let mut sum = DVec3::ZERO;
            for k in 0..8 {
                sum += w[k] * values[c[k] as usize];
            }
            sum
        }));
    }

    /// The largest particle index named, if any.
    pub fn max_particle(&self) -> Option<u32> {
        self.corners.iter().flatten().copied().max()
    }
}
