//! The fused pass of the explicit integrators: spring forces at (x, v), summed per particle,
//! and each particle's update, in one sweep that keeps the per-spring forces in cache.
//!
//! # Why
//!
//! Computing every spring force into a buffer and then gathering them per particle streams that
//! buffer (24 bytes per spring) out to memory and back, and the gather's reads jump across it:
//! on a large body that is most of a step's time. Here each thread sweeps its own contiguous
//! range of particles once.
//!
//! # How, and why the bits do not change
//!
//! [`gather`](crate::spring_forces::gather) sums a particle's spring forces in ascending spring
//! order, starting from +0. Sweeping the springs in ascending order and adding each force to
//! its first end's sum and subtracting it from its second end's sum produces, for every
//! particle, exactly that sequence of additions: the same bits.
//!
//! The sweep applies when every spring s has `a[s] < b[s]` and the springs are sorted by `a`
//! ("forward" models: every cuboid, and any set of bodies made of them). Then the springs that
//! start at particle p are one contiguous range `a_start[p]..a_start[p + 1]`, every spring
//! touching p starts at p or before it, and p's sum is complete once the sweep has passed p's
//! own springs: its update runs right then, reading the pass's inputs and writing its outputs
//! (other arrays: the workspace double-buffers the state).
//!
//! The particles are split into one chunk per thread. A chunk's *tail* is its particles from
//! the first one with a spring reaching beyond the chunk. Phase A computes the forces of the
//! springs starting in every tail into a small buffer. Phase B runs one task per chunk: it
//! zeroes its particles' sums, subtracts the forces of earlier chunks' tail springs that end in
//! it (in ascending order: those springs come before any of its own), then sweeps its own
//! springs in windows of [`WINDOW`], computing each window's forces with the spring kernel (or
//! taking them from phase A in the tail), adding each to its first end and subtracting it from
//! its second end when that lies in the chunk (the next chunks take the others from phase A).
//! Each spring is computed once, by the same kernel, from the same inputs, and every sum has
//! the gather's order, so the result does not depend on the number of chunks or threads.
//!
//! Models that are not forward take the plain route: every spring force into a buffer, then a
//! gather per particle.

use std::marker::PhantomData;
use std::ops::Range;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Model, Springs};

use crate::spring_forces::{Kernel, gather_block};

/// Particles gathered together on the plain route.
const BLOCK: usize = 64;
/// Springs whose forces are computed together in a sweep.
pub(crate) const WINDOW: usize = 512;

/// How a model's particles are split into chunks, made once per thread count, and the scratch
/// of the passes.
#[derive(Debug, Clone)]
pub(crate) struct Plan {
    /// Rayon threads the plan was made for.
    threads: usize,
    /// Particles per chunk (the last may have fewer).
    chunk: usize,
    /// The sweep's plan, for forward models.
    forward: Option<Forward>,
    /// Plain route: the force of every spring.
    per_spring: Vec<DVec3>,
}

#[derive(Debug, Clone)]
struct Forward {
    /// `a_start[p]..a_start[p + 1]` are the springs starting at p.
    a_start: Vec<u32>,
    /// Per chunk, its first tail particle (its end when no spring reaches beyond it).
    tail: Vec<usize>,
    /// Per chunk, where its tail springs' forces start in `tail_forces`.
    tail_offset: Vec<usize>,
    /// Per chunk, the largest second end among its tail springs (0 when none).
    tail_reach: Vec<usize>,
    /// Forces of the tail springs, chunk after chunk.
    tail_forces: Vec<DVec3>,
    /// Each particle's running sum of spring forces.
    sums: Vec<DVec3>,
}

impl Plan {
    /// The plan of `model` for the current rayon pool.
    pub(crate) fn new(model: &Model) -> Plan {
        let n = model.len();
        let threads = rayon::current_num_threads();
        // One chunk per thread: every chunk boundary costs phase-A work, and the chunks are
        // equal.
        let chunk = n.div_ceil(threads).max(BLOCK);
        let forward = forward_starts(n, &model.springs).map(|a_start| {
            let b = &model.springs.b;
            let chunks = n.div_ceil(chunk);
            let (mut tail, mut tail_offset, mut tail_reach) = (vec![], vec![], vec![]);
            let mut offset = 0;
            for c in 0..chunks {
                let (start, end) = (c * chunk, ((c + 1) * chunk).min(n));
                let starting = |p: usize| a_start[p] as usize..a_start[p + 1] as usize;
                let t = (start..end)
                    .find(|&p| b[starting(p)].iter().any(|&b| b as usize >= end))
                    .unwrap_or(end);
                let springs = a_start[t] as usize..a_start[end] as usize;
                tail.push(t);
                tail_offset.push(offset);
                tail_reach.push(
                    b[springs.clone()]
                        .iter()
                        .map(|&b| b as usize)
                        .max()
                        .unwrap_or(0),
                );
                offset += springs.len();
            }
            Forward {
                a_start,
                tail,
                tail_offset,
                tail_reach,
                tail_forces: vec![DVec3::ZERO; offset],
                sums: vec![DVec3::ZERO; n],
            }
        });
        let per_spring = match forward {
            Some(_) => Vec::new(),
            None => vec![DVec3::ZERO; model.springs.len()],
        };
        Plan {
            threads,
            chunk,
            forward,
            per_spring,
        }
    }

