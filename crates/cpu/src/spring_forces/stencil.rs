//! Spring forces of lattice bodies ([`softbody_scene::Lattice`]) as a stencil: a spring's
//! partner is a constant offset away, so no spring is stored, loaded or indexed.
//!
//! The force of each spring is [`spring_force`](super::spring_force) (the same IEEE operations
//! in the same order), and particle p's sum is the one [`gather`](super::gather) forms, the
//! same bits: the gather adds, in ascending spring order, −f of every spring ending at p (its
//! first end a = p − o ascends as the linear offset o descends), then +f of every spring
//! starting at p, in [`OFFSETS`] order. Here, for four (AVX2) or eight (AVX-512) consecutive
//! particles of a grid row at once, or one at a time where the CPU has neither ([`Isa`]):
//!
//! 1. the force of every spring starting in the row is computed once, a vector at a time, and
//!    kept in a ring of per-offset row records (zero where no spring starts) until the row
//!    where those springs end has taken them ([`Records`]: lag + 1 records per offset);
//! 2. the row's sums take −f from the ring at p − o, offsets by descending linear offset, then
//!    +f at p in [`OFFSETS`] order. Missing springs read +0, and adding or subtracting +0 leaves
//!    a sum's bits as they are (a sum that starts at +0 is never −0), so the boundary needs no
//!    branch.
//!
//! Positions and velocities are first copied into rows padded to a multiple of eight with at
//! least two spare slots (so that a partner beyond the row's end, or before its start, lands
//! in zeros of the padding), structure of arrays. A row needs the forces of the two planes
//! below it, so each thread sweeps its own slab of planes upwards and first computes the
//! springs that reach into its slab from the two planes below (computed again, with the same
//! bits, by the thread below): the result does not depend on how many slabs there are.
//!
//! A mesh body's lattice is masked: points without a particle, and springs missing between
//! points that have one. Its rows are taken by their runs of particles ([`Run`]): only the
//! runs' slots are computed ([`Stencil::computed`]), each lane's mask made from the point's
//! spring bits; a row's records are zeroed where it has no particle but a row its springs reach
//! reads back ([`Stencil::zeroed`]), so no sum reads a record left from an earlier row; and
//! the sums and the rows handed on are the runs'.
//!
//! The copy is a window of [`WINDOW`] planes moving up the slab (and the two above it, which
//! its springs reach; the next window copies those two again), so that a thread holds a few
//! planes whatever the body's size: the lean model's bytes per particle stay those of the
//! state.

use glam::DVec3;
use softbody_scene::topology::OFFSETS;
use softbody_scene::{Lattice, LatticeMask};

use super::{Isa, spring_force};

/// Zeros before and after every buffer, so that partners one or two slots before a row's start
/// stay inside it; a cache line of them, so that rows start on lines ([`Lines`]).
const GUARD: usize = LINE;
/// Slots per padded row are a multiple of this: the lanes of the widest path (AVX-512's eight
/// f64), so that the groups of every path tile a row; a cache line, so that rows start on
/// lines ([`Lines`]).
const ROW_MULTIPLE: usize = LINE;
/// f64 slots per cache line (64 bytes).
const LINE: usize = 8;
/// Particles side by side on the AVX2 path: the groups a masked lattice's spans are made of.
const AVX2_LANES: usize = 4;
/// Planes of a slab whose sums one copy of the state serves.
const WINDOW: usize = 8;

/// The springs of one lattice offset, as the stencil uses them.
#[derive(Debug, Clone, Copy)]
struct Offset {
    /// (di, dj, dk).
    o: [i32; 3],
    /// Where its records start in the ring ([`Slab::sweep`]): the x component of the first.
    ring: usize,
    /// Its records in the ring: one more than the rows from a spring's start to its end in
    /// the sweep's order, dk·ny + dj.
    depth: usize,
    /// Its bit in a masked lattice's spring bits (1 << its index in [`OFFSETS`]).
    bit: u16,
    rest: f64,
    ks: f64,
    kd: f64,
}

/// A grid row's run of points that hold particles: points `i0..i1`, the first of them the
/// body's particle `p` (a masked lattice numbers its particles in point order, so a run's
/// particles are consecutive).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Run {
    i0: u32,
    i1: u32,
    p: u32,
}

/// A lattice body's stencil: its geometry in the padded layout and its offsets.
#[derive(Debug, Clone)]
pub(crate) struct Stencil {
    /// Global index of particle (0, 0, 0).
    first: usize,
    /// Particles per axis.
    dims: [usize; 3],
    /// Slots per padded row: nx + 2 rounded up to a multiple of [`ROW_MULTIPLE`].
    row: usize,
    /// The offsets with springs, in [`OFFSETS`] order: the order of the forward sums, and each
    /// one's place in the ring.
    offsets: Vec<Offset>,
    /// The offsets (indices into `offsets`) by descending linear offset: the order of the
    /// backward sums.
    backward: Vec<usize>,
    /// Per offset and slot of a row (offset after offset): whether a spring of that offset
    /// starts there (all ones) or none does (zero), whatever the row; the vector paths load
    /// a cuboid's lane masks from it.
    lane_masks: Vec<u64>,
    /// A mesh body's spring bits per lattice point ([`softbody_scene::LatticeMask::springs`]),
    /// from which its lanes' masks are made; `None` for a cuboid.
    bits: Option<Vec<u16>>,
    /// Per row (j + ny·k), its runs of particles.
    runs: PerRow<Run>,
    /// Per row, the slots whose forces are computed: its runs' (a cuboid: the whole row).
    computed: PerRow<[u32; 2]>,
    /// Per row, the slots that rows its springs reach read back at where it has no
    /// particle, so no force is computed there: its records are zeroed there, so that none
    /// that a sum reads is left from an earlier row (a cuboid: none).
    zeroed: PerRow<[u32; 2]>,
    /// Per plane, and one past the last, the body's particles before it.
    plane_first: Vec<u32>,
    /// The path the rows take.
    isa: Isa,
}

