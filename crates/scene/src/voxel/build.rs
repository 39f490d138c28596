//! [`Voxels::new`], step by step: the mesh's bounding box, the lattice over it (refused before
//! it is allocated when it is too large), the cells the triangles cross and touch, the winding
//! number w at the other cells' centres, the kept cells (crossed, or |w| ≥ ½), each vertex's
//! cell, and the particles and springs of the kept cells.

use glam::DVec3;

use super::{
    BYTES_PER_LATTICE_POINT, CLEARLY_INSIDE, LatticeSize, UNDECIDED_SHARE, VoxelError, VoxelKey,
    Voxels, check_mesh, enclosed_volume, is_closed, triangle_meets_box, winding_number,
};
use crate::error::Num;
use crate::scene::TriangleMesh;
use crate::topology::{self, SpringKind};
use crate::winding::WindingTree;
use crate::{SpringCounts, model};

fn fail<T>(key: VoxelKey, message: String) -> Result<T, VoxelError> {
    Err(VoxelError { key, message })
}

/// Cells along an extent of `extent` at spacing `h`: `ceil(extent / h)`, at least 1, where a
/// quotient within 10⁻⁹ of a whole number counts as that number (a box 0.3 m long at h = 0.06 m
/// is 5 cells, not 6 because 0.3/0.06 = 5.000000000000001).
fn cells_along(extent: f64, h: f64) -> f64 {
    let x = extent / h;
    let r = x.round();
    let n = if (x - r).abs() <= 1e-9 * r.max(1.0) {
        r
    } else {
        x.ceil()
    };
    n.max(1.0)
}

/// The centre and the extent of the bounding box of the `used` vertices of `scaled`, the
/// mesh's scaled vertices (a vertex no triangle uses is carried along, but shapes nothing);
/// refused without extent.
fn bounding_box(
    scaled: &[DVec3],
    used: &[bool],
    mesh: &TriangleMesh,
) -> Result<(DVec3, DVec3), VoxelError> {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for (&v, _) in scaled.iter().zip(used).filter(|(_, used)| **used) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    let offset = 0.5 * (lo + hi);
    let extent = hi - lo;
    if !extent.is_finite() || extent.max_element() <= 0.0 {
        return fail(
            VoxelKey::File,
            format!(
                "{}: the triangles have no extent (every vertex at one point)",
                mesh.path.display()
            ),
        );
    }
    Ok((offset, extent))
}

/// The lattice's cells in local coordinates: edge `h`, `n` per axis (as `cells_along` counts
/// them), cell (i, j, k) is [i, i + 1] × [j, j + 1] × [k, k + 1] in lattice units from
/// `origin`, and number i + nx·(j + ny·k).
struct Grid {
    h: f64,
    n: [f64; 3],
    cells: [u32; 3],
    dims: [usize; 3],
    origin: DVec3,
}

impl Grid {
    /// The lattice of `size` centred on a bounding box of `extent`; refused when its points
    /// are more than a model holds or than the memory left holds.
    fn new(extent: DVec3, size: LatticeSize) -> Result<Grid, VoxelError> {
        let h = match size {
            LatticeSize::Cell(h) => h,
            LatticeSize::Resolution(r) => extent.max_element() / f64::from(r.max(1)),
        };
        let n = [0, 1, 2].map(|a| cells_along(extent[a], h));
        let points = (n[0] + 1.0) * (n[1] + 1.0) * (n[2] + 1.0);
        let limit = model::MAX_PARTICLES as f64;
        if !(h > 0.0 && points <= limit) {
            return fail(
                VoxelKey::Size,
                format!(
                    "a lattice of {} × {} × {} cells ({points:.3e} points) is more than the {} \
                     particles supported",
                    Num(n[0]),
                    Num(n[1]),
                    Num(n[2]),
                    model::MAX_PARTICLES
                ),
            );
        }
        let need = (points as u64).saturating_mul(BYTES_PER_LATTICE_POINT);
        if let Some((have, what)) =
            crate::memory::available_memory().filter(|&(have, _)| need > have)
        {
            return fail(
                VoxelKey::Size,
                format!(
                    "voxelising a lattice of {} × {} × {} cells needs about {:.1} GiB and {:.1} \
                     GiB are {what}",
                    n[0],
                    n[1],
                    n[2],
                    need as f64 / (1u64 << 30) as f64,
                    have as f64 / (1u64 << 30) as f64
                ),
            );
        }
        let cells = n.map(|x| x as u32);
        Ok(Grid {
            h,
            n,
            cells,
            dims: cells.map(|c| c as usize),
            origin: -0.5 * h * DVec3::new(n[0], n[1], n[2]),
        })
    }