    /// A plan for no particles (implicit Euler has no use for one).
    pub(crate) fn empty() -> Plan {
        Plan {
            threads: rayon::current_num_threads(),
            chunk: BLOCK,
            forward: None,
            per_spring: Vec::new(),
        }
    }

    /// Whether the plan was made for the current rayon pool.
    pub(crate) fn fits(&self) -> bool {
        self.threads == rayon::current_num_threads()
    }

    /// Bytes held on the heap.
    pub(crate) fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        vec_bytes(&self.per_spring)
            + self.forward.as_ref().map_or(0, |f| {
                vec_bytes(&f.a_start)
                    + vec_bytes(&f.tail)
                    + vec_bytes(&f.tail_offset)
                    + vec_bytes(&f.tail_reach)
                    + vec_bytes(&f.tail_forces)
                    + vec_bytes(&f.sums)
            })
    }
}

/// `a_start` when every spring has a < b and the springs are sorted by a; None otherwise.
fn forward_starts(n: usize, springs: &Springs) -> Option<Vec<u32>> {
    let (a, b) = (&springs.a, &springs.b);
    let forward = a.iter().zip(b).all(|(a, b)| a < b && (*b as usize) < n)
        && a.windows(2).all(|w| w[0] <= w[1]);
    if !forward {
        return None;
    }
    let mut start = vec![0u32; n + 1];
    for &a in a {
        start[a as usize + 1] += 1;
    }
    for p in 0..n {
        start[p + 1] += start[p];
    }
    Some(start)
}

/// A buffer that phase A's tasks write in disjoint ranges.
struct Shared<'a> {
    ptr: *mut DVec3,
    len: usize,
    _buffer: PhantomData<&'a mut [DVec3]>,
}

// SAFETY: phase A hands each task a disjoint range to write and reads nothing.
unsafe impl Send for Shared<'_> {}
unsafe impl Sync for Shared<'_> {}

impl<'a> Shared<'a> {
    fn new(buffer: &'a mut [DVec3]) -> Shared<'a> {
        Shared {
            ptr: buffer.as_mut_ptr(),
            len: buffer.len(),
            _buffer: PhantomData,
        }
    }

    /// # Safety
    /// No other reference to these elements exists while the slice lives.
    #[allow(clippy::mut_from_ref)]
    unsafe fn range_mut(&self, r: Range<usize>) -> &mut [DVec3] {
        assert!(r.start <= r.end && r.end <= self.len);
        // SAFETY: in bounds; exclusivity is the caller's promise.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(r.start), r.end - r.start) }
    }
}

/// Per-particle output arrays that a pass writes, split into chunks for the tasks.
pub(crate) trait Outputs: Send {
    /// One chunk of each array.
    type Chunk: Send;
    /// One element of each.
    type Item<'a>;
    /// The arrays in chunks of `size` particles.
    fn chunks(self, size: usize) -> impl IndexedParallelIterator<Item = Self::Chunk>;
    /// Element k of a chunk.
    fn item(chunk: &mut Self::Chunk, k: usize) -> Self::Item<'_>;
    /// Particles in a chunk.
    fn len(chunk: &Self::Chunk) -> usize;
}

impl<'o> Outputs for (&'o mut [DVec3], &'o mut [DVec3]) {
    type Chunk = (&'o mut [DVec3], &'o mut [DVec3]);
    type Item<'a> = (&'a mut DVec3, &'a mut DVec3);
    fn chunks(self, size: usize) -> impl IndexedParallelIterator<Item = Self::Chunk> {
        assert_eq!(self.0.len(), self.1.len());
        (self.0.par_chunks_mut(size), self.1.par_chunks_mut(size)).into_par_iter()
    }
    #[inline(always)]
    fn item(chunk: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        (&mut chunk.0[k], &mut chunk.1[k])
    }
    fn len(chunk: &Self::Chunk) -> usize {
        chunk.0.len()
    }
}

impl<'o> Outputs
    for (
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
    )
{
    type Chunk = (
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
        &'o mut [DVec3],
    );
    type Item<'a> = (&'a mut DVec3, &'a mut DVec3, &'a mut DVec3, &'a mut DVec3);
    fn chunks(self, size: usize) -> impl IndexedParallelIterator<Item = Self::Chunk> {
        let n = self.0.len();
        assert!(self.1.len() == n && self.2.len() == n && self.3.len() == n);
        (
            self.0.par_chunks_mut(size),
            self.1.par_chunks_mut(size),
            self.2.par_chunks_mut(size),
            self.3.par_chunks_mut(size),
        )
            .into_par_iter()
    }
    #[inline(always)]
    fn item(chunk: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        (
            &mut chunk.0[k],
            &mut chunk.1[k],
            &mut chunk.2[k],
            &mut chunk.3[k],
        )
    }
    fn len(chunk: &Self::Chunk) -> usize {
        chunk.0.len()
    }
}

