//! Spring chunks: per-spring arrays split across storage bindings.
//!
//! Per-spring arrays (the springs, the per-spring vectors, implicit Euler's blocks) grow with
//! the springs, about 13 per particle: a 100³ cube's 15.7 M springs need 314 MB of spring
//! records, more than one storage binding holds on many adapters (`max_storage_buffer_binding_size`
//! is 128 MiB on Mesa and a common default). So each is kept as K buffers of 2^k springs (the
//! last one shorter), with 2^k the largest power of two whose widest per-spring element (20
//! bytes, 32 with implicit Euler's blocks) fits one binding and one buffer
//! (`min(max_storage_buffer_binding_size, max_buffer_size)`); a scene that fits has one chunk.
//! Every per-spring kernel is dispatched once per chunk, with a bind group of that chunk's
//! buffers and its [`SpringChunk`] uniform (first spring, count, first energy partial). The
//! per-particle gathers bind all K chunks of what they gather and pick spring s's chunk as
//! `s >> k` (accessors generated per K by [`crate::shaders`]): the same reads in the same order,
//! so a chunked run is bit-identical to an unchunked one. What bounds K is checked against
//! the adapter's limits when the solver is built.

use wgpu::util::DeviceExt;

use crate::WORKGROUP_SIZE;
use crate::grid::Grid;
use crate::layout::SpringChunk;

/// Binding of the per-spring vectors' chunk 1 in the gathering kernels (chunk c at this + c − 1;
/// chunk 0 is binding 3).
pub const PER_SPRING_CHUNK_BINDING: u32 = 16;

/// Binding of implicit Euler's spring blocks' chunk 1 in `assemble_particles` and the fused
/// product (chunk c at this + c − 1; chunk 0 is binding 7).
pub const BLOCK_CHUNK_BINDING: u32 = 32;

/// Binding of the spring records' chunk 1 in the fused step's kernels and the fused product
/// (chunk c at this + c − 1; chunk 0 is binding 7 in the fused step, 6 in the fused product).
pub const SPRING_CHUNK_BINDING: u32 = 16;

/// Chunks of a per-spring array at most: the gathers' extra bindings are numbered below
/// 16 + this (the per-spring vectors) and 32 + this (implicit Euler's blocks) in the generated
/// accessors; in practice the adapter's storage buffers per stage bound the count first.
pub const MAX_SPRING_CHUNKS: u32 = 16;

/// How the per-spring arrays are split: `count` chunks of `2^shift` springs (the last one
/// shorter). One chunk (`count` 1) is the unsplit layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Chunking {
    /// Chunks, 1 to [`MAX_SPRING_CHUNKS`].
    pub count: u32,
    /// log2 of the springs per chunk.
    pub shift: u32,
}

impl Chunking {
    /// One chunk: every spring in one binding.
    pub const ONE: Chunking = Chunking {
        count: 1,
        shift: 31,
    };

    /// (first spring, springs) of each chunk of `springs` springs; one empty chunk when there
    /// are none.
    pub fn ranges(self, springs: u64) -> Vec<(u64, u64)> {
        if self.count == 1 {
            return vec![(0, springs)];
        }
        let per = 1u64 << self.shift;
        (0..u64::from(self.count))
            .map(|c| (c * per, per.min(springs - c * per)))
            .collect()
    }
}

/// How the per-spring arrays are split into chunks (see the module documentation).
pub(crate) struct SpringChunks {
    /// (first spring, springs) of each chunk; one empty chunk when there are no springs.
    pub ranges: Vec<(u64, u64)>,
    /// Each chunk's dispatch grid.
    pub grids: Vec<Grid>,
    /// [`SpringChunk`] of chunk c at byte `c · stride`.
    pub table: wgpu::Buffer,
    /// The uniform offset alignment (at least the record's size).
    pub stride: u64,
}

impl SpringChunks {
    /// The dispatch grids of the chunks of `springs` springs split as `chunking` says, at most
    /// `width` workgroups wide and `max_rows` rows; `None` if one does not fit.
    pub fn grids(chunking: Chunking, springs: u64, width: u32, max_rows: u32) -> Option<Vec<Grid>> {
        chunking
            .ranges(springs)
            .iter()
            .map(|&(_, count)| Grid::with_width(count, width, max_rows))
            .collect()
    }

