//! Spring topology of a cuboid body.
//!
//! Particle (i, j, k) has index `i + nx·(j + ny·k)` and sits on a regular grid spanning `size`,
//! rotated, then centred. Springs join a particle p to p + o for each offset o below whose most
//! significant non-zero component (k, then j, then i) is positive, so each pair appears once,
//! with `a < b`:
//! - structural: axis neighbours one cell apart (3 offsets);
//! - shear: pairs inside one cell that differ in two coordinates (face diagonals, 6 offsets) or
//!   three (body diagonals, 4 offsets);
//! - bending: axis neighbours two cells apart (3 offsets).
//!
//! Springs come out in ascending `a`, each particle's in the offset order below.

use glam::DVec3;

use crate::scene::{Cuboid, SpringCounts, rotation_from_degrees};

/// The three spring families.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpringKind {
    /// Axis neighbours one cell apart (and the explicit springs of `particles` bodies).
    Structural,
    /// Face and body diagonals of a cell.
    Shear,
    /// Axis neighbours two cells apart.
    Bending,
}

/// Grid offsets (di, dj, dk) and the family each belongs to.
pub const OFFSETS: [([i32; 3], SpringKind); 16] = {
    use SpringKind::*;
    [
        ([1, 0, 0], Structural),
        ([0, 1, 0], Structural),
        ([0, 0, 1], Structural),
        ([1, 1, 0], Shear),
        ([-1, 1, 0], Shear),
        ([1, 0, 1], Shear),
        ([-1, 0, 1], Shear),
        ([0, 1, 1], Shear),
        ([0, -1, 1], Shear),
        ([1, 1, 1], Shear),
        ([-1, 1, 1], Shear),
        ([1, -1, 1], Shear),
        ([-1, -1, 1], Shear),
        ([2, 0, 0], Bending),
        ([0, 2, 0], Bending),
        ([0, 0, 2], Bending),
    ]
};

/// Rest length of every spring of grid offset `o` on a lattice of cell edges `spacing`:
/// |o ⊙ spacing|, one value per offset. The lattice is regular, so this is the distance
/// between the spring's ends at rest; computing it once per offset rather than from each
/// pair's rotated and translated positions (which differ from it by rounding, particle to
/// particle) makes a lattice body's springs a stencil: the same parameters at every particle.
pub fn offset_rest(spacing: DVec3, o: [i32; 3]) -> f64 {
    (DVec3::new(f64::from(o[0]), f64::from(o[1]), f64::from(o[2])) * spacing).length()
}

/// Cell edges of a cuboid's lattice per axis: size / (resolution − 1).
pub fn cuboid_spacing(c: &Cuboid) -> DVec3 {
    let [nx, ny, nz] = c.resolution.map(|r| f64::from(r - 1));
    c.size / DVec3::new(nx, ny, nz)
}

/// Initial particle positions of a cuboid, in index order.
pub fn cuboid_positions(c: &Cuboid) -> Vec<DVec3> {
    let [nx, ny, nz] = c.resolution.map(|r| r as usize);
    let spacing = cuboid_spacing(c);
    let rot = rotation_from_degrees(c.rotation);
    let mut out = Vec::with_capacity(nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let local = DVec3::new(i as f64, j as f64, k as f64) * spacing - 0.5 * c.size;
                out.push(c.center + rot * local);
            }
        }
    }
    out
}

/// Calls `f(a, b, o)` for every spring of a full grid of `resolution` particles, in order:
/// the lattice with every cell present ([`for_each_lattice_spring`]).
pub fn for_each_cuboid_spring(resolution: [u32; 3], f: impl FnMut(u32, u32, usize)) {
    for_each_cuboid_spring_in(resolution, 0..resolution[2], f);
}

/// [`for_each_cuboid_spring`] for the springs starting in the z-planes `planes` only.
pub fn for_each_cuboid_spring_in(
    resolution: [u32; 3],
    planes: std::ops::Range<u32>,
    f: impl FnMut(u32, u32, usize),
) {
    for_each_lattice_spring(resolution, None, planes, f);
}