/// One fused pass: the spring forces at (x, v), then for every particle i
/// `update(i, springs_i, outputs_i)` with `springs_i` the sum of its spring forces. `update`
/// returns false for a particle it finds not finite; the pass returns the first such particle.
#[allow(clippy::too_many_arguments)]
pub(crate) fn pass<O: Outputs>(
    plan: &mut Plan,
    kernel: Kernel,
    model: &Model,
    x: &[DVec3],
    v: &[DVec3],
    outputs: O,
    update: impl Fn(usize, DVec3, O::Item<'_>) -> bool + Sync,
) -> Option<usize> {
    let n = model.len();
    assert!(x.len() == n && v.len() == n && plan.fits());
    let springs = &model.springs;
    let chunk = plan.chunk;
    let Some(fw) = &mut plan.forward else {
        // The plain route: every spring, then a gather per block of particles.
        let per_spring = &mut plan.per_spring[..];
        kernel.compute(springs, x, v, per_spring);
        let per_spring = &*per_spring;
        return outputs
            .chunks(chunk)
            .enumerate()
            .filter_map(|(c, mut out)| {
                let start = c * chunk;
                let end = start + O::len(&out);
                let mut bad = None;
                let mut sums = [DVec3::ZERO; BLOCK];
                for b0 in (start..end).step_by(BLOCK) {
                    let b1 = (b0 + BLOCK).min(end);
                    let sums = &mut sums[..b1 - b0];
                    gather_block(&model.adjacency, per_spring, b0, sums);
                    for (k, &f) in sums.iter().enumerate() {
                        let i = b0 + k;
                        if !update(i, f, O::item(&mut out, i - start)) && bad.is_none() {
                            bad = Some(i);
                        }
                    }
                }
                bad
            })
            .min();
    };
    let Forward {
        a_start,
        tail,
        tail_offset,
        tail_reach,
        tail_forces,
        sums,
    } = fw;
    let (a_start, tail, tail_offset, tail_reach) =
        (&a_start[..], &tail[..], &tail_offset[..], &tail_reach[..]);
    assert!(a_start.len() == n + 1 && a_start[n] as usize == springs.len());
    assert!(springs.b.len() == springs.len());
    // Phase A: the forces of the springs starting in every chunk's tail.
    {
        let shared = Shared::new(tail_forces);
        tail.par_iter().enumerate().for_each(|(c, &t)| {
            let end = ((c + 1) * chunk).min(n);
            let r = a_start[t] as usize..a_start[end] as usize;
            // SAFETY: each chunk writes its own range of the buffer; nothing reads it now.
            let out = unsafe { shared.range_mut(tail_offset[c]..tail_offset[c] + r.len()) };
            kernel.range(springs, x, v, r.start, out);
        });
    }
    let tail_forces = &tail_forces[..];
    let b_of = &springs.b[..];
    // Phase B: one sweep per chunk.
    (sums.par_chunks_mut(chunk), outputs.chunks(chunk))
        .into_par_iter()
        .enumerate()
        .filter_map(|(c, (sums, mut out))| {
            let start = c * chunk;
            let end = start + sums.len();
            sums.fill(DVec3::ZERO);
            // Earlier chunks' tail springs ending here, in ascending order.
            for e in 0..c {
                if tail_reach[e] < start {
                    continue;
                }
                let r = a_start[tail[e]] as usize..a_start[((e + 1) * chunk).min(n)] as usize;
                for (k, s) in r.enumerate() {
                    let b = b_of[s] as usize;
                    if (start..end).contains(&b) {
                        sums[b - start] -= tail_forces[tail_offset[e] + k];
                    }
                }
            }
            let own_tail = a_start[tail[c]] as usize;
            let own_end = a_start[end] as usize;
            let mut window = [DVec3::ZERO; WINDOW];
            // The window of computed forces, [w0, w1): empty, at the chunk's first spring.
            let (mut w0, mut w1) = (a_start[start] as usize, a_start[start] as usize);
            let mut bad = None;
            for p in start..end {
                let mut sum = sums[p - start];
                for s in a_start[p] as usize..a_start[p + 1] as usize {
                    let f = if s >= own_tail {
                        tail_forces[tail_offset[c] + s - own_tail]
                    } else {
                        if s == w1 {
                            (w0, w1) = (s, (s + WINDOW).min(own_tail));
                            kernel.range(springs, x, v, w0, &mut window[..w1 - w0]);
                        }
                        window[s - w0]
                    };
                    sum += f;
                    let b = b_of[s] as usize;
                    if b < end {
                        sums[b - start] -= f;
                    }
                }
                if !update(p, sum, O::item(&mut out, p - start)) && bad.is_none() {
                    bad = Some(p);
                }
            }
            debug_assert!(w1 <= own_tail && own_tail <= own_end);
            bad
        })
        .min()
}