    fn len(&self) -> usize {
        let [nx, ny, nz] = self.dims;
        nx * ny * nz
    }

    fn index(&self, i: usize, j: usize, k: usize) -> usize {
        let [nx, ny, _] = self.dims;
        i + nx * (j + ny * k)
    }

    fn coords(&self, at: usize) -> (usize, usize, usize) {
        let [nx, ny, _] = self.dims;
        (at % nx, at / nx % ny, at / (nx * ny))
    }

    /// The last cell, in lattice units.
    fn top(&self) -> DVec3 {
        let n = self.n;
        DVec3::new(n[0] - 1.0, n[1] - 1.0, n[2] - 1.0)
    }

    /// The centre of cell `at`, local coordinates.
    fn centre(&self, at: usize) -> DVec3 {
        let (i, j, k) = self.coords(at);
        self.origin + self.h * (DVec3::new(i as f64, j as f64, k as f64) + 0.5)
    }

    /// The cells a triangle crosses (meets the open cell: tested against the cell shrunk by
    /// 1e-9 h) and the cells it touches (meets the closed cell, grown by 1e-9 h), of the
    /// triangles over `unit`, the vertices in lattice units. A triangle lying in a lattice
    /// plane touches the cells on both sides and crosses neither: the centre test decides
    /// which side is kept.
    fn crossings(&self, unit: &[DVec3], triangles: &[[u32; 3]]) -> (Vec<bool>, Vec<bool>) {
        let mut crossed = vec![false; self.len()];
        let mut touched = vec![false; self.len()];
        let (shrunk, grown) = (DVec3::splat(0.5 - 1e-9), DVec3::splat(0.5 + 1e-9));
        let top = self.top();
        for t in triangles {
            let c = t.map(|i| unit[i as usize]);
            let lo = (c[0].min(c[1]).min(c[2]) - 1e-9)
                .floor()
                .clamp(DVec3::ZERO, top);
            let hi = (c[0].max(c[1]).max(c[2]) + 1e-9)
                .floor()
                .clamp(DVec3::ZERO, top);
            for k in lo.z as usize..=hi.z as usize {
                for j in lo.y as usize..=hi.y as usize {
                    for i in lo.x as usize..=hi.x as usize {
                        let at = self.index(i, j, k);
                        if crossed[at] {
                            continue;
                        }
                        let centre = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                        if !touched[at] {
                            touched[at] = triangle_meets_box(c, centre, grown);
                        }
                        if touched[at] {
                            crossed[at] = triangle_meets_box(c, centre, shrunk);
                        }
                    }
                }
            }
        }
        (crossed, touched)
    }

    /// |w| at the centre of every cell no triangle crosses, on a closed mesh: `winding` at
    /// each touched cell (its centre is off the surface: w is an integer), and once per
    /// 6-connected component of untouched cells.
    fn closed_windings(
        &self,
        crossed: &[bool],
        touched: &[bool],
        winding: &dyn Fn(usize) -> f64,
    ) -> Vec<f64> {
        let [nx, ny, nz] = self.dims;
        let mut w = vec![0.0f64; self.len()];
        let mut seen = touched.to_vec();
        let mut stack = Vec::new();
        for start in 0..w.len() {
            if crossed[start] {
                continue;
            }
            if touched[start] {
                w[start] = winding(start).abs();
                continue;
            }
            if seen[start] {
                continue;
            }
            let value = winding(start).abs();
            seen[start] = true;
            stack.push(start);
            while let Some(at) = stack.pop() {
                w[at] = value;
                let (i, j, k) = self.coords(at);
                let mut visit = |ok: bool, next: usize| {
                    if ok && !seen[next] {
                        seen[next] = true;
                        stack.push(next);
                    }
                };
                visit(i > 0, at.wrapping_sub(1));
                visit(i + 1 < nx, at + 1);
                visit(j > 0, at.wrapping_sub(nx));
                visit(j + 1 < ny, at + nx);
                visit(k > 0, at.wrapping_sub(nx * ny));
                visit(k + 1 < nz, at + nx * ny);
            }
        }
        w
    }