impl Stencil {
    /// The stencil of `lattice`.
    pub(crate) fn new(lattice: &Lattice) -> Stencil {
        let dims = lattice.dims.map(|d| d as usize);
        let [nx, ny, nz] = dims;
        let row = (nx + 2).next_multiple_of(ROW_MULTIPLE);
        let mut ring = GUARD;
        let offsets: Vec<Offset> = (lattice.springs.iter())
            .map(|s| {
                let o = OFFSETS[s.offset].0;
                // Forward offsets: dk > 0, or dk = 0 and dj ≥ 0, so the lag is not negative.
                let lag = i64::from(o[2]) * ny as i64 + i64::from(o[1]);
                let depth = usize::try_from(lag + 1).expect("a forward offset");
                let first = ring;
                ring += depth * 3 * row;
                Offset {
                    o,
                    ring: first,
                    depth,
                    bit: 1 << s.offset,
                    rest: s.rest,
                    ks: s.stiffness,
                    kd: s.damping,
                }
            })
            .collect();
        let linear = |o: [i32; 3]| {
            i64::from(o[0]) + nx as i64 * (i64::from(o[1]) + ny as i64 * i64::from(o[2]))
        };
        let mut backward: Vec<usize> = (0..offsets.len()).collect();
        // Two offsets of equal linear offset never both end at one particle (its partner
        // would be one particle at two places), so their relative order does not matter.
        backward.sort_by_key(|&r| std::cmp::Reverse(linear(offsets[r].o)));
        let lane_masks = (offsets.iter())
            .flat_map(|off| {
                (0..row as i64).map(|i| {
                    let q = i + i64::from(off.o[0]);
                    let starts = i < nx as i64 && (0..nx as i64).contains(&q);
                    if starts { u64::MAX } else { 0 }
                })
            })
            .collect();
        let rows = ny * nz;
        let mut runs = PerRow::new();
        let mut plane_first = vec![0];
        let (bits, computed, zeroed) = match &lattice.mask {
            None => {
                let (mut whole, mut none) = (PerRow::new(), PerRow::new());
                for r in 0..rows {
                    let p = u32::try_from(nx * r).expect("particles are u32");
                    let i1 = nx as u32;
                    runs.push([Run { i0: 0, i1, p }]);
                    whole.push([[0, row as u32]]);
                    none.push([]);
                }
                plane_first.extend((1..=nz).map(|k| (k * nx * ny) as u32));
                (None, whole, none)
            }
            Some(mask) => {
                let mut count = 0;
                for r in 0..rows {
                    let particle = |i: usize| mask.particle_of[nx * r + i];
                    let mut row_runs = Vec::new();
                    let mut i = 0;
                    while i < nx {
                        if particle(i) == LatticeMask::NONE {
                            i += 1;
                            continue;
                        }
                        let i0 = i;
                        while i < nx && particle(i) != LatticeMask::NONE {
                            i += 1;
                        }
                        row_runs.push(Run {
                            i0: i0 as u32,
                            i1: i as u32,
                            p: particle(i0),
                        });
                        count += (i - i0) as u32;
                    }
                    runs.push(row_runs);
                    if (r + 1) % ny == 0 {
                        plane_first.push(count);
                    }
                }
                let (mut computed, mut zeroed) = (PerRow::new(), PerRow::new());
                for r in 0..rows {
                    let (j, k) = ((r % ny) as i64, (r / ny) as i64);
                    let row_of = |dj: i64, dk: i64| {
                        let (j, k) = (j + dj, k + dk);
                        let inside = (0..ny as i64).contains(&j) && (0..nz as i64).contains(&k);
                        let q = (j + ny as i64 * k) as usize;
                        if inside { runs.row(q) } else { &[] }.iter()
                    };
                    let own = row_of(0, 0).map(|run| [run.i0 as i64, run.i1 as i64]);
                    let own = groups(own);
                    // A spring of offset o from slot i of this row ends at slot i + di of the
                    // row o reaches, whose sums read this row's record there: where this row
                    // has no particle, a zero.
                    let read = offsets.iter().flat_map(|off| {
                        let [di, dj, dk] = off.o.map(i64::from);
                        row_of(dj, dk).map(move |run| {
                            [
                                (run.i0 as i64 - di).max(0),
                                (run.i1 as i64 - di).min(nx as i64),
                            ]
                        })
                    });
                    let read = groups(read.filter(|[lo, hi]| lo < hi));
                    zeroed.push(difference(&read, &own));
                    computed.push(own);
                }
                (Some(mask.springs.clone()), computed, zeroed)
            }
        };
        // A masked lattice's lanes take their masks from bits, which the AVX2 path tests in
        // its loop; the AVX-512 path has no such loop (yet), so a mesh body stops at AVX2.
        let isa = match (Isa::detect(), &bits) {
            (Isa::Avx512, Some(_)) => Isa::Avx2,
            (isa, _) => isa,
        };
        Stencil {
            first: lattice.first as usize,
            dims,
            row,
            offsets,
            backward,
            lane_masks,
            bits,
            runs,
            computed,
            zeroed,
            plane_first,
            isa,
        }
    }

