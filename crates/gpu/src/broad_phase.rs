//! `shaders/broad_phase.wgsl` ↔ `softbody_cpu::broad_phase`: the hashed uniform grid of the
//! particles with a contact radius, in which contact between bodies finds its pairs
//! (`shaders/shared/neighbours.wgsl` searches it).
//!
//! Each particle's cell c = ⌊x/s⌋ (s a hair above 2·r_max) is hashed into one of B buckets (a
//! power of two ≥ 2n: a particle far from the others costs nothing) with the CPU's hash, and
//! the particles are counting-sorted by bucket on the device: clear the counts, count with an
//! integer `atomicAdd`, an exclusive prefix sum over the counts, scatter each particle to an
//! atomically taken slot of its bucket, sort each bucket's run by particle index. The prefix
//! sum is a scan per workgroup of 256 counts that writes each block's total to the next level,
//! recursively up to a single block (B = 2²⁴ has levels of 2²⁴, 65,536, 256), then each level
//! adds its block's scanned total going back down; every dispatch is a 2-D grid where it needs
//! more than 65,535 workgroups. Integer sums and sorted runs: the grid is a function of the
//! positions alone, and a run repeats bit for bit.
//!
//! Unlike the CPU's, the grid keeps no Verlet list: it is built twice per step, from a snapshot
//! of the state that the counting kernel writes (the step's start for the penalty forces, its
//! end for the response; [`Snapshot`]).

use crate::buffers::Setup;
use crate::grid::Grid;
use crate::kernel::{Call, Resources};
use crate::layout::ScanLevel;
use crate::shaders::Stage;
use crate::{GpuError, WORKGROUP_SIZE};

/// Which snapshot of the state the grid is built from (and the counting kernel writes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Snapshot {
    /// The step's start: particles [0, n) of the snapshot.
    Start,
    /// The step's end: particles [n, 2n).
    End,
}

/// The grid's buffers and the calls that build it.
pub(crate) struct BroadPhase {
    /// Per bucket the end of its run in `sorted`, followed by the prefix sum's upper levels.
    counts: wgpu::Buffer,
    /// The particles with a radius, bucket after bucket.
    sorted: wgpu::Buffer,
    clear: Call,
    count_start: Call,
    count_end: Call,
    scan_up: Call,
    scan_down: Call,
    scatter: Call,
    sort: Call,
    /// One thread per bucket, per particle.
    buckets: Grid,
    particles: Grid,
    /// Each level of the prefix sum: its grid (one thread per element) and its slot's offset
    /// in the level table.
    levels: Vec<(Grid, u32)>,
}

/// Elements of each level of the prefix sum over `buckets` counts: the counts, then the totals
/// of the previous level's blocks of [`WORKGROUP_SIZE`], up to a level of one block.
fn level_sizes(buckets: u64) -> Vec<u64> {
    let mut sizes = vec![buckets];
    while let Some(&last) = sizes.last().filter(|&&last| last > WORKGROUP_SIZE) {
        sizes.push(last.div_ceil(WORKGROUP_SIZE));
    }
    sizes
}

/// Words of the counts buffer for `buckets` buckets: every level and the top's total.
pub(crate) fn count_words(buckets: u64) -> u64 {
    level_sizes(buckets).iter().sum::<u64>() + 1
}

impl BroadPhase {
    /// The grid of `buckets` buckets over the solver's particles; `shared` names the contact
    /// data ([`crate::body_contact`]) its kernels read. `grid(threads)` lays out a dispatch.
    pub fn new(
        s: Setup<'_>,
        shared: &Resources<'_>,
        buckets: u64,
        grid: impl Fn(u64) -> Result<Grid, GpuError>,
    ) -> Result<BroadPhase, GpuError> {
        let sizes = level_sizes(buckets);
        let stride = s.buffers.step_stride;
        let mut table = vec![0u8; sizes.len() * stride as usize];
        let mut offset = 0;
        let mut levels = Vec::with_capacity(sizes.len());
        for (l, &size) in sizes.iter().enumerate() {
            let level = ScanLevel {
                offset: offset as u32,
                count: size as u32,
                // The next level, or for the top the word after it.
                sums: (offset + size) as u32,
                _pad: 0,
            };
            let at = l * stride as usize;
            table[at..at + std::mem::size_of::<ScanLevel>()]
                .copy_from_slice(bytemuck::bytes_of(&level));
            levels.push((grid(size)?, (l as u64 * stride) as u32));
            offset += size;
        }
        let table = s
            .builder
            .init("scan_levels", &table, wgpu::BufferUsages::UNIFORM);
        let counts = s.builder.storage("counts", count_words(buckets), 4);
        let sorted = s.builder.storage("sorted", s.n, 4);
        let particle_bucket = s.builder.storage("particle_bucket", s.n, 4);
        let resources = shared
            .clone()
            .buffer("counts", &counts)
            .buffer("counts_atomic", &counts)
            .buffer("sorted", &sorted)
            .buffer("particle_bucket", &particle_bucket)
            .resource(
                "scan_level",
                wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &table,
                    offset: 0,
                    size: std::num::NonZeroU64::new(std::mem::size_of::<ScanLevel>() as u64),
                }),
            );
        let call = |entry| s.builder.call(Stage::BroadPhase, entry, &resources);
        Ok(BroadPhase {
            clear: call("grid_clear")?,
            count_start: call("grid_count_start")?,
            count_end: call("grid_count_end")?,
            scan_up: call("scan_up")?,
            scan_down: call("scan_down")?,
            scatter: call("grid_scatter")?,
            sort: call("grid_sort")?,
            buckets: grid(buckets)?,
            particles: s.particles,
            levels,
            counts,
            sorted,
        })
    }

    /// `resources` with the grid's buffers, as its searches read them.
    pub fn resources<'a>(&'a self, resources: Resources<'a>) -> Resources<'a> {
        resources
            .buffer("counts", &self.counts)
            .buffer("sorted", &self.sorted)
    }

    /// Encodes the snapshot of the solver's state as `snapshot` and the grid of its positions.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>, snapshot: Snapshot) {
        self.clear.run(pass, self.buckets);
        let count = match snapshot {
            Snapshot::Start => &self.count_start,
            Snapshot::End => &self.count_end,
        };
        count.run(pass, self.particles);
        for &(grid, slot) in &self.levels {
            self.scan_up.run_at(pass, grid, &[slot]);
        }
        // Downwards from the level below the top, which one block has scanned whole.
        for &(grid, slot) in self.levels.iter().rev().skip(1) {
            self.scan_down.run_at(pass, grid, &[slot]);
        }
        self.scatter.run(pass, self.particles);
        self.sort.run(pass, self.buckets);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prefix_sum_has_a_level_per_factor_of_256() {
        assert_eq!(level_sizes(4), [4]);
        assert_eq!(level_sizes(256), [256]);
        assert_eq!(level_sizes(512), [512, 2]);
        assert_eq!(level_sizes(1 << 24), [1 << 24, 65_536, 256]);
        assert_eq!(level_sizes(1 << 25), [1 << 25, 131_072, 512, 2]);
        assert_eq!(count_words(512), 515);
    }
}