/// Calls `f(a, b, o)` (o the spring's index in [`OFFSETS`]) for every spring of a lattice of `points` particles per axis whose
/// cells (`points − 1` per axis, x fastest) are present where `cells` says (`None`: all), in
/// the order of the module doc; `a`, `b` are lattice point indices `i + nx·(j + ny·k)`. Only
/// the springs starting in the z-planes `planes` are visited: the order is plane after plane,
/// so disjoint ranges visit disjoint runs of the sequence.
///
/// A spring of the full grid is kept when it lies in the present cells: a structural or shear
/// spring when some present cell has both ends as corners, a bending spring when both
/// structural springs it spans are kept. Particles of present cells that share no present cell
/// (the two sides of a gap one cell wide, or of a torus's hole) are not joined, so a spring
/// never bridges empty space. With every cell present this is every spring of the grid.
pub fn for_each_lattice_spring(
    points: [u32; 3],
    cells: Option<&[bool]>,
    planes: std::ops::Range<u32>,
    mut f: impl FnMut(u32, u32, usize),
) {
    let [nx, ny, nz] = points.map(|r| r as i64);
    let (cx, cy, cz) = (nx - 1, ny - 1, nz - 1);
    let present = |c: [i64; 3]| match cells {
        None => true,
        Some(cells) => {
            (0..cx).contains(&c[0])
                && (0..cy).contains(&c[1])
                && (0..cz).contains(&c[2])
                && cells[(c[0] + cx * (c[1] + cy * c[2])) as usize]
        }
    };
    // Whether some present cell has p and p + o (o in {−1, 0, 1}³) as corners: along an axis
    // where o is ±1 the cell starts at the smaller end, where it is 0 at p − 1 or p.
    let in_a_cell = |p: [i64; 3], o: [i64; 3]| {
        let choices = |a: usize| -> [Option<i64>; 2] {
            match o[a] {
                0 => [Some(p[a] - 1), Some(p[a])],
                d => [Some(p[a].min(p[a] + d)), None],
            }
        };
        let (x, y, z) = (choices(0), choices(1), choices(2));
        x.iter().flatten().any(|&i| {
            y.iter()
                .flatten()
                .any(|&j| z.iter().flatten().any(|&k| present([i, j, k])))
        })
    };
    for k in i64::from(planes.start)..i64::from(planes.end).min(nz) {
        for j in 0..ny {
            for i in 0..nx {
                let p = i + nx * (j + ny * k);
                for (o, ([di, dj, dk], kind)) in OFFSETS.into_iter().enumerate() {
                    let (qi, qj, qk) = (i + di as i64, j + dj as i64, k + dk as i64);
                    if !((0..nx).contains(&qi) && (0..ny).contains(&qj) && (0..nz).contains(&qk)) {
                        continue;
                    }
                    let kept = cells.is_none() || {
                        let o = [di, dj, dk].map(i64::from);
                        if kind == SpringKind::Bending {
                            let half = o.map(|c| c / 2);
                            let mid = [i + half[0], j + half[1], k + half[2]];
                            in_a_cell([i, j, k], half) && in_a_cell(mid, half)
                        } else {
                            in_a_cell([i, j, k], o)
                        }
                    };
                    if kept {
                        f(p as u32, (qi + nx * (qj + ny * qk)) as u32, o);
                    }
                }
            }
        }
    }
}

/// The outer surface of a grid of `resolution` particles: each boundary face's cells split into
/// two triangles, wound counter-clockwise seen from outside (so (b − a) × (c − a) points
/// outwards while the body keeps its rest orientation), faces in the order −x, +x, −y, +y, −z, +z.
pub fn cuboid_surface(resolution: [u32; 3]) -> Vec<[u32; 3]> {
    let n = resolution.map(|r| r as usize);
    let index = |c: [usize; 3]| (c[0] + n[0] * (c[1] + n[1] * c[2])) as u32;
    let mut out = Vec::new();
    for axis in 0..3 {
        // (axis, u, w) is a cyclic permutation of (x, y, z), so e_u × e_w = e_axis.
        let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
        for (layer, outward) in [(0, false), (n[axis] - 1, true)] {
            for b in 0..n[w] - 1 {
                for a in 0..n[u] - 1 {
                    let corner = |da: usize, db: usize| {
                        let mut c = [0; 3];
                        c[axis] = layer;
                        c[u] = a + da;
                        c[w] = b + db;
                        index(c)
                    };
                    let (p00, p10, p11, p01) =
                        (corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1));
                    if outward {
                        out.extend([[p00, p10, p11], [p00, p11, p01]]);
                    } else {
                        out.extend([[p00, p11, p10], [p00, p01, p11]]);
                    }
                }
            }
        }
    }
    out
}

/// Springs of each family in a cuboid, by formula (no allocation: validation uses it to refuse
/// scenes too large for memory). Families a body leaves out count zero.
pub fn cuboid_spring_counts(c: &Cuboid) -> SpringCounts {
    let counts = grid_spring_counts(c.resolution);
    SpringCounts {
        structural: if c.structural.is_some() {
            counts.structural
        } else {
            0
        },
        shear: if c.shear.is_some() { counts.shear } else { 0 },
        bending: if c.bending.is_some() {
            counts.bending
        } else {
            0
        },
    }
}

/// Springs of grid offset `o` on a full grid of `resolution` particles: the points whose
/// partner p + o lies in the grid (saturating).
pub fn offset_spring_count(resolution: [u32; 3], o: [i32; 3]) -> u64 {
    (0..3).fold(1u64, |acc, a| {
        acc.saturating_mul(u64::from(resolution[a]).saturating_sub(u64::from(o[a].unsigned_abs())))
    })
}