    /// Takes the path of `isa`, which the CPU must run, rather than the widest it runs (for
    /// tests of every path); a mesh body stays at AVX2 when given AVX-512 (no bit-mask loop).
    #[cfg(test)]
    pub(crate) fn with_isa(&mut self, isa: Isa) {
        assert!(isa.runs(), "{isa:?} on a CPU without it");
        if !(isa == Isa::Avx512 && self.bits.is_some()) {
            self.isa = isa;
        }
    }

    /// The path the rows take.
    pub(crate) fn isa(&self) -> Isa {
        self.isa
    }

    /// Slots of the ring: every offset's records, between guards.
    fn ring_slots(&self) -> usize {
        let records: usize = self.offsets.iter().map(|o| o.depth).sum();
        GUARD + records * 3 * self.row + GUARD
    }

    /// Planes (k).
    pub(crate) fn planes(&self) -> usize {
        self.dims[2]
    }

    /// Global index of the first particle of plane k (or past it, of the next plane's).
    pub(crate) fn plane_start(&self, k: usize) -> usize {
        self.first + self.plane_first[k] as usize
    }

    /// Row (j, k)'s runs of particles.
    fn runs(&self, j: usize, k: usize) -> &[Run] {
        self.runs.row(j + self.dims[1] * k)
    }

    /// Row (j, k)'s spans of slots whose forces are computed.
    fn computed(&self, j: usize, k: usize) -> &[[u32; 2]] {
        self.computed.row(j + self.dims[1] * k)
    }

    /// Row (j, k)'s spans of slots whose records are zeroed.
    fn zeroed(&self, j: usize, k: usize) -> &[[u32; 2]] {
        self.zeroed.row(j + self.dims[1] * k)
    }

    /// Slots of one padded plane.
    fn plane_slots(&self) -> usize {
        self.row * self.dims[1]
    }
}

/// Items per grid row, row after row (runs of particles; spans of slots `[lo, hi)`, apart and
/// ascending): row r's are `items[row_start[r]..row_start[r + 1]]`.
#[derive(Debug, Clone)]
struct PerRow<T> {
    row_start: Vec<u32>,
    items: Vec<T>,
}

impl<T> PerRow<T> {
    fn new() -> PerRow<T> {
        PerRow {
            row_start: vec![0],
            items: Vec::new(),
        }
    }

    /// Appends the next row's.
    fn push(&mut self, row: impl IntoIterator<Item = T>) {
        self.items.extend(row);
        self.row_start.push(self.items.len() as u32);
    }

    fn row(&self, r: usize) -> &[T] {
        &self.items[self.row_start[r] as usize..self.row_start[r + 1] as usize]
    }
}

/// The slots of `spans` in whole groups of the AVX2 path (four), apart and ascending.
fn groups(spans: impl Iterator<Item = [i64; 2]>) -> Vec<[u32; 2]> {
    let group = AVX2_LANES as i64;
    let mut spans: Vec<[i64; 2]> = spans
        .map(|[lo, hi]| [lo - lo.rem_euclid(group), hi + (-hi).rem_euclid(group)])
        .collect();
    spans.sort_unstable();
    let mut merged: Vec<[u32; 2]> = Vec::new();
    for [lo, hi] in spans {
        match merged.last_mut() {
            Some([_, end]) if i64::from(*end) >= lo => *end = (*end).max(hi as u32),
            _ => merged.push([lo as u32, hi as u32]),
        }
    }
    merged
}

/// The slots of `all` not in `some` (both apart and ascending).
fn difference(all: &[[u32; 2]], some: &[[u32; 2]]) -> Vec<[u32; 2]> {
    let mut out = Vec::new();
    for &[lo, hi] in all {
        let mut at = lo;
        for &[a, b] in some.iter().filter(|[a, b]| *a < hi && *b > lo) {
            if a > at {
                out.push([at, a]);
            }
            at = at.max(b);
        }
        if at < hi {
            out.push([at, hi]);
        }
    }
    out
}

/// Which rows of one plane k have springs of each offset (worked out once per plane): the rows
/// j where they start (the partner's row j + dj and plane k + dk lie in the grid) and end
/// (j − dj, k − dk).
#[derive(Debug, Clone, Copy)]
struct PlaneRing {
    starts: [(usize, usize); 16],
    ends: [(usize, usize); 16],
}

/// Where the row the sweep is at, its t-th, writes and reads each offset's records in the
/// ring: the sweep takes rows in order (j, then k), and a spring starting in row t ends in
/// row t + lag with lag = dk·ny + dj, so an offset's forces live in a circle of lag + 1
/// records, row t's in record t mod (lag + 1): written at row t, read at row t + lag, which
/// writes record (t + lag) mod (lag + 1) = (t − 1) mod (lag + 1), not t's. Row t reads the
/// record of row t − lag, (t + 1) mod (lag + 1): the next one. The ring so holds about 11
/// rows per row of a plane instead of 27 planes' worth, and what a row reads was written a few
/// rows or one plane before.
#[derive(Debug, Clone, Copy)]
struct Records {
    /// Per offset, row t's record.
    at: [usize; 16],
}

impl Records {
    /// Row 0's.
    fn start() -> Records {
        Records { at: [0; 16] }
    }

    /// The next row's.
    fn advance(&mut self, stencil: &Stencil) {
        for (at, off) in self.at.iter_mut().zip(&stencil.offsets) {
            *at = if *at + 1 == off.depth { 0 } else { *at + 1 };
        }
    }

    /// Slot (x component) of the record that this row writes offset r's forces into.
    #[inline]
    fn write(&self, stencil: &Stencil, r: usize) -> usize {
        stencil.offsets[r].ring + self.at[r] * 3 * stencil.row
    }

