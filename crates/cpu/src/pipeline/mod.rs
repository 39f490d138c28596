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
//! springs starting in every tail into a small buffer, split evenly among the threads. Phase B
//! runs one task per chunk (the chunk boundaries are placed so that these take equal work): it
//! zeroes its particles' sums, subtracts the forces of earlier chunks' tail springs that end in
//! it (in ascending order: those springs come before any of its own), then sweeps its own
//! springs, computing their forces with the spring kernel four at a time (or taking them from
//! phase A in the tail), adding each to its first end and subtracting it from its second end
//! when that lies in the chunk (the next chunks take the others from phase A).
//! Each spring is computed once, by the same kernel, from the same inputs, and every sum has
//! the gather's order, so the result does not depend on the number of chunks or threads.
//!
//! Models whose bodies are all lattices (cuboids, mesh bodies) take the stencil route instead
//! ([`crate::spring_forces::stencil`]): one slab of planes per chunk, partners at constant
//! offsets, the sums again in the gather's order. Models that are not forward take the plain
//! route: every spring force into a buffer, then a gather per particle. All three give the
//! same bits.

mod chunks;
mod plan;
#[cfg(test)]
mod tests;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::Model;

use crate::spring_forces::stencil::Row;
use crate::spring_forces::{Cursor, Kernel, LANES, Sum, gather_block};
pub(crate) use chunks::Outputs;
use chunks::{Chunks, Shared};
pub(crate) use plan::Plan;
use plan::{Forward, Route};

/// Particles gathered, or updated, together.
const BLOCK: usize = 64;
/// Fewest particles per chunk.
const MIN_CHUNK: usize = 256;