    /// |w| at the centre of every cell no triangle crosses, on an open mesh (`local`, its
    /// vertices in local coordinates), by the tree: cells × log(triangles) instead of cells ×
    /// triangles solid angles (the fast winding number; within 1e-3 of the exact sum, which
    /// decides at ½ and ¾). Refused when too many cells are undecided.
    fn open_windings(
        &self,
        crossed: &[bool],
        local: &[DVec3],
        mesh: &TriangleMesh,
    ) -> Result<Vec<f64>, VoxelError> {
        let mut w = vec![0.0f64; self.len()];
        let tree = WindingTree::new(local, &mesh.triangles);
        let (mut undecided, mut candidates) = (0u64, 0u64);
        for at in (0..w.len()).filter(|&at| !crossed[at]) {
            w[at] = tree.winding(self.centre(at)).abs();
            if w[at] > 0.25 {
                candidates += 1;
                if w[at] < 0.75 {
                    undecided += 1;
                }
            }
        }
        if undecided as f64 > UNDECIDED_SHARE * candidates.max(1) as f64 {
            return fail(
                VoxelKey::File,
                format!(
                    "{} is not closed enough to tell inside from outside: the winding \
                     number is between ¼ and ¾ at {undecided} of the {candidates} cells \
                     where it is above ¼ (more than {}%); close its holes",
                    mesh.path.display(),
                    UNDECIDED_SHARE * 100.0
                ),
            );
        }
        Ok(w)
    }

    /// The cells whose centre is clearly inside (|w| ≥ [`CLEARLY_INSIDE`]); refused when there
    /// are none.
    fn inside_cells(
        &self,
        crossed: &[bool],
        w: &[f64],
        closed: bool,
        winding: &dyn Fn(usize) -> f64,
        mesh: &TriangleMesh,
    ) -> Result<u64, VoxelError> {
        let mut inside_cells = (0..w.len())
            .filter(|&at| !crossed[at] && w[at] >= CLEARLY_INSIDE)
            .count() as u64;
        // On a closed mesh a crossed cell whose centre is clearly inside counts too (a plate
        // thinner than a cell has no other). Not on an open one: a centre on a sheet gets ±½
        // from each triangle whose edge it lies on, whatever the sides, so only cells off the
        // surface tell.
        if inside_cells == 0 && closed {
            inside_cells = (0..w.len())
                .filter(|&at| crossed[at] && winding(at).abs() >= CLEARLY_INSIDE)
                .count() as u64;
        }
        if inside_cells == 0 {
            let n = self.n;
            return fail(
                VoxelKey::Size,
                format!(
                    "no cell of the {} × {} × {} lattice (h = {} m) has its centre inside {} \
                     (winding number ¾ or more): the mesh is flat, open or thinner than a \
                     cell; use a smaller cell",
                    n[0],
                    n[1],
                    n[2],
                    Num(self.h),
                    mesh.path.display()
                ),
            );
        }
        Ok(inside_cells)
    }