    /// Slot (x component) of the record of the row that offset r's springs ending in this row
    /// start in.
    #[inline]
    fn read(&self, stencil: &Stencil, r: usize) -> usize {
        let off = &stencil.offsets[r];
        let next = if self.at[r] + 1 == off.depth {
            0
        } else {
            self.at[r] + 1
        };
        off.ring + next * 3 * stencil.row
    }
}

impl PlaneRing {
    /// Whether springs of offset r start in row j.
    #[inline]
    fn starts(&self, r: usize, j: usize) -> bool {
        (self.starts[r].0..self.starts[r].1).contains(&j)
    }

    /// Whether springs of offset r end in row j.
    #[inline]
    fn ends(&self, r: usize, j: usize) -> bool {
        (self.ends[r].0..self.ends[r].1).contains(&j)
    }
}

/// One thread's part of a lattice: planes `k0..k1`, with its padded copies of the state and its
/// ring of forces.
#[derive(Debug, Clone)]
pub(crate) struct Slab {
    /// The lattice (an index into the pass's stencils).
    pub(crate) lattice: usize,
    k0: usize,
    k1: usize,
    /// First plane with springs into the slab: k0 − 2 or 0.
    kb: usize,
    /// First plane of the window copied into `state`.
    base: usize,
    /// Slots of each of the state arrays (x, y, z of x; x, y, z of v; a masked lattice's
    /// spring bits, as the bits of f64).
    len: usize,
    state: Lines,
    /// Slots between the components of a record in the ring: a padded row.
    ring_len: usize,
    /// Per offset, its records (`Records`): each the forces of the springs starting in a row,
    /// the x components, then the y, then the z (zero where no spring starts).
    ring: Lines,
    /// A row's sums, per component.
    sums: Lines,
}

impl Slab {
    /// Planes `k0..k1` of `stencil` (the `lattice`-th).
    pub(crate) fn new(stencil: &Stencil, lattice: usize, k0: usize, k1: usize) -> Slab {
        let kb = k0.saturating_sub(2);
        // The first window is the largest: the planes below, WINDOW planes, two above.
        let planes = (k0 - kb) + WINDOW.min(k1 - k0) + 2;
        let len = GUARD + planes * stencil.plane_slots() + GUARD;
        let ring_len = stencil.row;
        Slab {
            lattice,
            k0,
            k1,
            kb,
            base: kb,
            len,
            state: Lines::zeroed((6 + usize::from(stencil.bits.is_some())) * len),
            ring_len,
            ring: Lines::zeroed(stencil.ring_slots()),
            sums: Lines::zeroed(3 * stencil.row),
        }
    }

