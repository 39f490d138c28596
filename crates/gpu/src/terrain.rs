//! Terrain for the GPU: packs the scene's terrain shapes into the two storage buffers that
//! `shaders/terrain.wgsl` reads at group 1 (`surfaces`: one [`SurfaceGpu`] per shape,
//! `terrain_data`: heights and signed-distance grids), and bakes mesh terrain into
//! signed-distance grids. `shaders/terrain.wgsl` is the f32 twin of
//! [`softbody_terrain`]; its header lists which field holds what for each kind.
//!
//! # Heightfields
//!
//! The GPU uses the CPU's triangulation and inside test exactly; only the nearest-triangle
//! search is bounded: it visits the cells that overlap the square of half-size R around the
//! point (R = the distance to the surface point straight above or below it, an upper bound on
//! |φ|; outside the solid, at most the reach), but no more than [`HF_MAX_HALF_WINDOW`] cells on
//! each side of the point's own cell (≤ 17 × 17 cells, 578 triangles). Hence φ is exact (to
//! f32 rounding) whenever the true |φ| ≤ `HF_MAX_HALF_WINDOW · min(dx, dz)`, which covers
//! every contact for any reach below that; farther from the surface |φ| is the distance to the
//! nearest triangle in the window, an overestimate that never exceeds the vertical distance,
//! and the sign is always exact.
//!
//! # Meshes: the signed-distance grid
//!
//! [`pack`] samples the CPU twin's φ (`Surface::query(node, ∞)`, positive in free space) at
//! the nodes of a regular grid ([`SdfGrid::for_bounds`]): cell size h = (bounding-box
//! diagonal D) / [`SDF_CELLS_PER_DIAGONAL`], the mesh's bounding box padded on every side by
//! [`SDF_MARGIN_FRACTION`]·D + [`SDF_MARGIN_CELLS`]·h, at most [`SDF_MAX_NODES_PER_AXIS`] nodes
//! along an axis and [`SDF_MAX_NODES`] in all (h grows by 5 % steps until both hold; with the
//! default constants they never bind: a mesh needs at most about 160 nodes along an axis and
//! 1.2 M nodes, 4.7 MB). Nodes are stored x fastest, then y, then z. The shader interpolates
//! trilinearly and takes the normal from the gradient of the interpolant.
//!
//! Error bound, inside the grid: the CPU φ is 1-Lipschitz wherever it is continuous, and the
//! trilinear weights w_i of the corners x_i of a cell satisfy Σ w_i |x_i − x|² =
//! h² Σ_axes t(1 − t) ≤ 3h²/4, so |φ_grid − φ| ≤ Σ w_i |φ(x_i) − φ(x)| ≤ h·√3/2 (≈ 0.0068·D),
//! reached only next to sharp edges and on medial surfaces; where φ is C² over the cell the
//! error is at most (h²/8)·Σ_axes max|∂²φ/∂a²|, and where it is affine over the cell (all
//! corners and x nearest the same face's plane, e.g. above a flat part) the grid is exact to
//! f32 rounding, normal included. Measured on `scenes/terrain.obj` (D = 4.29 m, h = 3.35 cm,
//! 150 × 43 × 76 nodes, 1.9 MB) at 20,000 random points within 4h of the surface (unit test
//! `terrain_obj_error`, which prints the numbers): median |φ_grid − φ| 5e-11 m, 99th percentile
//! 1.1 mm, maximum 5.3 mm where φ is continuous over the cell (bound 29 mm), 7e-9 m and 4e-7 rad
//! in affine cells (93 % of the points); 2.8 cm including the cells that straddle the sign
//! jump below. The unit cube (h = 1.35 cm): maximum 3.7 mm (bound 11.7 mm).
//!
//! Where the CPU's φ jumps, no bound holds: beyond the rim of an open mesh (a ground patch)
//! the CPU takes the sign from the rim's pseudo-normal, so φ flips from +d to −d (d the
//! distance to the rim) across the sheet that continues the surface past its rim. The grid
//! interpolates that jump into a zero crossing: the same solid region (same sign away from
//! the sheet), but the surface seems to continue past the rim, up to the grid's edge, where
//! the CPU would push a point under the sheet back to the rim itself.
//!
//! Outside the grid box, with c the closest point of the box and d = |x − c|, the shader
//! returns φ(c) + sign(φ(c))·d: continuous, with the sign of the grid there (free space
//! around a closed mesh; the solid side below an open ground patch or around an inside-out
//! mesh, as on the CPU, where a plain φ(c) + d would turn deep solid into free space). Such
//! points lie at least the padding (≥ 0.1·D + 2h) from every triangle: on the free side they
//! are in contact with no reach below that, on the solid side they are deep inside. |φ| is
//! overestimated by at most 2d plus the grid's error at c (φ is 1-Lipschitz).

use bytemuck::{Pod, Zeroable};
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use softbody_scene::{FrictionModel, Terrain, TerrainShape, rotation_from_degrees};
use softbody_terrain::Surface;