    /// The chunks of `springs` springs split as `chunking` says, with their grids `grids`
    /// ([`SpringChunks::grids`]) and their uniform table.
    pub fn new(
        device: &wgpu::Device,
        chunking: Chunking,
        springs: u64,
        grids: Vec<Grid>,
        uniform_alignment: u32,
    ) -> SpringChunks {
        let ranges = chunking.ranges(springs);
        let stride = u64::from(uniform_alignment).max(std::mem::size_of::<SpringChunk>() as u64);
        let mut table = vec![0u8; (ranges.len() as u64 * stride) as usize];
        for (c, &(base, count)) in ranges.iter().enumerate() {
            let at = c * stride as usize;
            let record = SpringChunk {
                base: base as u32,
                count: count as u32,
                first_group: (base / WORKGROUP_SIZE) as u32,
                _pad: 0,
            };
            table[at..at + std::mem::size_of::<SpringChunk>()]
                .copy_from_slice(bytemuck::bytes_of(&record));
        }
        let table = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("spring chunks"),
            contents: &table,
            usage: wgpu::BufferUsages::UNIFORM,
        });
        SpringChunks {
            ranges,
            grids,
            table,
            stride,
        }
    }

    /// Chunk `c`'s uniform, for its bind groups.
    pub fn uniform(&self, c: usize) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &self.table,
            offset: c as u64 * self.stride,
            size: std::num::NonZeroU64::new(std::mem::size_of::<SpringChunk>() as u64),
        })
    }

    /// The grid of the largest chunk (the first), which the indirect dispatches of every chunk
    /// use: the threads of a shorter chunk past its count return at once.
    pub fn largest_grid(&self) -> Grid {
        self.grids[0]
    }

    /// Chunks.
    pub fn len(&self) -> usize {
        self.ranges.len()
    }
}

/// The chunking of `springs` springs whose widest per-spring element has `stride` bytes, in
/// bindings of at most `cap` bytes: one chunk if they fit, else chunks of the largest power of
/// two of springs that fits (at least a workgroup, so that the energy partial sums of a chunk
/// start at a whole workgroup); `None` if not even a workgroup's springs fit.
pub(crate) fn plan_chunks(springs: u64, stride: u64, cap: u64) -> Option<Chunking> {
    if springs.saturating_mul(stride) <= cap {
        return Some(Chunking::ONE);
    }
    let per = cap / stride;
    if per < WORKGROUP_SIZE {
        return None;
    }
    let shift = per.ilog2().min(31);
    Some(Chunking {
        count: u32::try_from(springs.div_ceil(1 << shift)).unwrap_or(u32::MAX),
        shift,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn springs_are_chunked_by_powers_of_two_that_fit_a_binding() {
        let mib = 1u64 << 20;
        // Fits: one chunk of any length.
        assert_eq!(plan_chunks(6_220, 20, 6_220 * 20), Some(Chunking::ONE));
        assert_eq!(plan_chunks(0, 32, 0), Some(Chunking::ONE));
        // A 100³ cube's 15.7 M springs under Mesa's 128 MiB bindings: 4 M springs per chunk
        // (20-byte records, or 32-byte implicit blocks: 4 M × 32 B = 128 MiB exactly).
        let cube = 15_700_000;
        let explicit = plan_chunks(cube, 20, 128 * mib).unwrap();
        assert_eq!((explicit.count, explicit.shift), (4, 22));
        let implicit = plan_chunks(cube, 32, 128 * mib).unwrap();
        assert_eq!((implicit.count, implicit.shift), (4, 22));
        // The test cap: 64 KiB bindings split 6,220 springs into 4 chunks of 2,048.
        let small = plan_chunks(6_220, 20, 64 * 1024).unwrap();
        assert_eq!((small.count, small.shift), (4, 11));
        // Not even a workgroup's springs fit.
        assert_eq!(plan_chunks(10_000, 20, 255 * 20), None);
        assert!(plan_chunks(10_000, 20, 256 * 20).is_some());
    }
}