    /// Bytes held on the heap.
    pub(crate) fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        vec_bytes(&self.state.0) + vec_bytes(&self.ring.0) + vec_bytes(&self.sums.0)
    }

    /// Global index of the slab's first particle and one past its last.
    pub(crate) fn particles(&self, stencil: &Stencil) -> (usize, usize) {
        (stencil.plane_start(self.k0), stencil.plane_start(self.k1))
    }

    /// Slot of (i, j, k) in the state arrays.
    #[inline]
    fn slot(&self, stencil: &Stencil, i: usize, j: usize, k: usize) -> usize {
        GUARD + i + stencil.row * j + stencil.plane_slots() * (k - self.base)
    }

    /// Plane k's view of the ring.
    fn plane_ring(&self, stencil: &Stencil, k: usize) -> PlaneRing {
        let [_, ny, nz] = stencil.dims.map(|d| d as i64);
        let mut plane = PlaneRing {
            starts: [(0, 0); 16],
            ends: [(0, 0); 16],
        };
        // Rows j with j + d in 0..ny, when plane k + e is in 0..nz (else none).
        let rows = |d: i64, e: i64| {
            let k = k as i64 + e;
            if (0..nz).contains(&k) {
                ((-d).max(0) as usize, (ny - d).min(ny).max(0) as usize)
            } else {
                (0, 0)
            }
        };
        for (r, off) in stencil.offsets.iter().enumerate() {
            let [_, dj, dk] = off.o.map(i64::from);
            plane.starts[r] = rows(dj, dk);
            plane.ends[r] = rows(-dj, -dk);
        }
        plane
    }

    /// Hands every row of the slab, in ascending order, to `done` with its particles' state
    /// and the sums of their spring forces at (x, v) (the whole model's arrays).
    pub(crate) fn sweep(
        &mut self,
        stencil: &Stencil,
        x: &[DVec3],
        v: &[DVec3],
        done: &mut impl FnMut(&Row<'_>),
    ) {
        let ny = stencil.dims[1];
        self.window(stencil, x, v, self.kb, self.k0);
        let mut records = Records::start();
        // The springs from the two planes below that reach into the slab.
        for k in self.kb..self.k0 {
            let plane = self.plane_ring(stencil, k);
            for j in 0..ny {
                self.compute_row(stencil, &plane, &records, (j, k), (self.k0 - k) as i32);
                records.advance(stencil);
            }
        }
        for k in self.k0..self.k1 {
            if k > self.k0 && (k - self.k0).is_multiple_of(WINDOW) {
                self.window(stencil, x, v, k, k);
            }
            let plane = self.plane_ring(stencil, k);
            for j in 0..ny {
                self.compute_row(stencil, &plane, &records, (j, k), 0);
                let runs = stencil.runs(j, k);
                self.sum_row(stencil, &plane, &records, j, runs);
                for run in runs {
                    let (i0, n) = (run.i0 as usize, (run.i1 - run.i0) as usize);
                    let s0 = self.slot(stencil, i0, j, k);
                    let state = |c: usize| &self.state[c * self.len + s0..][..n];
                    let sums = |c: usize| &self.sums[c * stencil.row + i0..][..n];
                    done(&Row {
                        p0: stencil.first + run.p as usize,
                        x: [state(0), state(1), state(2)],
                        v: [state(3), state(4), state(5)],
                        f: [sums(0), sums(1), sums(2)],
                    });
                }
                records.advance(stencil);
            }
        }
    }

    /// Copies into padded rows the state of planes `base..` up to the two above the window
    /// of sums that starts at plane `from` (the planes between are those below the slab).
    fn window(&mut self, stencil: &Stencil, x: &[DVec3], v: &[DVec3], base: usize, from: usize) {
        let [nx, ny, nz] = stencil.dims;
        let end = ((from + WINDOW).min(self.k1) + 2).min(nz);
        self.base = base;
        let (state, bits) = self.state.split_at_mut(6 * self.len);
        let mut arrays = split6(state, self.len);
        for k in base..end {
            for j in 0..ny {
                let row0 = GUARD + stencil.row * j + stencil.plane_slots() * (k - base);
                // A masked lattice's slots without a particle keep what an earlier window
                // left there: their lanes' bits are zero, which masks whatever they compute.
                for run in stencil.runs(j, k) {
                    let (p0, n) = (stencil.first + run.p as usize, (run.i1 - run.i0) as usize);
                    let s0 = row0 + run.i0 as usize;
                    let (xs, vs) = (&x[p0..p0 + n], &v[p0..p0 + n]);
                    let [r0, r1, r2, r3, r4, r5] = arrays.each_mut().map(|c| &mut c[s0..s0 + n]);
                    transpose(stencil.isa, xs, [r0, r1, r2]);
                    transpose(stencil.isa, vs, [r3, r4, r5]);
                }
                if let Some(point_bits) = &stencil.bits {
                    let from = &point_bits[nx * (j + ny * k)..][..nx];
                    for (slot, &b) in bits[row0..row0 + nx].iter_mut().zip(from) {
                        *slot = f64::from_bits(u64::from(b));
                    }
                }
            }
        }
    }

    /// The forces of the springs of offsets with dk ≥ `min_dk` starting in row (j, k), into
    /// the ring.
    fn compute_row(
        &mut self,
        stencil: &Stencil,
        plane: &PlaneRing,
        records: &Records,
        (j, k): (usize, usize),
        min_dk: i32,
    ) {
        let springs = self.row_springs(stencil, plane, records, (j, k), min_dk);
        for &RowSpring { out, .. } in springs.springs() {
            for &[lo, hi] in springs.zeroed {
                for c in 0..3 {
                    let at = out + c * self.ring_len;
                    self.ring[at + lo as usize..at + hi as usize].fill(0.0);
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        match stencil.isa {
            // SAFETY: AVX-512F was detected at run time (`Isa::runs`); `row_springs` checked
            // the slots.
            Isa::Avx512 => return unsafe { avx512::compute_row(self, stencil, &springs) },
            // SAFETY: AVX2 was detected at run time (`Isa::runs`); `row_springs` checked the
            // slots.
            Isa::Avx2 if stencil.bits.is_some() => {
                return unsafe { avx::compute_row::<true>(self, stencil, &springs) };
            }
            // SAFETY: as above.
            Isa::Avx2 => return unsafe { avx::compute_row::<false>(self, stencil, &springs) },
            Isa::Scalar => {}
        }
        let a0 = springs.a0;
        for &RowSpring { r, b0, out } in springs.springs() {
            let off = &stencil.offsets[r];
            for i in springs
                .lanes
                .iter()
                .flat_map(|&[lo, hi]| lo as usize..hi as usize)
            {
                let at = |s: usize| {
                    let c = |c: usize| self.state[c * self.len + s];
                    (DVec3::new(c(0), c(1), c(2)), DVec3::new(c(3), c(4), c(5)))
                };
                let live = match stencil.bits {
                    Some(_) => self.state[6 * self.len + a0 + i].to_bits() & u64::from(off.bit),
                    None => stencil.lane_masks[r * stencil.row + i],
                };
                let f = if live != 0 {
                    let ((xa, va), (xb, vb)) = (at(a0 + i), at(b0 + i));
                    spring_force(xa, xb, va, vb, off.rest, off.ks, off.kd)
                } else {
                    DVec3::ZERO
                };
                for (c, value) in f.to_array().into_iter().enumerate() {
                    self.ring[out + i + c * self.ring_len] = value;
                }
            }
        }
    }

    /// The springs of offsets with dk ≥ `min_dk` starting in row (j, k): where the row starts
    /// in the state arrays, its slots to compute and, per offset, where its partners do and
    /// where its forces go in the ring (x component).
    fn row_springs<'s>(
        &self,
        stencil: &'s Stencil,
        plane: &PlaneRing,
        records: &Records,
        (j, k): (usize, usize),
        min_dk: i32,
    ) -> RowSprings<'s> {
        let row = stencil.row;
        let a0 = self.slot(stencil, 0, j, k);
        let (lanes, zeroed) = (stencil.computed(j, k), stencil.zeroed(j, k));
        let mut springs = RowSprings {
            a0,
            lanes,
            zeroed,
            springs: [RowSpring {
                r: 0,
                b0: 0,
                out: 0,
            }; 16],
            count: 0,
        };
        let ends = [lanes, zeroed].map(|spans| spans.last().map_or(0, |&[_, end]| end));
        let end = ends[0].max(ends[1]);
        if end == 0 {
            return springs;
        }
        // What the vector paths read and write lies in the buffers: a's row and b's row are
        // rows of the state buffer (b's row is in the grid: `PlaneRing::starts`), and b's
        // slots are at most two before its row's start (GUARD) or after a's slots (the
        // padding); a spring's forces fill a row of each ring array; the lane masks hold a row
        // per offset.
        assert!(a0 >= GUARD && a0 + row <= self.len && end as usize <= row);
        // The bits, a seventh state array, exist for the path that reads them; the AVX-512
        // path reads the lane-mask table alone, so it never takes a masked lattice.
        assert_eq!(
            self.state.len(),
            (6 + usize::from(stencil.bits.is_some())) * self.len
        );
        assert!(stencil.isa != Isa::Avx512 || stencil.bits.is_none());
        assert_eq!(stencil.lane_masks.len(), row * stencil.offsets.len());
        for (r, off) in stencil.offsets.iter().enumerate() {
            if off.o[2] < min_dk || !plane.starts(r, j) {
                continue;
            }
            let b0 = a0.wrapping_add_signed(offset_slots(stencil, off.o));
            assert!((GUARD - 2..=self.len - row).contains(&b0));
            let out = records.write(stencil, r);
            assert!(out + 2 * self.ring_len + row <= self.ring.len());
            springs.springs[springs.count] = RowSpring { r, b0, out };
            springs.count += 1;
        }
        springs
    }

    /// Where the sums of row (j, k) take their forces from, in order: the first slot (of the
    /// x component) of the ring row of each spring ending in the row, lined up with the row's
    /// particles, then of each starting there.
    fn sources(
        &self,
        stencil: &Stencil,
        plane: &PlaneRing,
        records: &Records,
        j: usize,
    ) -> Sources {
        let r = stencil.row;
        let mut sources = Sources {
            back: [0; 16],
            forth: [0; 16],
            counts: (0, 0),
        };
        for &q in &stencil.backward {
            let o = stencil.offsets[q].o;
            if plane.ends(q, j) {
                // Partners up to two slots before the row's start: the guard or the previous
                // row's padding, both zero.
                let at = records.read(stencil, q).wrapping_add_signed(-o[0] as isize);
                sources.back[sources.counts.0] = at;
                sources.counts.0 += 1;
            }
        }
        for q in 0..stencil.offsets.len() {
            if plane.starts(q, j) {
                sources.forth[sources.counts.1] = records.write(stencil, q);
                sources.counts.1 += 1;
            }
        }
        // What the vector paths read and write lies in the buffers: each source's row of every
        // ring array, and the row of sums of every component.
        for &at in sources.back().iter().chain(sources.forth()) {
            assert!(at >= GUARD - 2 && at + r + 2 * self.ring_len <= self.ring.len());
        }
        assert_eq!(self.sums.len(), 3 * r);
        sources
    }

    /// The sums of row (j, k) into `sums`, at least at the slots of its `runs`: −f of the
    /// springs ending there, then +f of those starting there.
    fn sum_row(
        &mut self,
        stencil: &Stencil,
        plane: &PlaneRing,
        records: &Records,
        j: usize,
        runs: &[Run],
    ) {
        if runs.is_empty() {
            return;
        }
        let sources = self.sources(stencil, plane, records, j);
        for run in runs {
            self.sum_run(stencil, &sources, (run.i0 as usize, run.i1 as usize));
        }
    }

    /// The sums of slots `lanes.0..lanes.1` of a row (at least: the vector paths sum whole
    /// groups) from its `sources`.
    fn sum_run(&mut self, stencil: &Stencil, sources: &Sources, lanes: (usize, usize)) {
        assert!(lanes.1 <= stencil.row);
        #[cfg(target_arch = "x86_64")]
        match stencil.isa {
            // SAFETY: AVX-512F was detected at run time (`Isa::runs`); `sources` checked the
            // slots. Only a cuboid takes this path, and its rows are one run, summed whole.
            Isa::Avx512 => return unsafe { avx512::sum_row(self, stencil.row, sources) },
            // SAFETY: AVX2 was detected at run time (`Isa::runs`); `sources` checked the slots.
            Isa::Avx2 => return unsafe { avx::sum_row(self, stencil.row, lanes, sources) },
            Isa::Scalar => {}
        }
        let r = stencil.row;
        for (c, sums) in self.sums.chunks_mut(r).enumerate() {
            let component = c * self.ring_len;
            let sums = &mut sums[lanes.0..lanes.1];
            sums.fill(0.0);
            let at = |a: usize| a + component + lanes.0;
            for &a in sources.back() {
                for (s, f) in sums.iter_mut().zip(&self.ring[at(a)..]) {
                    *s -= f;
                }
            }
            for &a in sources.forth() {
                for (s, f) in sums.iter_mut().zip(&self.ring[at(a)..]) {
                    *s += f;
                }
            }
        }
    }
}

/// One grid row of a sweep ([`Slab::sweep`]), structure of arrays: particles
/// `p0..p0 + len()`, their positions and velocities (the bits of the model's arrays) and the
/// sums of their spring forces.
pub(crate) struct Row<'a> {
    pub(crate) p0: usize,
    pub(crate) x: [&'a [f64]; 3],
    pub(crate) v: [&'a [f64]; 3],
    pub(crate) f: [&'a [f64]; 3],
}

impl Row<'_> {
    /// Particles in the row.
    #[inline(always)]
    pub(crate) fn len(&self) -> usize {
        self.x[0].len()
    }

    /// Position, velocity and spring-force sum of the row's i-th particle.
    #[inline(always)]
    pub(crate) fn particle(&self, i: usize) -> (DVec3, DVec3, DVec3) {
        let at = |c: &[&[f64]; 3]| DVec3::new(c[0][i], c[1][i], c[2][i]);
        (at(&self.x), at(&self.v), at(&self.f))
    }
}

/// A row's springs of one offset ([`Slab::row_springs`]).
#[derive(Debug, Clone, Copy)]
struct RowSpring {
    /// The offset (an index into the stencil's offsets).
    r: usize,
    /// Slot of the first particle's partner in the state arrays.
    b0: usize,
    /// Slot of the first particle's force in the ring (x component).
    out: usize,
}

/// A row's springs ([`Slab::row_springs`]).
struct RowSprings<'a> {
    /// Slot of the row's first particle in the state arrays.
    a0: usize,
    /// The row's spans of slots to compute ([`Stencil::computed`]).
    lanes: &'a [[u32; 2]],
    /// The row's spans of slots whose records are zeroed ([`Stencil::zeroed`]).
    zeroed: &'a [[u32; 2]],
    springs: [RowSpring; 16],
    count: usize,
}

impl RowSprings<'_> {
    fn springs(&self) -> &[RowSpring] {
        &self.springs[..self.count]
    }
}