/// `SurfaceGpu::kind` of a plane.
pub const KIND_PLANE: u32 = 0;
/// `SurfaceGpu::kind` of an oriented box.
pub const KIND_BOX: u32 = 1;
/// `SurfaceGpu::kind` of a solid ball.
pub const KIND_SPHERE: u32 = 2;
/// `SurfaceGpu::kind` of a bowl (the inside of a sphere is free space).
pub const KIND_BOWL: u32 = 3;
/// `SurfaceGpu::kind` of a heightfield.
pub const KIND_HEIGHTFIELD: u32 = 4;
/// `SurfaceGpu::kind` of a triangle mesh, sampled from its signed-distance grid.
pub const KIND_MESH: u32 = 5;
/// `SurfaceGpu::kind` of geometry that touches nothing (what the CPU twin makes of shapes
/// validation would refuse), and of the placeholder bound when a scene has no terrain:
/// φ = `TERRAIN_FAR` (3e38), N = +y.
pub const KIND_NONE: u32 = 6;

/// `SurfaceGpu::friction_model` for Coulomb friction.
pub const FRICTION_COULOMB: u32 = 0;
/// `SurfaceGpu::friction_model` for viscous friction.
pub const FRICTION_VISCOUS: u32 = 1;

/// Degenerate-normal threshold of the GPU, relative to the shape's coordinate magnitude M
/// (the CPU's is 1e-9, for f64): within max(1e-4·M, [`NORMAL_EPS_ABS`]) of the surface the
/// normal comes from the geometry (box face, heightfield triangle, +y at a ball's centre), as
/// on the CPU. f32 rounding puts ~1e-7·M of noise on the offset from the closest point, so
/// directions computed just above the threshold are good to about 1e-3 rad.
pub const NORMAL_EPS_REL: f64 = 1e-4;
/// Floor of the degenerate-normal threshold, metres.
pub const NORMAL_EPS_ABS: f64 = 1e-9;

/// Heightfield search window cap, cells on each side of the point's cell; must equal
/// `TERRAIN_HF_MAX_HALF_WINDOW` in `shaders/terrain.wgsl`.
pub const HF_MAX_HALF_WINDOW: u32 = 8;

/// Mesh SDF grid: cells along the diagonal of the mesh's bounding box.
pub const SDF_CELLS_PER_DIAGONAL: f64 = 128.0;
/// Mesh SDF grid padding on each side, as a fraction of the bounding-box diagonal…
pub const SDF_MARGIN_FRACTION: f64 = 0.1;
/// …plus this many cells.
pub const SDF_MARGIN_CELLS: f64 = 2.0;
/// Mesh SDF grid: at most this many nodes along an axis.
pub const SDF_MAX_NODES_PER_AXIS: usize = 256;
/// Mesh SDF grid: at most this many nodes in all (64 MiB of f32).
pub const SDF_MAX_NODES: usize = 1 << 24;
/// Smallest diagonal the grid rule uses, metres (for a mesh collapsed to a point).
pub const SDF_MIN_DIAGONAL: f64 = 1e-6;

/// One terrain shape as the shaders read it; must match `SurfaceGpu` in
/// `shaders/terrain.wgsl` (112 bytes, 16-byte aligned rows; the per-kind use of each field is
/// listed in that file's header).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct SurfaceGpu {
    /// One of the `KIND_*` constants.
    pub kind: u32,
    /// [`FRICTION_COULOMB`] or [`FRICTION_VISCOUS`].
    pub friction_model: u32,
    /// Coefficient of restitution k_r.
    pub restitution: f32,
    /// Friction coefficient (μ or k_f).
    pub friction: f32,
    /// Plane: point. Box, sphere, bowl: centre, w = ε. Heightfield: world position of vertex
    /// (0, 0) at height 0, w = ε. Mesh: grid node (0, 0, 0), w = cell size h.
    pub center: [f32; 4],
    /// Plane: unit normal. Box: half extents. Sphere, bowl: x = radius. Heightfield: (dx, dz,
    /// lowest height, highest height). Mesh: unused.
    pub axis: [f32; 4],
    /// Box: first column of the box → world rotation (`rotation_from_degrees`).
    pub rot0: [f32; 4],
    /// Box: second column.
    pub rot1: [f32; 4],
    /// Box: third column.
    pub rot2: [f32; 4],
    /// Heightfield: (rows, cols, offset of `heights[0][0]` in the data, 0); heights row-major.
    /// Mesh: (nx, ny, nz, offset of node (0, 0, 0)); nodes x fastest, then y, then z.
    pub dims: [u32; 4],
}

const _: () = assert!(std::mem::size_of::<SurfaceGpu>() == 112);

impl SurfaceGpu {
    /// A surface that touches nothing.
    pub const NONE: SurfaceGpu = SurfaceGpu {
        kind: KIND_NONE,
        friction_model: FRICTION_COULOMB,
        restitution: 0.0,
        friction: 0.0,
        center: [0.0; 4],
        axis: [0.0; 4],
        rot0: [0.0; 4],
        rot1: [0.0; 4],
        rot2: [0.0; 4],
        dims: [0; 4],
    };
}