    /// Each vertex's cell (`unit`: the vertices in lattice units) and its coordinates in it.
    ///
    /// A vertex a triangle uses (`used`) is in the cell holding it, or, on a lattice plane, the
    /// first kept one of those whose boundary holds it; one no kept cell holds keeps its cell
    /// (a vertex of a triangle lying in a lattice plane outside everything), which is kept in
    /// `present` from then on. A vertex no triangle uses adds no cell: it is in the kept cell
    /// holding it, or else in the kept cell whose centre is nearest it (the first in lattice
    /// order of those equally near), its coordinates there outside [0, 1].
    fn embed(&self, unit: &[DVec3], used: &[bool], present: &mut [bool]) -> Vec<([u32; 3], DVec3)> {
        let mut cells = vec![None; unit.len()];
        // The used vertices first: the cells they keep are there for the others.
        for pass_used in [true, false] {
            for (v, &u) in unit
                .iter()
                .enumerate()
                .filter(|(v, _)| used[*v] == pass_used)
            {
                let holding = self.cells_holding(u, pass_used);
                let kept = holding.iter().copied().find(|&c| present[self.at(c)]);
                cells[v] = Some(match (kept, pass_used) {
                    (Some(cell), _) => (cell, true),
                    (None, true) => {
                        present[self.at(holding[0])] = true;
                        (holding[0], true)
                    }
                    (None, false) => (self.nearest_kept(u, present), false),
                });
            }
        }
        (cells.into_iter().zip(unit))
            .map(|(cell, &u)| {
                let (cell, holds) = cell.expect("every vertex is used or not");
                let t = u - cell;
                (
                    [cell.x as u32, cell.y as u32, cell.z as u32],
                    if holds {
                        t.clamp(DVec3::ZERO, DVec3::ONE)
                    } else {
                        t
                    },
                )
            })
            .collect()
    }

    fn at(&self, c: DVec3) -> usize {
        self.index(c.x as usize, c.y as usize, c.z as usize)
    }

    /// The cells (lattice coordinates of their lowest corner) whose closed box holds `u`, in
    /// lattice order: one, or up to eight on lattice planes. Outside the lattice, the cell it
    /// clamps to when `clamp` (a vertex of the triangles, inside but for rounding), else none.
    fn cells_holding(&self, u: DVec3, clamp: bool) -> Vec<DVec3> {
        let top = self.top();
        let outside = (0..3).any(|a| !(-1e-9..=top[a] + 1.0 + 1e-9).contains(&u[a]));
        if outside && !clamp {
            return Vec::new();
        }
        let choices = |a: usize| -> [Option<f64>; 2] {
            let r = u[a].round();
            let f = u[a].floor().clamp(0.0, top[a]);
            if (u[a] - r).abs() <= 1e-9 && r >= 1.0 && r <= top[a] {
                [Some(r - 1.0), Some(r)]
            } else {
                [Some(f), None]
            }
        };
        let (cx, cy, cz) = (choices(0), choices(1), choices(2));
        let mut all = Vec::with_capacity(8);
        for &k in cz.iter().flatten() {
            for &j in cy.iter().flatten() {
                for &i in cx.iter().flatten() {
                    all.push(DVec3::new(i, j, k));
                }
            }
        }
        all
    }

    /// The kept cell whose centre is nearest `u` (lattice units), the first in lattice order
    /// of those equally near. Cells are the Voronoi regions of their centres, so a point in a
    /// kept cell gets that cell.
    fn nearest_kept(&self, u: DVec3, present: &[bool]) -> DVec3 {
        let mut best = (f64::INFINITY, DVec3::ZERO);
        for at in (0..present.len()).filter(|&at| present[at]) {
            let (i, j, k) = self.coords(at);
            let corner = DVec3::new(i as f64, j as f64, k as f64);
            let d = (corner + 0.5).distance_squared(u);
            if d < best.0 {
                best = (d, corner);
            }
        }
        best.1
    }

    /// The particles: the corners of the `present` cells, in lattice order. Returns the
    /// particle of each lattice point (`u32::MAX` where none) and each particle's point.
    fn particles(&self, present: &[bool]) -> (Vec<u32>, Vec<[u32; 3]>) {
        let [nx, ny, nz] = self.dims;
        let pn = [nx + 1, ny + 1, nz + 1];
        let mut particle_of = vec![u32::MAX; pn[0] * pn[1] * pn[2]];
        for (at, _) in present.iter().enumerate().filter(|(_, p)| **p) {
            let (i, j, k) = self.coords(at);
            for c in 0..8 {
                let (a, b, d) = (i + (c & 1), j + (c >> 1 & 1), k + (c >> 2));
                particle_of[a + pn[0] * (b + pn[1] * d)] = 0;
            }
        }
        let mut points = Vec::new();
        for (p, slot) in particle_of.iter_mut().enumerate() {
            if *slot == 0 {
                *slot = points.len() as u32;
                points.push([
                    (p % pn[0]) as u32,
                    (p / pn[0] % pn[1]) as u32,
                    (p / (pn[0] * pn[1])) as u32,
                ]);
            }
        }
        (particle_of, points)
    }