/// A row's sources ([`Slab::sources`]).
struct Sources {
    back: [usize; 16],
    forth: [usize; 16],
    counts: (usize, usize),
}

impl Sources {
    fn back(&self) -> &[usize] {
        &self.back[..self.counts.0]
    }
    fn forth(&self) -> &[usize] {
        &self.forth[..self.counts.1]
    }
}

/// A cache line of f64 slots.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Line([f64; LINE]);
const _: () = assert!(size_of::<Line>() == size_of::<[f64; LINE]>());

/// Zeroed f64 slots on whole cache lines, as a slice: a slab's buffers start on a line, and
/// with guards and rows of whole lines so does every row of the state, of the ring and of the
/// sums. Then a vector of a row's own slots never straddles two lines (which costs a second
/// access; the AVX-512 path's vectors, a line each, would straddle on every load elsewhere).
#[derive(Debug, Clone)]
struct Lines(Vec<Line>);

impl Lines {
    /// `slots` zeros, whole lines of them.
    fn zeroed(slots: usize) -> Lines {
        assert!(slots.is_multiple_of(LINE));
        Lines(vec![Line([0.0; LINE]); slots / LINE])
    }
}

impl std::ops::Deref for Lines {
    type Target = [f64];

    fn deref(&self) -> &[f64] {
        // SAFETY: a `Line` is LINE f64 and nothing else (`repr(C)`, no padding: asserted
        // beside it), so the lines are LINE times as many contiguous f64.
        unsafe { std::slice::from_raw_parts(self.0.as_ptr().cast(), LINE * self.0.len()) }
    }
}