/// The contents of the terrain buffers (group 1 of the shaders).
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainBuffers {
    /// One per scene terrain shape, in scene order (empty for a scene without terrain).
    pub surfaces: Vec<SurfaceGpu>,
    /// Heights and SDF grids; never empty (a lone 0.0 when no shape needs data), so it can be
    /// bound as is.
    pub data: Vec<f32>,
}

impl TerrainBuffers {
    /// What to upload to the `surfaces` binding: the surfaces, or one [`SurfaceGpu::NONE`]
    /// placeholder when there are none (wgpu cannot bind an empty buffer).
    pub fn surfaces_for_binding(&self) -> &[SurfaceGpu] {
        if self.surfaces.is_empty() {
            std::slice::from_ref(&SurfaceGpu::NONE)
        } else {
            &self.surfaces
        }
    }
}

/// The regular grid a mesh's signed distance is sampled on (see the module doc for the rule).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SdfGrid {
    /// Node (0, 0, 0), metres; exactly representable in f32.
    pub origin: DVec3,
    /// Cell size h, metres; exactly representable in f32.
    pub cell: f64,
    /// Nodes along x, y, z (each at least 2).
    pub dims: [usize; 3],
}

impl SdfGrid {
    /// The grid for a mesh whose vertices span `[min, max]`.
    pub fn for_bounds(min: DVec3, max: DVec3) -> SdfGrid {
        Self::for_bounds_with(
            min,
            max,
            SDF_CELLS_PER_DIAGONAL,
            SDF_MAX_NODES_PER_AXIS,
            SDF_MAX_NODES,
        )
    }

    fn for_bounds_with(
        min: DVec3,
        max: DVec3,
        cells_per_diagonal: f64,
        max_per_axis: usize,
        max_nodes: usize,
    ) -> SdfGrid {
        let diagonal = (max - min).length().max(SDF_MIN_DIAGONAL);
        let mut cell = diagonal / cells_per_diagonal;
        loop {
            // f32-exact origin and cell, so the GPU's nodes are the baked ones.
            let h = f64::from(cell as f32);
            let margin = SDF_MARGIN_FRACTION * diagonal + SDF_MARGIN_CELLS * h;
            let origin = (min - DVec3::splat(margin)).as_vec3().as_dvec3();
            let extent = max + DVec3::splat(margin) - origin;
            let dims = extent
                .to_array()
                .map(|e| ((e / h).ceil() as usize + 1).max(2));
            let nodes: usize = dims.iter().product();
            if dims.iter().all(|&n| n <= max_per_axis) && nodes <= max_nodes {
                return SdfGrid {
                    origin,
                    cell: h,
                    dims,
                };
            }
            cell *= 1.05;
        }
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// Whether the grid has no nodes (never, for a grid from [`SdfGrid::for_bounds`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Position of node (i, j, k).
    pub fn node(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.origin + self.cell * DVec3::new(i as f64, j as f64, k as f64)
    }

    /// φ at every node, x fastest, then y, then z, from the CPU twin (in parallel).
    pub fn bake(&self, surface: &Surface) -> Vec<f32> {
        let [nx, ny, _] = self.dims;
        let mut values = vec![0.0f32; self.len()];
        values
            .par_chunks_mut(nx * ny)
            .enumerate()
            .for_each(|(k, slice)| {
                for j in 0..ny {
                    for i in 0..nx {
                        let phi = surface
                            .query(self.node(i, j, k), f64::INFINITY)
                            .map_or(f64::MAX, |c| c.phi);
                        slice[i + nx * j] = phi as f32;
                    }
                }
            });
        values
    }
}

fn eps_for(magnitude: f64) -> f32 {
    (NORMAL_EPS_REL * magnitude).max(NORMAL_EPS_ABS) as f32
}

fn v4(v: DVec3, w: f64) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w as f32]
}

fn offset_of(data: &[f32]) -> u32 {
    u32::try_from(data.len()).expect("terrain data beyond 2^32 values")
}

/// Packs the scene's terrain for the shaders, baking each mesh's signed-distance grid from
/// the CPU twin (parallel over the grid's z slices).
pub fn pack(terrain: &[Terrain]) -> TerrainBuffers {
    let mut data = Vec::new();
    let mut surfaces = Vec::with_capacity(terrain.len());
    for t in terrain {
        let cpu = Surface::new(t);
        // The CPU twin answers every finite point with an infinite reach unless it made the
        // shape touch nothing.
        let mut s = if cpu.query(DVec3::ZERO, f64::INFINITY).is_none() {
            SurfaceGpu::NONE
        } else {
            pack_geometry(&t.shape, &cpu, &mut data)
        };
        s.friction_model = match t.friction_model {
            FrictionModel::Coulomb => FRICTION_COULOMB,
            FrictionModel::Viscous => FRICTION_VISCOUS,
        };
        s.restitution = t.restitution as f32;
        s.friction = t.friction as f32;
        surfaces.push(s);
    }
    if data.is_empty() {
        data.push(0.0);
    }
    TerrainBuffers { surfaces, data }
}

