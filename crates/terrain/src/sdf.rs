//! The signed-distance grid that mesh terrain is baked into for the GPU (`softbody-gpu` uploads it,
//! `crates/gpu/shaders/shared/terrain.wgsl` samples it), and the shader's sampler in f64
//! ([`SdfGrid::sample`]), for tests and error studies.
//!
//! # The grid
//!
//! [`SdfGrid::bake`] samples the CPU's φ ([`Surface::query`] at each node with an infinite
//! reach, positive in free space) at the nodes of a regular grid ([`SdfGrid::for_bounds`]):
//! cell size h = (bounding-box diagonal D) / [`SDF_CELLS_PER_DIAGONAL`], the mesh's bounding
//! box padded on every side by [`SDF_MARGIN_FRACTION`]·D + [`SDF_MARGIN_CELLS`]·h, at most
//! [`SDF_MAX_NODES_PER_AXIS`] nodes along an axis and [`SDF_MAX_NODES`] in all (h grows by 5 %
//! steps until both hold; with the default constants they never bind: a mesh needs at most
//! about 160 nodes along an axis and 1.2 M nodes, 4.7 MB). Nodes are stored x fastest, then y,
//! then z. The shader interpolates trilinearly and takes the normal from the gradient of the
//! interpolant.
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

use glam::DVec3;
use rayon::prelude::*;

use crate::Surface;

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
    /// The grid for a mesh with these vertices: [`SdfGrid::for_bounds`] of their bounding box.
    pub fn for_vertices(vertices: &[DVec3]) -> SdfGrid {
        let (min, max) = vertices
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(*v), hi.max(*v))
            });
        Self::for_bounds(min, max)
    }

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

    /// φ at every node, x fastest, then y, then z, from [`Surface::query`] (in parallel over
    /// the z slices).
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

    /// The shader's mesh sampler (`terrain_mesh` in `crates/gpu/shaders/shared/terrain.wgsl`) in
    /// f64, operation for operation: (φ, unit normal) at x from the node values `values` (as
    /// [`SdfGrid::bake`] returns them).
    pub fn sample(&self, values: &[f32], x: DVec3) -> (f64, DVec3) {
        let lo = self.origin;
        let h = self.cell;
        let n = self.dims;
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
            f64::from(values[cell[0] + di + n[0] * (cell[1] + dj + n[1] * (cell[2] + dk))])
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{Rng, cube_mesh, surface};
    use softbody_scene::{TerrainShape, TriangleMesh};

    fn terrain_obj() -> TriangleMesh {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/terrain.obj");
        softbody_scene::mesh::load_obj(&path).unwrap()
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
            let grid = SdfGrid::for_vertices(&mesh.vertices);
            let cpu = surface(TerrainShape::Mesh(mesh));
            let values = grid.bake(&cpu);
            let [nx, ny, nz] = grid.dims;
            let mut rng = Rng::new(3);
            for n in 0..3000 {
                // The eight corners of the grid, then random nodes.
                let (i, j, k) = if n < 8 {
                    (
                        (n & 1) * (nx - 1),
                        (n >> 1 & 1) * (ny - 1),
                        (n >> 2) * (nz - 1),
                    )
                } else {
                    (rng.index(nx), rng.index(ny), rng.index(nz))
                };
                let x = grid.node(i, j, k);
                let phi = cpu.query(x, f64::INFINITY).unwrap().phi;
                assert_eq!(
                    values[i + nx * (j + ny * k)],
                    phi as f32,
                    "node {i} {j} {k}"
                );
                // The sampler returns node values at nodes.
                let (sampled, _) = grid.sample(&values, x);
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
    fn agreement(mesh: &TriangleMesh, band: f64, count: usize, seed: u64) -> (Agreement, SdfGrid) {
        let grid = SdfGrid::for_vertices(&mesh.vertices);
        let cpu = surface(TerrainShape::Mesh(mesh.clone()));
        let values = grid.bake(&cpu);
        let at = |x: DVec3| cpu.query(x, f64::INFINITY).unwrap();
        let (origin, h) = (grid.origin, grid.cell);
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
        let mut rng = Rng::new(seed);
        let mut st = Agreement::default();
        for _ in 0..count {
            let mut pick = rng.unit() * total;
            let mut k = 0;
            while k + 1 < tris.len() && pick >= areas[k] {
                pick -= areas[k];
                k += 1;
            }
            let [a, bb, c] = tris[k];
            let (mut u, mut v) = (rng.unit(), rng.unit());
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
            let (phi, normal) = grid.sample(&values, x);
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
        (st, grid)
    }

    fn check_bound(name: &str, st: &Agreement, grid: &SdfGrid) {
        let h = grid.cell;
        let bound = h * 3f64.sqrt() / 2.0;
        let mut sorted = st.errors.clone();
        sorted.sort_by(f64::total_cmp);
        let pct = |q: f64| sorted[((sorted.len() - 1) as f64 * q) as usize];
        eprintln!(
            "{name}: h = {h:.5} m, grid {:?}, bound h√3/2 = {bound:.5} m; {} points: max |Δφ| = \
             {:.3e} m (median {:.3e}, 99% {:.3e}); {} in Lipschitz cells: max {:.3e} m; {} in \
             affine cells: max {:.3e} m, max normal angle {:.3e} rad",
            grid.dims,
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
        let (st, grid) = agreement(&mesh, 4.0 * h, 4000, 5);
        check_bound("unit cube", &st, &grid);
        // Closed mesh: φ is continuous everywhere.
        assert_eq!(st.lipschitz, st.points);
    }

    #[test]
    fn terrain_obj_error() {
        let mesh = terrain_obj();
        let h = SdfGrid::for_vertices(&mesh.vertices).cell;
        let (st, grid) = agreement(&mesh, 4.0 * h, 20000, 9);
        check_bound("scenes/terrain.obj", &st, &grid);
    }

    #[test]
    fn outside_the_grid() {
        let grid = SdfGrid::for_bounds(DVec3::ZERO, DVec3::ONE);
        let cpu = surface(TerrainShape::Mesh(cube_mesh()));
        let values = grid.bake(&cpu);
        // Straight out from a face, the extension is exact: φ(c) is affine there.
        for (x, phi, n) in [
            (DVec3::new(5.0, 0.5, 0.5), 4.0, DVec3::X),
            (DVec3::new(0.3, -7.0, 0.6), 7.0, DVec3::NEG_Y),
            (DVec3::new(0.5, 0.5, 3.0), 2.0, DVec3::Z),
        ] {
            let (p, normal) = grid.sample(&values, x);
            assert!((p - phi).abs() < 1e-5, "{x}: {p}");
            assert!((normal - n).length() < 1e-5, "{x}: {normal}");
        }
        // Beyond a corner: positive, within 2d of the truth, pointing away.
        let x = DVec3::new(4.0, 5.0, -3.0);
        let (p, normal) = grid.sample(&values, x);
        let exact = cpu.query(x, f64::INFINITY).unwrap();
        assert!(p >= exact.phi - 1e-6 && p <= exact.phi + 2.0 * 6.0);
        assert!(normal.dot(exact.normal) > 0.9);
        // Inside-out cube (a room): outside the grid is solid.
        let mut room = cube_mesh();
        for t in &mut room.triangles {
            t.swap(1, 2);
        }
        let room = surface(TerrainShape::Mesh(room));
        let (p, normal) = grid.sample(&grid.bake(&room), DVec3::new(0.5, 0.5, 5.0));
        assert!((p + 4.0).abs() < 1e-5, "{p}");
        assert!((normal - DVec3::NEG_Z).length() < 1e-5);
    }
}