/// What a pass on the stencil route does with a whole grid row before the per-particle
/// update: the lanes it can update together (in vector registers), leaving the others to the
/// per-particle update. It must write, for every lane it takes, the bits the per-particle
/// update would, and take no lane that update would find not finite.
pub(crate) trait RowUpdate<O: Outputs>: Sync {
    /// Updates the lanes of `row` that it can into `out` (the chunk's outputs, in which the
    /// row's first particle is at `at`), and sets `todo[i]` to whether it leaves lane i to the
    /// per-particle update.
    fn row(&self, row: &Row<'_>, out: &mut O::Chunk, at: usize, todo: &mut [bool]);
}

/// Every particle by the per-particle update.
pub(crate) struct PerParticle;

impl<O: Outputs> RowUpdate<O> for PerParticle {
    fn row(&self, _: &Row<'_>, _: &mut O::Chunk, _: usize, todo: &mut [bool]) {
        todo.fill(true);
    }
}

/// One fused pass: the spring forces at (x, v), then for every particle i
/// `update(i, springs_i, outputs_i)` with `springs_i` the sum of its spring forces. `update`
/// returns false for a particle it finds not finite; the pass returns the first such particle.
pub(crate) fn pass<O: Outputs, U>(
    plan: &mut Plan,
    kernel: Kernel,
    model: &Model,
    (x, v): (&[DVec3], &[DVec3]),
    outputs: O,
    update: U,
) -> Option<usize>
where
    U: Fn(usize, DVec3, O::Item<'_>) -> bool + Sync,
{
    pass_rows(plan, kernel, model, (x, v), outputs, &PerParticle, update)
}

/// [`pass`], with `rows` taking what it can of each grid row on the stencil route first.
pub(crate) fn pass_rows<O: Outputs, U>(
    plan: &mut Plan,
    kernel: Kernel,
    model: &Model,
    (x, v): (&[DVec3], &[DVec3]),
    outputs: O,
    rows: &impl RowUpdate<O>,
    update: U,
) -> Option<usize>
where
    U: Fn(usize, DVec3, O::Item<'_>) -> bool + Sync,
{
    let n = model.len();
    let outputs = outputs.whole();
    assert!(x.len() == n && v.len() == n && O::len(&outputs) == n && plan.fits());
    let k = plan.bounds.len() - 1;
    let ctx = Chunks {
        bounds: &plan.bounds,
    };
    let fw = match &mut plan.route {
        Route::Stencil { stencils, slabs } => {
            let (stencils, slabs) = (&stencils[..], &slabs[..]);
            let leaf = |c: usize, _: &mut [Sum], mut out: O::Chunk| {
                // Each chunk's slab is locked by its one task only.
                let mut slab = slabs[c].lock().unwrap_or_else(|e| e.into_inner());
                let start = ctx.bounds[c];
                let mut bad = None;
                let stencil = &stencils[slab.lattice];
                let mut todo = Vec::new();
                slab.sweep(stencil, x, v, &mut |row| {
                    todo.resize(row.len(), true);
                    rows.row(row, &mut out, row.p0 - start, &mut todo);
                    for (i, _) in todo.iter().enumerate().filter(|(_, t)| **t) {
                        let (p, (_, _, f)) = (row.p0 + i, row.particle(i));
                        if !update(p, f, O::item(&mut out, p - start)) && bad.is_none() {
                            bad = Some(p);
                        }
                    }
                });
                bad
            };
            return ctx.chunks::<O>(0, k, &mut [], outputs, &leaf);
        }
        Route::Sweep(fw) => fw,
        Route::Gather { per_spring } => {
            // The plain route: every spring, then a gather per block of particles.
            let per_spring = &mut per_spring[..];
            kernel.compute(model.springs(), x, v, per_spring);
            let per_spring = &*per_spring;
            let leaf = |c: usize, _: &mut [Sum], mut out: O::Chunk| {
                let (start, end) = (ctx.bounds[c], ctx.bounds[c + 1]);
                let mut bad = None;
                let mut sums = [DVec3::ZERO; BLOCK];
                for b0 in (start..end).step_by(BLOCK) {
                    let b1 = (b0 + BLOCK).min(end);
                    let sums = &mut sums[..b1 - b0];
                    gather_block(model.adjacency(), per_spring, b0, sums);
                    for (k, &f) in sums.iter().enumerate() {
                        let i = b0 + k;
                        if !update(i, f, O::item(&mut out, i - start)) && bad.is_none() {
                            bad = Some(i);
                        }
                    }
                }
                bad
            };
            return ctx.chunks::<O>(0, k, &mut [], outputs, &leaf);
        }
    };
    let Forward {
        a_start,
        tail,
        tail_offset,
        tail_reach,
        tail_forces,
        sums,
    } = fw;
    let springs = model.springs();
    let (a_start, tail, tail_offset, tail_reach) =
        (&a_start[..], &tail[..], &tail_offset[..], &tail_reach[..]);
    assert!(a_start.len() == n + 1 && a_start[n] as usize == springs.len());
    assert!(springs.b.len() == springs.len() && springs.rest.len() == springs.len());
    assert!(springs.stiffness.len() == springs.len() && springs.damping.len() == springs.len());
    // Phase A: the forces of the springs starting in every chunk's tail, in equal pieces.
    {
        let total = tail_forces.len();
        let piece = total
            .div_ceil(rayon::current_num_threads())
            .next_multiple_of(LANES)
            .max(LANES);
        let shared = Shared::new(tail_forces);
        (0..total.div_ceil(piece)).into_par_iter().for_each(|q| {
            let (q0, q1) = (q * piece, ((q + 1) * piece).min(total));
            for c in 0..k {
                let (o0, o1) = (tail_offset[c].max(q0), tail_offset[c + 1].min(q1));
                if o0 < o1 {
                    // SAFETY: the pieces are disjoint; nothing reads the buffer now.
                    let out = unsafe { shared.range_mut(o0..o1) };
                    let first = a_start[tail[c]] as usize + (o0 - tail_offset[c]);
                    kernel.range(springs, x, v, first, out);
                }
            }
        });
    }
    let tail_forces = &tail_forces[..];
    // Phase B: one sweep per chunk.
    let leaf = |c: usize, sums: &mut [Sum], mut out: O::Chunk| {
        let (start, end) = (ctx.bounds[c], ctx.bounds[c + 1]);
        assert_eq!(sums.len(), end - start);
        sums.fill(Sum::ZERO);
        // Earlier chunks' tail springs ending here, in ascending order.
        for e in 0..c {
            if tail_reach[e] < start {
                continue;
            }
            let r = a_start[tail[e]] as usize..a_start[ctx.bounds[e + 1]] as usize;
            let forces = &tail_forces[tail_offset[e]..tail_offset[e + 1]];
            for (&b, f) in springs.b[r].iter().zip(forces) {
                let b = b as usize;
                if (start..end).contains(&b) {
                    sums[b - start].f -= *f;
                }
            }
        }
        let mut bad = None;
        let mut cursor = Cursor {
            p: start,
            sum: sums.first().map_or(DVec3::ZERO, |s| s.f),
        };
        // The chunk's springs before its tail are computed here; its tail's come from
        // phase A.
        let tail_first = a_start[tail[c]] as usize;
        let forces = &tail_forces[tail_offset[c]..tail_offset[c + 1]];
        let mut block = [DVec3::ZERO; BLOCK];
        for b0 in (start..end).step_by(BLOCK) {
            let b1 = (b0 + BLOCK).min(end);
            // The sums of the block's particles, as the sweep completes them.
            let mut record = |p: usize, sum: DVec3| block[p - b0] = sum;
            let (s0, s1) = (a_start[b0] as usize, a_start[b1] as usize);
            let computed = s0..s1.min(tail_first);
            if !computed.is_empty() {
                // SAFETY: the plan checked that every spring has a < b < n, and the pass
                // that x, v, rest (and parameters) have their lengths. These springs start
                // before the chunk's tail, so none reaches beyond the chunk (`tails`): every
                // b lies in start..end, the particles of `sums`.
                cursor = unsafe {
                    kernel.sweep_checked(
                        springs,
                        x,
                        v,
                        computed.start,
                        computed.len(),
                        sums,
                        start,
                        cursor,
                        &mut record,
                    )
                };
            }
            for s in s0.max(tail_first)..s1 {
                let (a, b) = (springs.a[s] as usize, springs.b[s] as usize);
                cursor.take(a, b, forces[s - tail_first], sums, start, &mut record);
            }
            cursor.advance(b1, sums, start, &mut record);
            for (k, &sum) in block[..b1 - b0].iter().enumerate() {
                let p = b0 + k;
                if !update(p, sum, O::item(&mut out, p - start)) && bad.is_none() {
                    bad = Some(p);
                }
            }
        }
        bad
    };
    ctx.chunks::<O>(0, k, sums, outputs, &leaf)
}