fn pack_geometry(shape: &TerrainShape, cpu: &Surface, data: &mut Vec<f32>) -> SurfaceGpu {
    let mut s = SurfaceGpu::NONE;
    match shape {
        TerrainShape::Plane { point, normal } => {
            s.kind = KIND_PLANE;
            s.center = v4(*point, 0.0);
            s.axis = v4(normal.normalize_or_zero(), 0.0);
        }
        TerrainShape::Box {
            center,
            half_extents,
            rotation,
        } => {
            let r = DMat3::from_quat(rotation_from_degrees(*rotation));
            s.kind = KIND_BOX;
            s.center = v4(*center, 0.0);
            s.center[3] = eps_for(center.length() + half_extents.length());
            s.axis = v4(*half_extents, 0.0);
            s.rot0 = v4(r.x_axis, 0.0);
            s.rot1 = v4(r.y_axis, 0.0);
            s.rot2 = v4(r.z_axis, 0.0);
        }
        TerrainShape::Sphere { center, radius } | TerrainShape::Bowl { center, radius } => {
            s.kind = if matches!(shape, TerrainShape::Sphere { .. }) {
                KIND_SPHERE
            } else {
                KIND_BOWL
            };
            s.center = v4(*center, 0.0);
            s.center[3] = eps_for(center.length() + radius.abs());
            s.axis = [*radius as f32, 0.0, 0.0, 0.0];
        }
        TerrainShape::Heightfield(h) => {
            let rows = h.heights.len();
            let cols = h.heights[0].len();
            let [dx, dz] = h.cell_size;
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            let offset = offset_of(data);
            for row in &h.heights {
                for &y in row {
                    lo = lo.min(y);
                    hi = hi.max(y);
                    data.push(y as f32);
                }
            }
            // As the CPU: the magnitude of the world box around the surface.
            let mins = h.origin + DVec3::new(0.0, lo, 0.0);
            let maxs = h.origin + DVec3::new(dx * (cols - 1) as f64, hi, dz * (rows - 1) as f64);
            s.kind = KIND_HEIGHTFIELD;
            s.center = v4(h.origin, 0.0);
            s.center[3] = eps_for(mins.abs().max(maxs.abs()).length());
            s.axis = [dx as f32, dz as f32, lo as f32, hi as f32];
            s.dims = [rows as u32, cols as u32, offset, 0];
        }
        TerrainShape::Mesh(m) => {
            let (min, max) = m
                .vertices
                .iter()
                .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), v| {
                    (lo.min(*v), hi.max(*v))
                });
            let grid = SdfGrid::for_bounds(min, max);
            let offset = offset_of(data);
            data.extend(grid.bake(cpu));
            s.kind = KIND_MESH;
            s.center = v4(grid.origin, grid.cell);
            s.dims = [
                grid.dims[0] as u32,
                grid.dims[1] as u32,
                grid.dims[2] as u32,
                offset,
            ];
        }
    }
    s
}