impl std::ops::DerefMut for Lines {
    fn deref_mut(&mut self) -> &mut [f64] {
        // SAFETY: as for `deref`, through the only borrow of the lines.
        unsafe { std::slice::from_raw_parts_mut(self.0.as_mut_ptr().cast(), LINE * self.0.len()) }
    }
}

/// The components of `from` into the three arrays `to` (as long as `from`), with the widest
/// vector instructions the CPU has (the compiler turns the loop into loads and permutes).
fn transpose(isa: Isa, from: &[DVec3], to: [&mut [f64]; 3]) {
    #[inline(always)]
    fn lanes(from: &[DVec3], [x, y, z]: [&mut [f64]; 3]) {
        let n = from.len();
        let (x, y, z) = (&mut x[..n], &mut y[..n], &mut z[..n]);
        for i in 0..n {
            (x[i], y[i], z[i]) = (from[i].x, from[i].y, from[i].z);
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn avx512(from: &[DVec3], to: [&mut [f64]; 3]) {
        lanes(from, to);
    }
    #[cfg(target_arch = "x86_64")]
    if isa == Isa::Avx512 {
        // SAFETY: AVX-512F was detected at run time (`Isa::runs`).
        return unsafe { avx512(from, to) };
    }
    lanes(from, to);
}

/// The six arrays of `len` slots of a slab's state, apart.
fn split6(state: &mut [f64], len: usize) -> [&mut [f64]; 6] {
    let (c0, rest) = state.split_at_mut(len);
    let (c1, rest) = rest.split_at_mut(len);
    let (c2, rest) = rest.split_at_mut(len);
    let (c3, rest) = rest.split_at_mut(len);
    let (c4, c5) = rest.split_at_mut(len);
    [c0, c1, c2, c3, c4, c5]
}

/// The slots between a particle and its partner at offset `o` in the state arrays.
#[inline]
fn offset_slots(stencil: &Stencil, o: [i32; 3]) -> isize {
    o[0] as isize
        + stencil.row as isize * (o[1] as isize + stencil.dims[1] as isize * o[2] as isize)
}

#[cfg(target_arch = "x86_64")]
mod avx512;

#[cfg(target_arch = "x86_64")]
mod avx {
    //! The stencil's rows in 256-bit vectors: four consecutive particles per group, each lane
    //! doing exactly [`spring_force`](crate::spring_forces::spring_force)'s IEEE operations in
    //! its order (nothing fused), and the sums' additions in the scalar path's order.

    use std::arch::x86_64::*;

    use super::{ROW_MULTIPLE, RowSpring, RowSprings, Slab, Sources, Stencil};
    use crate::spring_forces::avx::forces;

    /// Particles side by side.
    const LANES: usize = 4;
    const _: () = assert!(ROW_MULTIPLE.is_multiple_of(LANES));

    /// Four f64 from `p`.
    ///
    /// # Safety
    /// `p..p + 4` is readable.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn load(p: *const f64) -> __m256d {
        // SAFETY: the caller's promise.
        unsafe { _mm256_loadu_pd(p) }
    }

    /// The forces of `springs` into the ring ([`Slab::compute_row`]).
    ///
    /// # Safety
    /// AVX2 is available, and `springs` were made by [`Slab::row_springs`] for this slab and
    /// stencil.
    ///
    /// `BITS`: the lanes' masks are made from a masked lattice's spring bits (the slab's
    /// seventh state array) rather than loaded from the stencil's `lane_masks`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn compute_row<const BITS: bool>(
        slab: &mut Slab,
        stencil: &Stencil,
        springs: &RowSprings,
    ) {
        let row = stencil.row;
        let (len, rl) = (slab.len, slab.ring_len);
        let state = slab.state.as_ptr();
        let ring = slab.ring.as_mut_ptr();
        for &RowSpring { r, b0, out } in springs.springs() {
            let off = &stencil.offsets[r];
            let (rest, ks, kd) = (
                _mm256_set1_pd(off.rest),
                _mm256_set1_pd(off.ks),
                _mm256_set1_pd(off.kd),
            );
            let bit = _mm256_set1_epi64x(i64::from(off.bit));
            // The partners' slots less the first ends': the partner rows are addressed from
            // the first ends' pointers (ten streams in registers instead of sixteen).
            let partner = b0 as isize - springs.a0 as isize;
            // SAFETY: `Slab::row_springs` checked that rows a0.., b0.. of every state array
            // (with BITS, the seventh too), row out.. of every ring array and this offset's
            // row of lane masks hold `row` slots, a multiple of four.
            unsafe {
                let a: [*const f64; 6] = std::array::from_fn(|c| state.add(c * len + springs.a0));
                let dst = [ring.add(out), ring.add(out + rl), ring.add(out + 2 * rl)];
                let masks = if BITS {
                    state.add(6 * len + springs.a0)
                } else {
                    stencil.lane_masks.as_ptr().add(r * row).cast::<f64>()
                };
                // Whole groups over the spans to compute: they lie in the padded row.
                for &[lo, hi] in springs.lanes {
                    for g in lo as usize / LANES..(hi as usize).div_ceil(LANES) {
                        let i = opaque(LANES * g);
                        let b = i as isize + partner;
                        let d = |c: usize| _mm256_sub_pd(load(a[c].add(i)), load(a[c].offset(b)));
                        let (dx, dy, dz) = (d(0), d(1), d(2));
                        let (wx, wy, wz) = (d(3), d(4), d(5));
                        // Lanes without a spring exert no force.
                        let mask = if BITS {
                            let bits = _mm256_castpd_si256(load(masks.add(i)));
                            let set = _mm256_cmpeq_epi64(_mm256_and_si256(bits, bit), bit);
                            _mm256_castsi256_pd(set)
                        } else {
                            load(masks.add(i))
                        };
                        let [fx, fy, fz] = forces(dx, dy, dz, [wx, wy, wz], rest, ks, kd, mask);
                        _mm256_storeu_pd(dst[0].add(i), fx);
                        _mm256_storeu_pd(dst[1].add(i), fy);
                        _mm256_storeu_pd(dst[2].add(i), fz);
                    }
                }
            }
        }
    }

    /// `i`, through an empty `asm!` block that hides from LLVM where it comes from. A loop
    /// addressing many arrays with a counted index is otherwise rewritten by LLVM's loop
    /// strength reduction into a pointer per array, each incremented every iteration: the
    /// springs' loop has more streams than there are registers, and in the loop over a row's
    /// spans they were spilled, which made the 46³ cube's step 1.3× slower
    /// (docs/lab/explicit-stencil.md).
    #[inline(always)]
    fn opaque(mut i: usize) -> usize {
        // SAFETY: the block is empty: it reads and writes nothing but `i`'s register.
        unsafe { std::arch::asm!("/* {0} */", inout(reg) i, options(pure, nomem, nostack)) };
        i
    }

    /// # Safety
    /// AVX2 is available, and `sources` were made by [`Slab::sources`] for this slab.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sum_row(
        slab: &mut Slab,
        r: usize,
        lanes: (usize, usize),
        sources: &Sources,
    ) {
        let ring = slab.ring.as_ptr();
        let sums = slab.sums.as_mut_ptr();
        let rl = slab.ring_len;
        // Whole groups over the slots asked for: they lie in the padded row.
        for g in lanes.0 / LANES..lanes.1.div_ceil(LANES) {
            let (mut sx, mut sy, mut sz) = (
                _mm256_setzero_pd(),
                _mm256_setzero_pd(),
                _mm256_setzero_pd(),
            );
            // SAFETY: `Slab::sources` checked that each component's row lies in the ring.
            unsafe {
                for &at in sources.back() {
                    let p = ring.add(at + LANES * g);
                    sx = _mm256_sub_pd(sx, load(p));
                    sy = _mm256_sub_pd(sy, load(p.add(rl)));
                    sz = _mm256_sub_pd(sz, load(p.add(2 * rl)));
                }
                for &at in sources.forth() {
                    let p = ring.add(at + LANES * g);
                    sx = _mm256_add_pd(sx, load(p));
                    sy = _mm256_add_pd(sy, load(p.add(rl)));
                    sz = _mm256_add_pd(sz, load(p.add(2 * rl)));
                }
            }
            // SAFETY: `sums` holds three rows of r slots.
            unsafe {
                _mm256_storeu_pd(sums.add(LANES * g), sx);
                _mm256_storeu_pd(sums.add(r + LANES * g), sy);
                _mm256_storeu_pd(sums.add(2 * r + LANES * g), sz);
            }
        }
    }
}