    /// Springs of each family on the `present` cells.
    fn spring_counts(&self, present: &[bool]) -> SpringCounts {
        let cells = self.cells;
        let mut springs = SpringCounts::default();
        topology::for_each_lattice_spring(
            cells.map(|c| c + 1),
            Some(present),
            0..cells[2] + 1,
            |_, _, o| match topology::OFFSETS[o].1 {
                SpringKind::Structural => springs.structural += 1,
                SpringKind::Shear => springs.shear += 1,
                SpringKind::Bending => springs.bending += 1,
            },
        );
        springs
    }
}

impl Voxels {
    /// Voxelises `mesh` (file coordinates) scaled by `scale` (each component positive) at
    /// `size`. Refuses, before allocating the lattice, one whose flags would not fit in memory.
    pub fn new(mesh: TriangleMesh, scale: DVec3, size: LatticeSize) -> Result<Voxels, VoxelError> {
        check_mesh(&mesh).map_err(|m| VoxelError {
            key: VoxelKey::File,
            message: m,
        })?;
        let scaled: Vec<DVec3> = mesh.vertices.iter().map(|&v| v * scale).collect();
        let mut used = vec![false; scaled.len()];
        for &i in mesh.triangles.iter().flatten() {
            used[i as usize] = true;
        }
        let (offset, extent) = bounding_box(&scaled, &used, &mesh)?;
        let grid = Grid::new(extent, size)?;
        let (origin, h) = (grid.origin, grid.h);
        let unit: Vec<DVec3> = scaled.iter().map(|&v| (v - offset - origin) / h).collect();
        let (crossed, touched) = grid.crossings(&unit, &mesh.triangles);

        let local: Vec<DVec3> = scaled.iter().map(|&v| v - offset).collect();
        let winding = |at: usize| winding_number(&local, &mesh.triangles, grid.centre(at));
        let closed = is_closed(&mesh);
        // Translation leaves a closed mesh's volume as it is; an inside-out one is negative.
        let enclosed = closed.then(|| enclosed_volume(&local, &mesh.triangles).abs());
        let w = if closed {
            grid.closed_windings(&crossed, &touched, &winding)
        } else {
            grid.open_windings(&crossed, &local, &mesh)?
        };
        let mut present: Vec<bool> = (0..w.len()).map(|at| crossed[at] || w[at] >= 0.5).collect();
        let inside_cells = grid.inside_cells(&crossed, &w, closed, &winding, &mesh)?;
        let embedding = grid.embed(&unit, &used, &mut present);
        // Extended weights grow as the cube of the distance: beyond one lattice length they
        // would magnify the particles' rounding more than a vertex can carry.
        let longest = grid.cells.iter().copied().max().unwrap_or(1);
        let reach = f64::from(longest) + 1.0;
        if let Some(v) =
            (0..embedding.len()).find(|&v| !used[v] && embedding[v].1.abs().max_element() > reach)
        {
            return fail(
                VoxelKey::File,
                format!(
                    "{}: vertex {}, which no face uses, is farther from the lattice than the \
                     lattice is long ({longest} cells): it cannot ride on it; remove it or bring \
                     it nearer",
                    mesh.path.display(),
                    v
                ),
            );
        }
        let (particle_of, points) = grid.particles(&present);
        let springs = grid.spring_counts(&present);
        Ok(Voxels {
            mesh,
            scale,
            size,
            offset,
            cell: h,
            cells: grid.cells,
            origin,
            present,
            particle_of,
            points,
            springs,
            embedding,
            inside_cells,
            closed,
            enclosed,
        })
    }
}