/// The shader's mesh sampler (`terrain_mesh` in `shaders/terrain.wgsl`) in f64, operation for
/// operation: (φ, unit normal) of a [`KIND_MESH`] surface at x. For tests and error studies.
pub fn sample_sdf(s: &SurfaceGpu, data: &[f32], x: DVec3) -> (f64, DVec3) {
    debug_assert_eq!(s.kind, KIND_MESH);
    let lo = DVec3::new(s.center[0].into(), s.center[1].into(), s.center[2].into());
    let h = f64::from(s.center[3]);
    let n = [s.dims[0] as usize, s.dims[1] as usize, s.dims[2] as usize];
    let offset = s.dims[3] as usize;
    let hi = lo + h * DVec3::new((n[0] - 1) as f64, (n[1] - 1) as f64, (n[2] - 1) as f64);
    let c = x.clamp(lo, hi);
    let g = (c - lo) / h;
    let cell = [0, 1, 2].map(|a| (g[a].floor() as usize).min(n[a] - 2));
    let t = DVec3::new(
        (g.x - cell[0] as f64).clamp(0.0, 1.0),
        (g.y - cell[1] as f64).clamp(0.0, 1.0),
        (g.z - cell[2] as f64).clamp(0.0, 1.0),
    );
    let node = |di: usize, dj: usize, dk: usize| {
        f64::from(data[offset + cell[0] + di + n[0] * (cell[1] + dj + n[1] * (cell[2] + dk))])
    };
    let mix = |a: f64, b: f64, t: f64| a * (1.0 - t) + b * t;
    let (c000, c100, c010, c110) = (node(0, 0, 0), node(1, 0, 0), node(0, 1, 0), node(1, 1, 0));
    let (c001, c101, c011, c111) = (node(0, 0, 1), node(1, 0, 1), node(0, 1, 1), node(1, 1, 1));
    let c00 = mix(c000, c100, t.x);
    let c10 = mix(c010, c110, t.x);
    let c01 = mix(c001, c101, t.x);
    let c11 = mix(c011, c111, t.x);
    let c0 = mix(c00, c10, t.y);
    let c1 = mix(c01, c11, t.y);
    let mut phi = mix(c0, c1, t.z);
    let gx = mix(
        mix(c100 - c000, c110 - c010, t.y),
        mix(c101 - c001, c111 - c011, t.y),
        t.z,
    );
    let gy = mix(c10 - c00, c11 - c01, t.z);
    let gz = c1 - c0;
    let mut grad = DVec3::new(gx, gy, gz) / h;
    let d = x - c;
    let dist = d.length();
    if dist > 0.0 {
        let sgn = if phi >= 0.0 { 1.0 } else { -1.0 };
        phi += sgn * dist;
        for a in 0..3 {
            if d[a] != 0.0 {
                grad[a] = sgn * d[a] / dist;
            }
        }
    }
    let len = grad.length();
    let normal = if len > 0.0 { grad / len } else { DVec3::Y };
    (phi, normal)
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::{Heightfield, TriangleMesh};

    fn terrain(shape: TerrainShape) -> Terrain {
        Terrain {
            shape,
            restitution: 0.25,
            friction: 0.75,
            friction_model: FrictionModel::Viscous,
        }
    }

    /// xorshift64*: reproducible pseudo-random numbers in [0, 1).
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

    /// The unit cube [0, 1]³, closed and outward-wound.
    fn cube_mesh() -> TriangleMesh {
        TriangleMesh::cube(DVec3::ZERO, 1.0)
    }

    fn terrain_obj() -> TriangleMesh {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/terrain.obj");
        softbody_scene::mesh::load_obj(&path).unwrap()
    }

    #[test]
    fn layout_matches_the_shader() {
        // The WGSL struct: u32, u32, f32, f32, then six 16-byte rows.
        assert_eq!(std::mem::size_of::<SurfaceGpu>(), 112);
        assert_eq!(std::mem::align_of::<SurfaceGpu>(), 4);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, restitution), 8);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, friction), 12);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, center), 16);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, axis), 32);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, rot0), 48);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, rot1), 64);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, rot2), 80);
        assert_eq!(std::mem::offset_of!(SurfaceGpu, dims), 96);
        let shader = include_str!("../../../shaders/terrain.wgsl");
        assert!(shader.contains(&format!(
            "const TERRAIN_HF_MAX_HALF_WINDOW: u32 = {HF_MAX_HALF_WINDOW}u;"
        )));
        for (name, value) in [
            ("PLANE", KIND_PLANE),
            ("BOX", KIND_BOX),
            ("SPHERE", KIND_SPHERE),
            ("BOWL", KIND_BOWL),
            ("HEIGHTFIELD", KIND_HEIGHTFIELD),
            ("MESH", KIND_MESH),
            ("NONE", KIND_NONE),
            ("FRICTION_COULOMB", FRICTION_COULOMB),
            ("FRICTION_VISCOUS", FRICTION_VISCOUS),
        ] {
            assert!(
                shader.contains(&format!("const TERRAIN_{name}: u32 = {value}u;")),
                "{name}"
            );
        }
    }

    #[test]
    fn pack_round_trips() {
        let heights = vec![vec![0.5, -0.25, 0.125], vec![1.0, 2.0, -3.0]];
        let scene = vec![
            terrain(TerrainShape::Plane {
                point: DVec3::new(1.0, 2.0, 3.0),
                normal: DVec3::new(0.0, 2.0, 0.0),
            }),
            terrain(TerrainShape::Box {
                center: DVec3::new(0.5, -1.0, 2.0),
                half_extents: DVec3::new(0.1, 0.2, 0.3),
                rotation: DVec3::new(10.0, 20.0, 30.0),
            }),
            terrain(TerrainShape::Sphere {
                center: DVec3::new(0.0, 3.0, 4.0),
                radius: 1.5,
            }),
            terrain(TerrainShape::Heightfield(Heightfield {
                heights: heights.clone(),
                cell_size: [0.5, 0.25],
                origin: DVec3::new(-1.0, 0.5, 2.0),
            })),
            terrain(TerrainShape::Mesh(cube_mesh())),
            terrain(TerrainShape::Bowl {
                center: DVec3::ZERO,
                radius: 2.0,
            }),
            terrain(TerrainShape::Plane {
                point: DVec3::ZERO,
                normal: DVec3::ZERO,
            }),
        ];
        let b = pack(&scene);
        assert_eq!(b.surfaces.len(), scene.len());
        for s in &b.surfaces {
            assert_eq!(
                (s.friction_model, s.restitution, s.friction),
                (FRICTION_VISCOUS, 0.25, 0.75)
            );
        }
        let [plane, boxy, sphere, field, mesh, bowl, none] = b.surfaces[..] else {
            unreachable!()
        };
        assert_eq!(plane.kind, KIND_PLANE);
        assert_eq!(plane.center, [1.0, 2.0, 3.0, 0.0]);
        assert_eq!(plane.axis, [0.0, 1.0, 0.0, 0.0]);

        assert_eq!(boxy.kind, KIND_BOX);
        assert_eq!(boxy.center[..3], [0.5, -1.0, 2.0]);
        assert_eq!(boxy.axis, [0.1, 0.2, 0.3, 0.0]);
        let r = DMat3::from_quat(rotation_from_degrees(DVec3::new(10.0, 20.0, 30.0)));
        for (col, want) in [boxy.rot0, boxy.rot1, boxy.rot2]
            .iter()
            .zip([r.x_axis, r.y_axis, r.z_axis])
        {
            for a in 0..3 {
                assert!((f64::from(col[a]) - want[a]).abs() < 1e-7);
            }
        }
        let eps = (1e-4
            * (DVec3::new(0.5, -1.0, 2.0).length() + DVec3::new(0.1, 0.2, 0.3).length()))
            as f32;
        assert_eq!(boxy.center[3], eps);

        assert_eq!((sphere.kind, bowl.kind), (KIND_SPHERE, KIND_BOWL));
        assert_eq!(sphere.center[..3], [0.0, 3.0, 4.0]);
        assert_eq!(sphere.axis[0], 1.5);
        assert_eq!(bowl.axis[0], 2.0);
        assert_eq!(bowl.center[3], NORMAL_EPS_REL as f32 * 2.0);

        assert_eq!(field.kind, KIND_HEIGHTFIELD);
        assert_eq!(field.center[..3], [-1.0, 0.5, 2.0]);
        assert_eq!(field.axis, [0.5, 0.25, -3.0, 2.0]);
        let [rows, cols, off, _] = field.dims.map(|d| d as usize);
        assert_eq!((rows, cols), (2, 3));
        for (r, row) in heights.iter().enumerate() {
            for (c, &y) in row.iter().enumerate() {
                assert_eq!(b.data[off + r * cols + c], y as f32);
            }
        }

        assert_eq!(mesh.kind, KIND_MESH);
        let grid = SdfGrid::for_bounds(DVec3::ZERO, DVec3::ONE);
        assert_eq!(mesh.center, v4(grid.origin, grid.cell));
        assert_eq!(mesh.dims[..3], grid.dims.map(|d| d as u32));
        let moff = mesh.dims[3] as usize;
        assert_eq!(moff, off + rows * cols, "bulk data packed back to back");
        assert_eq!(b.data.len(), moff + grid.len());

        assert_eq!(none.kind, KIND_NONE);

        // Bytes round-trip as the GPU buffer holds them.
        let bytes: &[u8] = bytemuck::cast_slice(&b.surfaces);
        assert_eq!(bytes.len(), 112 * scene.len());
        let back: Vec<SurfaceGpu> = bytemuck::pod_collect_to_vec(bytes);
        assert_eq!(back, b.surfaces);

        let empty = pack(&[]);
        assert_eq!(empty.data, [0.0]);
        assert_eq!(empty.surfaces_for_binding(), [SurfaceGpu::NONE]);
        assert_eq!(b.surfaces_for_binding(), &b.surfaces[..]);
    }

    #[test]
    fn grid_rule() {
        let (min, max) = (DVec3::new(-1.5, 0.0, -0.75), DVec3::new(2.5, 0.4, 0.75));
        let g = SdfGrid::for_bounds(min, max);
        let diagonal = (max - min).length();
        assert!((g.cell - diagonal / SDF_CELLS_PER_DIAGONAL).abs() < 1e-7 * g.cell);
        assert_eq!(f64::from(g.cell as f32), g.cell);
        assert_eq!(g.origin.as_vec3().as_dvec3(), g.origin);
        let margin = SDF_MARGIN_FRACTION * diagonal + SDF_MARGIN_CELLS * g.cell;
        let top = g.node(g.dims[0] - 1, g.dims[1] - 1, g.dims[2] - 1);
        assert!((g.origin - (min - margin)).abs().max_element() < 1e-6);
        assert!(top.cmpge(max + margin).all() && top.cmplt(max + margin + g.cell).all());
        // A degenerate (flat) mesh still gets cells along its thin axis.
        let flat = SdfGrid::for_bounds(DVec3::new(-1.0, 0.0, -1.0), DVec3::new(1.0, 0.0, 1.0));
        assert!(flat.dims[1] > 2 * (SDF_MARGIN_CELLS as usize));
        // The default rule stays well inside the caps, even for a needle or a cube.
        for (lo, hi) in [
            (DVec3::ZERO, DVec3::new(1e3, 1e-3, 1e-3)),
            (DVec3::ZERO, DVec3::ONE),
        ] {
            let g = SdfGrid::for_bounds(lo, hi);
            assert!(g.dims.iter().all(|&n| n <= 160), "{:?}", g.dims);
            assert!(g.len() <= 1_200_000, "{:?}", g.dims);
        }
        // Tighter caps coarsen the grid until they hold.
        let capped = SdfGrid::for_bounds_with(DVec3::ZERO, DVec3::ONE, 128.0, 50, 1 << 30);
        assert!(capped.dims.iter().all(|&n| n <= 50) && capped.dims[0] >= 45);
        let budget = SdfGrid::for_bounds_with(DVec3::ZERO, DVec3::ONE, 128.0, 256, 20_000);
        assert!(
            budget.len() <= 20_000 && budget.len() >= 15_000,
            "{:?}",
            budget.dims
        );
    }

    #[test]
    fn grid_nodes_hold_the_cpu_phi() {
        for mesh in [cube_mesh(), terrain_obj()] {
            let t = terrain(TerrainShape::Mesh(mesh));
            let b = pack(std::slice::from_ref(&t));
            let s = b.surfaces[0];
            let cpu = Surface::new(&t);
            let origin = DVec3::new(s.center[0].into(), s.center[1].into(), s.center[2].into());
            let h = f64::from(s.center[3]);
            let [nx, ny, nz, off] = s.dims.map(|d| d as usize);
            let mut rng = Rng(3);
            for n in 0..3000 {
                // The eight corners of the grid, then random nodes.
                let (i, j, k) = if n < 8 {
                    (
                        (n & 1) * (nx - 1),
                        (n >> 1 & 1) * (ny - 1),
                        (n >> 2) * (nz - 1),
                    )
                } else {
                    let r = |rng: &mut Rng, n: usize| ((rng.next() * n as f64) as usize).min(n - 1);
                    (r(&mut rng, nx), r(&mut rng, ny), r(&mut rng, nz))
                };
                let x = origin + h * DVec3::new(i as f64, j as f64, k as f64);
                let phi = cpu.query(x, f64::INFINITY).unwrap().phi;
                assert_eq!(
                    b.data[off + i + nx * (j + ny * k)],
                    phi as f32,
                    "node {i} {j} {k}"
                );
                // The sampler returns node values at nodes.
                let (sampled, _) = sample_sdf(&s, &b.data, x);
                assert!((sampled - f64::from(phi as f32)).abs() <= 1e-6 * (1.0 + phi.abs()));
            }
        }
    }

    /// Agreement statistics of the grid with the CPU twin at points near a mesh.
    #[derive(Debug, Default)]
    struct Agreement {
        points: usize,
        /// Points whose cell the CPU φ is 1-Lipschitz over (the bound applies).
        lipschitz: usize,
        max_err: f64,
        max_err_lipschitz: f64,
        /// Points in cells where the CPU φ is affine (same face plane at corners and point).
        affine: usize,
        max_err_affine: f64,
        max_angle_affine: f64,
        errors: Vec<f64>,
    }

    /// Random points within `band` of random triangles (area-weighted), compared with the CPU.
    fn agreement(
        mesh: &TriangleMesh,
        band: f64,
        count: usize,
        seed: u64,
    ) -> (Agreement, SurfaceGpu) {
        let t = terrain(TerrainShape::Mesh(mesh.clone()));
        let b = pack(std::slice::from_ref(&t));
        let s = b.surfaces[0];
        let cpu = Surface::new(&t);
        let at = |x: DVec3| cpu.query(x, f64::INFINITY).unwrap();
        let origin = DVec3::new(s.center[0].into(), s.center[1].into(), s.center[2].into());
        let h = f64::from(s.center[3]);
        let tris: Vec<[DVec3; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|k| mesh.vertices[k as usize]))
            .collect();
        let areas: Vec<f64> = tris
            .iter()
            .map(|[a, b, c]| 0.5 * (*b - *a).cross(*c - *a).length())
            .collect();
        let total: f64 = areas.iter().sum();
        let mut rng = Rng(seed);
        let mut st = Agreement::default();
        for _ in 0..count {
            let mut pick = rng.next() * total;
            let mut k = 0;
            while k + 1 < tris.len() && pick >= areas[k] {
                pick -= areas[k];
                k += 1;
            }
            let [a, bb, c] = tris[k];
            let (mut u, mut v) = (rng.next(), rng.next());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let on = a + u * (bb - a) + v * (c - a);
            let n = (bb - a).cross(c - a).normalize();
            let jitter = DVec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            );
            let x = on + rng.range(-band, band) * n + 0.25 * band * jitter;
            let exact = at(x);
            let (phi, normal) = sample_sdf(&s, &b.data, x);
            let err = (phi - exact.phi).abs();
            st.points += 1;
            st.max_err = st.max_err.max(err);
            st.errors.push(err);
            // The cell's corners.
            let g = ((x - origin) / h).floor();
            let corners: Vec<DVec3> = (0..8)
                .map(|m| {
                    origin
                        + h * (g + DVec3::new((m & 1) as f64, (m >> 1 & 1) as f64, (m >> 2) as f64))
                })
                .collect();
            let values: Vec<_> = corners.iter().map(|&y| at(y)).collect();
            let lipschitz = (0..8).all(|i| {
                (0..8).all(|j| {
                    (values[i].phi - values[j].phi).abs()
                        <= (corners[i] - corners[j]).length() * (1.0 + 1e-9) + 1e-12
                })
            });
            if lipschitz {
                st.lipschitz += 1;
                st.max_err_lipschitz = st.max_err_lipschitz.max(err);
            }
            // Affine: every corner and x project onto the same plane (same normal, same
            // plane offset φ − N·y).
            let plane = exact.phi - exact.normal.dot(x);
            let affine = values.iter().zip(&corners).all(|(c, y)| {
                (c.normal - exact.normal).length() < 1e-9
                    && (c.phi - c.normal.dot(*y) - plane).abs() < 1e-9
            });
            if affine {
                st.affine += 1;
                st.max_err_affine = st.max_err_affine.max(err);
                st.max_angle_affine = st.max_angle_affine.max(normal.angle_between(exact.normal));
            }
        }
        (st, s)
    }

    fn check_bound(name: &str, st: &Agreement, s: &SurfaceGpu) {
        let h = f64::from(s.center[3]);
        let bound = h * 3f64.sqrt() / 2.0;
        let mut sorted = st.errors.clone();
        sorted.sort_by(f64::total_cmp);
        let pct = |q: f64| sorted[((sorted.len() - 1) as f64 * q) as usize];
        eprintln!(
            "{name}: h = {h:.5} m, grid {:?}, bound h√3/2 = {bound:.5} m; {} points: max |Δφ| = \
             {:.3e} m (median {:.3e}, 99% {:.3e}); {} in Lipschitz cells: max {:.3e} m; {} in \
             affine cells: max {:.3e} m, max normal angle {:.3e} rad",
            &s.dims[..3],
            st.points,
            st.max_err,
            pct(0.5),
            pct(0.99),
            st.lipschitz,
            st.max_err_lipschitz,
            st.affine,
            st.max_err_affine,
            st.max_angle_affine,
        );
        // f32 storage and sampling add ~1e-7 of the coordinates' magnitude.
        let slack = 1e-6;
        assert!(st.max_err_lipschitz <= bound + slack, "{name}: {st:?}");
        assert!(st.max_err_affine <= slack, "{name}");
        assert!(st.max_angle_affine <= 1e-4, "{name}");
        assert!(
            st.affine > st.points / 10,
            "{name}: too few affine cells to judge"
        );
    }

    #[test]
    fn cube_error() {
        let mesh = cube_mesh();
        let h = SdfGrid::for_bounds(DVec3::ZERO, DVec3::ONE).cell;
        let (st, s) = agreement(&mesh, 4.0 * h, 4000, 5);
        check_bound("unit cube", &st, &s);
        // Closed mesh: φ is continuous everywhere.
        assert_eq!(st.lipschitz, st.points);
    }

    #[test]
    fn terrain_obj_error() {
        let mesh = terrain_obj();
        let (min, max) = mesh
            .vertices
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(*v), hi.max(*v))
            });
        let h = SdfGrid::for_bounds(min, max).cell;
        let (st, s) = agreement(&mesh, 4.0 * h, 20000, 9);
        check_bound("scenes/terrain.obj", &st, &s);
    }

    #[test]
    fn outside_the_grid() {
        let t = terrain(TerrainShape::Mesh(cube_mesh()));
        let b = pack(std::slice::from_ref(&t));
        let s = b.surfaces[0];
        // Straight out from a face, the extension is exact: φ(c) is affine there.
        for (x, phi, n) in [
            (DVec3::new(5.0, 0.5, 0.5), 4.0, DVec3::X),
            (DVec3::new(0.3, -7.0, 0.6), 7.0, DVec3::NEG_Y),
            (DVec3::new(0.5, 0.5, 3.0), 2.0, DVec3::Z),
        ] {
            let (p, normal) = sample_sdf(&s, &b.data, x);
            assert!((p - phi).abs() < 1e-5, "{x}: {p}");
            assert!((normal - n).length() < 1e-5, "{x}: {normal}");
        }
        // Beyond a corner: positive, within 2d of the truth, pointing away.
        let x = DVec3::new(4.0, 5.0, -3.0);
        let (p, normal) = sample_sdf(&s, &b.data, x);
        let exact = Surface::new(&t).query(x, f64::INFINITY).unwrap();
        assert!(p >= exact.phi - 1e-6 && p <= exact.phi + 2.0 * 6.0);
        assert!(normal.dot(exact.normal) > 0.9);
        // Inside-out cube (a room): outside the grid is solid.
        let mut room = cube_mesh();
        for t in &mut room.triangles {
            t.swap(1, 2);
        }
        let b = pack(&[terrain(TerrainShape::Mesh(room))]);
        let (p, normal) = sample_sdf(&b.surfaces[0], &b.data, DVec3::new(0.5, 0.5, 5.0));
        assert!((p + 4.0).abs() < 1e-5, "{p}");
        assert!((normal - DVec3::NEG_Z).length() < 1e-5);
    }
}
