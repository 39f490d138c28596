//! Terrain for the GPU: packs the scene's terrain shapes into the two storage buffers that
//! `shaders/shared/terrain.wgsl` reads at group 1 (`surfaces`: one [`SurfaceGpu`] per shape,
//! `terrain_data`: heights and signed-distance grids). `shaders/shared/terrain.wgsl` is the f32
//! twin of [`softbody_terrain::Surface`]; its header lists which field holds what for each kind.
//!
//! # Heightfields
//!
//! The GPU uses the CPU's triangulation ([`softbody_terrain::CellTriangle`]) and inside test
//! exactly; only the nearest-triangle search is bounded: it visits the cells that overlap the
//! square of half-size R around the point (R = the distance to the surface point straight
//! above or below it, an upper bound on |φ|; outside the solid, at most the reach), but no
//! more than [`HF_MAX_HALF_WINDOW`] cells on each side of the point's own cell (≤ 17 × 17
//! cells, 578 triangles). Hence φ is exact (to f32 rounding) whenever the true
//! |φ| ≤ `HF_MAX_HALF_WINDOW · min(dx, dz)`, which covers every contact for any reach below
//! that; farther from the surface |φ| is the distance to the nearest triangle in the window,
//! an overestimate that never exceeds the vertical distance, and the sign is always exact.
//!
//! # Meshes
//!
//! [`pack`] bakes each mesh into the signed-distance grid of [`softbody_terrain::sdf`] (whose
//! module doc has the grid rule, the error bounds and what the shader does outside the grid)
//! and appends its node values to `terrain_data`.

use bytemuck::{Pod, Zeroable};
use glam::{DMat3, DVec3};
use softbody_scene::{Terrain, TerrainShape, rotation_from_degrees};

use crate::layout::{FRICTION_COULOMB, friction_code};
use softbody_terrain::Surface;
use softbody_terrain::sdf::SdfGrid;

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

/// Degenerate-normal threshold of the GPU, relative to the shape's coordinate magnitude M
/// (the CPU's is 1e-9, for f64): within max(1e-4·M, [`NORMAL_EPS_ABS`]) of the surface the
/// normal comes from the geometry (box face, heightfield triangle, +y at a ball's centre), as
/// on the CPU. f32 rounding puts ~1e-7·M of noise on the offset from the closest point, so
/// directions computed just above the threshold are good to about 1e-3 rad.
pub const NORMAL_EPS_REL: f64 = 1e-4;
/// Floor of the degenerate-normal threshold, metres.
pub const NORMAL_EPS_ABS: f64 = 1e-9;

/// Heightfield search window cap, cells on each side of the point's cell; must equal
/// `TERRAIN_HF_MAX_HALF_WINDOW` in `shaders/shared/terrain.wgsl`.
pub const HF_MAX_HALF_WINDOW: u32 = 8;

/// One terrain shape as the shaders read it; must match `SurfaceGpu` in
/// `shaders/shared/terrain.wgsl` (112 bytes, 16-byte aligned rows; the per-kind use of each field
/// is listed in that file's header).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct SurfaceGpu {
    /// One of the `KIND_*` constants.
    pub kind: u32,
    /// [`friction_code`] of the surface's model.
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

    /// The signed-distance grid of surface `k` and its node values, as [`pack`] laid them out;
    /// None unless that surface is a [`KIND_MESH`].
    pub fn sdf(&self, k: usize) -> Option<(SdfGrid, &[f32])> {
        let s = self.surfaces.get(k)?;
        if s.kind != KIND_MESH {
            return None;
        }
        let [origin @ .., cell] = s.center.map(f64::from);
        let grid = SdfGrid {
            origin: DVec3::from_array(origin),
            cell,
            dims: [s.dims[0], s.dims[1], s.dims[2]].map(|n| n as usize),
        };
        let offset = s.dims[3] as usize;
        Some((grid, &self.data[offset..offset + grid.len()]))
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

/// Packs the scene's terrain for the shaders, baking each mesh's signed-distance grid
/// ([`SdfGrid::bake`], parallel over the grid's z slices).
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
        s.friction_model = friction_code(t.friction_model);
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
            let grid = SdfGrid::for_vertices(&m.vertices);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::FRICTION_VISCOUS;
    use softbody_scene::{FrictionModel, Heightfield, TriangleMesh};

    fn terrain(shape: TerrainShape) -> Terrain {
        Terrain {
            shape,
            restitution: 0.25,
            friction: 0.75,
            friction_model: FrictionModel::Viscous,
        }
    }

    /// The unit cube [0, 1]³, closed and outward-wound.
    fn cube_mesh() -> TriangleMesh {
        TriangleMesh::cube(DVec3::ZERO, 1.0)
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
        let shader = include_str!("../shaders/shared/terrain.wgsl");
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
        let baked = grid.bake(&Surface::new(&scene[4]));
        assert_eq!(b.sdf(4), Some((grid, &baked[..])));
        assert_eq!(b.sdf(3), None);

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
}
