//! A lattice body's springs as a stencil: one set of offsets and parameters at every lattice
//! point, masked to the kept points and cells for a mesh body.

use glam::DVec3;

use crate::scene::SpringParams;
use crate::topology::{self, SpringKind};

#[cfg(doc)]
use super::Model;

/// A lattice body's springs as a stencil. A cuboid's particle (i, j, k), global index
/// `first + i + nx·(j + ny·k)`, is joined to the particle at (i, j, k) + o for every offset o
/// of `springs` where that lies in the grid, with that offset's parameters. A mesh body's
/// lattice is masked: only the kept points are particles, and only the springs its kept cells
/// hold exist ([`LatticeMask`]). These are the springs [`Model::springs`] lists for the body,
/// in its order ([`topology::for_each_lattice_spring`]): a solver may take them from either.
#[derive(Debug, Clone, PartialEq)]
pub struct Lattice {
    /// The body (an index into [`Model::bodies`]).
    pub body: u32,
    /// Its first particle.
    pub first: u32,
    /// Lattice points per axis (nx, ny, nz).
    pub dims: [u32; 3],
    /// The offsets with springs, in [`topology::OFFSETS`] order (families the body leaves out
    /// have none).
    pub springs: Vec<LatticeSpring>,
    /// Which points are particles and which springs exist, for a mesh body; `None` for a
    /// cuboid (every point, every spring whose partner lies in the grid).
    pub mask: Option<LatticeMask>,
}

/// The particles and springs of a masked lattice, per lattice point `i + nx·(j + ny·k)`.
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeMask {
    /// The particle (within the body) at each point, [`LatticeMask::NONE`] where there is none;
    /// ascending over the points that have one.
    pub particle_of: Vec<u32>,
    /// Bit o set where a spring of offset o ([`topology::OFFSETS`], one of `springs`) starts
    /// at the point.
    pub springs: Vec<u16>,
}

impl LatticeMask {
    /// `particle_of` of a point without a particle.
    pub const NONE: u32 = u32::MAX;
}

/// The springs of one lattice offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatticeSpring {
    /// Index into [`topology::OFFSETS`].
    pub offset: usize,
    /// r, metres: [`topology::offset_rest`].
    pub rest: f64,
    /// k_s, N/m.
    pub stiffness: f64,
    /// k_d, N·s/m.
    pub damping: f64,
}

impl Lattice {
    /// The lattice of a body of `dims` points at cell edges `spacing` whose structural, shear
    /// and bending families have the parameters `families` (`None`: left out).
    pub(super) fn new(
        body: u32,
        first: u32,
        dims: [u32; 3],
        spacing: DVec3,
        families: [Option<SpringParams>; 3],
    ) -> Lattice {
        let [structural, shear, bending] = families;
        let params = |kind| match kind {
            SpringKind::Structural => structural,
            SpringKind::Shear => shear,
            SpringKind::Bending => bending,
        };
        let springs = (topology::OFFSETS.iter().enumerate())
            .filter_map(|(offset, &(o, kind))| {
                params(kind).map(|p| LatticeSpring {
                    offset,
                    rest: topology::offset_rest(spacing, o),
                    stiffness: p.stiffness,
                    damping: p.damping,
                })
            })
            .collect();
        Lattice {
            body,
            first,
            dims,
            springs,
            mask: None,
        }
    }

    /// The lattice of a mesh body: `new`'s, masked to the points with a particle
    /// (`particle_of`) and the springs of the cells `present`.
    pub(super) fn masked(mut self, particle_of: &[u32], present: &[bool]) -> Lattice {
        let mut springs = vec![0u16; particle_of.len()];
        let kept = self
            .springs
            .iter()
            .fold(0u16, |bits, s| bits | 1 << s.offset);
        topology::for_each_lattice_spring(self.dims, Some(present), 0..self.dims[2], |a, _, o| {
            springs[a as usize] |= (1 << o) & kept;
        });
        self.mask = Some(LatticeMask {
            particle_of: particle_of.to_vec(),
            springs,
        });
        self
    }

    /// The springs of offset `o` (an index into [`topology::OFFSETS`]), if the body has them.
    pub fn spring(&self, o: usize) -> Option<&LatticeSpring> {
        self.springs.iter().find(|s| s.offset == o)
    }

    /// Number of springs.
    pub fn spring_count(&self) -> u64 {
        match &self.mask {
            None => (self.springs.iter())
                .map(|s| topology::offset_spring_count(self.dims, topology::OFFSETS[s.offset].0))
                .sum(),
            Some(mask) => mask.springs.iter().map(|b| u64::from(b.count_ones())).sum(),
        }
    }

    /// Calls `f(a, b, spring)` for each spring starting in the z-planes `planes`, a and b global
    /// particle indices, in the order of [`Model::springs`].
    pub fn for_each_spring(
        &self,
        planes: std::ops::Range<u32>,
        mut f: impl FnMut(u32, u32, &LatticeSpring),
    ) {
        let mut by_offset = [None; topology::OFFSETS.len()];
        for s in &self.springs {
            by_offset[s.offset] = Some(s);
        }
        let Some(mask) = &self.mask else {
            topology::for_each_cuboid_spring_in(self.dims, planes, |a, b, o| {
                if let Some(s) = by_offset[o] {
                    f(self.first + a, self.first + b, s);
                }
            });
            return;
        };
        let [nx, ny, nz] = self.dims.map(|d| d as usize);
        let plane = nx * ny;
        let points = planes.start as usize * plane..(planes.end as usize).min(nz) * plane;
        for (p, &bits) in mask.springs[points.clone()].iter().enumerate() {
            let p = points.start + p;
            for (o, s) in by_offset.iter().enumerate() {
                if let Some(s) = s.filter(|_| bits >> o & 1 == 1) {
                    let [di, dj, dk] = topology::OFFSETS[o].0.map(|d| d as isize);
                    let q = p.wrapping_add_signed(di + nx as isize * (dj + ny as isize * dk));
                    let (a, b) = (mask.particle_of[p], mask.particle_of[q]);
                    f(self.first + a, self.first + b, s);
                }
            }
        }
    }
}