/// Springs of each family on a full grid of `resolution` particles (saturating).
pub fn grid_spring_counts(resolution: [u32; 3]) -> SpringCounts {
    let mut counts = SpringCounts::default();
    for (o, kind) in OFFSETS {
        let slot = match kind {
            SpringKind::Structural => &mut counts.structural,
            SpringKind::Shear => &mut counts.shear,
            SpringKind::Bending => &mut counts.bending,
        };
        *slot = slot.saturating_add(offset_spring_count(resolution, o));
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every face of a 3×4×5 grid: 2(2·3 + 3·4 + 2·4)·2 triangles, all outward (the triangle's
    /// normal points away from the centre), every boundary particle used, closed (each edge
    /// shared by exactly two triangles, in opposite directions).
    #[test]
    fn surface_is_closed_and_outward() {
        let res = [3u32, 4, 5];
        let tris = cuboid_surface(res);
        assert_eq!(tris.len(), 2 * 2 * (2 * 3 + 3 * 4 + 2 * 4));
        let pos = |p: u32| {
            let (i, j, k) = (p % 3, (p / 3) % 4, p / 12);
            DVec3::new(i as f64, j as f64, k as f64)
        };
        let centre = DVec3::new(1.0, 1.5, 2.0);
        let mut edges = std::collections::HashMap::new();
        for t in &tris {
            let [a, b, c] = t.map(pos);
            let normal = (b - a).cross(c - a);
            assert!(
                normal.dot((a + b + c) / 3.0 - centre) > 0.0,
                "{t:?} faces inwards"
            );
            for e in 0..3 {
                *edges.entry((t[e], t[(e + 1) % 3])).or_insert(0) += 1;
            }
        }
        for (&(a, b), &count) in &edges {
            assert_eq!(count, 1, "edge {a}->{b} used twice");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}->{b} has no twin");
        }
        let used: std::collections::HashSet<u32> = tris.iter().flatten().copied().collect();
        assert_eq!(used.len(), 3 * 4 * 5 - 2 * 3); // all but the 1×2×3 interior
    }

    fn enumerate(res: [u32; 3]) -> (SpringCounts, Vec<(u32, u32)>) {
        let mut c = SpringCounts::default();
        let mut pairs = Vec::new();
        for_each_cuboid_spring(res, |a, b, o| {
            pairs.push((a, b));
            match OFFSETS[o].1 {
                SpringKind::Structural => c.structural += 1,
                SpringKind::Shear => c.shear += 1,
                SpringKind::Bending => c.bending += 1,
            }
        });
        (c, pairs)
    }

    #[test]
    fn counts_match_the_formula_and_the_peer_benchmark() {
        // The peer benchmark's 10³ cube has 12,876 springs: 2,700 + 7,776 + 2,400.
        let (c, _) = enumerate([10, 10, 10]);
        assert_eq!((c.structural, c.shear, c.bending), (2700, 7776, 2400));
        for res in [[2, 2, 2], [3, 4, 5], [2, 7, 3], [6, 2, 2]] {
            assert_eq!(enumerate(res).0, grid_spring_counts(res), "{res:?}");
        }
    }

    #[test]
    fn a_single_cell_has_every_pair_once() {
        // 8 corners, 28 pairs: 12 edges, 12 face diagonals, 4 body diagonals; no bending.
        let (c, mut pairs) = enumerate([2, 2, 2]);
        assert_eq!((c.structural, c.shear, c.bending), (12, 16, 0));
        pairs.sort();
        pairs.dedup();
        assert_eq!(pairs.len(), 28);
        assert!(pairs.iter().all(|(a, b)| a < b));
    }

    #[test]
    fn grid_is_centred_rotated_and_indexed() {
        let c = Cuboid {
            size: DVec3::new(2.0, 1.0, 1.0),
            resolution: [3, 2, 2],
            center: DVec3::new(0.0, 5.0, 0.0),
            rotation: DVec3::new(0.0, 0.0, 90.0),
            velocity: DVec3::ZERO,
            mass: 1.0,
            structural: None,
            shear: None,
            bending: None,
        };
        let x = cuboid_positions(&c);
        assert_eq!(x.len(), 12);
        let mean = x.iter().sum::<DVec3>() / 12.0;
        assert!((mean - c.center).length() < 1e-12);
        // (i, j, k) = (2, 0, 0) is local (1, -0.5, -0.5); 90° about z maps (x, y) to (-y, x).
        assert!(
            (x[2] - DVec3::new(0.5, 6.0, -0.5)).length() < 1e-12,
            "{:?}",
            x[2]
        );
        // index i + nx·(j + ny·k): (0, 1, 1) is 0 + 3·(1 + 2·1) = 9, local (-1, 0.5, 0.5).
        assert!(
            (x[9] - DVec3::new(-0.5, 4.0, 0.5)).length() < 1e-12,
            "{:?}",
            x[9]
        );
    }
}
