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

use std::marker::PhantomData;
use std::ops::Range;
use std::sync::Mutex;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Model, Springs};

use crate::spring_forces::Isa;
use crate::spring_forces::stencil::{Row, Slab, Stencil};
use crate::spring_forces::{Cursor, Kernel, LANES, Sum, gather_block};

/// Particles gathered, or updated, together.
const BLOCK: usize = 64;
/// Fewest particles per chunk.
const MIN_CHUNK: usize = 256;

/// How a model's particles are split into chunks, made once per thread count, and the scratch
/// of the passes.
#[derive(Debug, Clone)]
pub(crate) struct Plan {
    /// Rayon threads the plan was made for.
    threads: usize,
    /// Chunk c is particles `bounds[c]..bounds[c + 1]`.
    bounds: Vec<usize>,
    route: Route,
}

/// How a pass finds each particle's springs.
#[derive(Debug)]
enum Route {
    /// Every body a cuboid: the stencil of each lattice, and chunk c's slab of planes.
    Stencil {
        stencils: Vec<Stencil>,
        slabs: Vec<Mutex<Slab>>,
    },
    /// Forward models: the sweep.
    Sweep(Forward),
    /// Others: every spring force into `per_spring`, then a gather per particle.
    Gather { per_spring: Vec<DVec3> },
}

impl Clone for Route {
    fn clone(&self) -> Route {
        match self {
            Route::Stencil { stencils, slabs } => Route::Stencil {
                stencils: stencils.clone(),
                slabs: (slabs.iter())
                    .map(|s| Mutex::new(s.lock().unwrap_or_else(|e| e.into_inner()).clone()))
                    .collect(),
            },
            Route::Sweep(f) => Route::Sweep(f.clone()),
            Route::Gather { per_spring } => Route::Gather {
                per_spring: per_spring.clone(),
            },
        }
    }
}

/// The routes a plan can take ([`Plan::with_route`]), by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RouteKind {
    /// [`crate::spring_forces::stencil`], for models of lattice bodies only (cuboids, mesh
    /// bodies).
    Stencil,
    /// The fused sweep over springs sorted by their first end, for forward models.
    Sweep,
    /// Every spring into a buffer, then a gather per particle: any model.
    Gather,
}

#[derive(Debug, Clone)]
struct Forward {
    /// `a_start[p]..a_start[p + 1]` are the springs starting at p.
    a_start: Vec<u32>,
    /// Per chunk, its first tail particle (its end when no spring reaches beyond it).
    tail: Vec<usize>,
    /// Chunk c's tail springs' forces are `tail_forces[tail_offset[c]..tail_offset[c + 1]]`.
    tail_offset: Vec<usize>,
    /// Per chunk, the largest second end among its tail springs (0 when none).
    tail_reach: Vec<usize>,
    /// Forces of the tail springs, chunk after chunk.
    tail_forces: Vec<DVec3>,
    /// Each particle's running sum of spring forces.
    sums: Vec<Sum>,
}

impl Plan {
    /// The plan of `model` for the current rayon pool, by the fastest route that applies.
    pub(crate) fn new(model: &Model) -> Plan {
        let route = if Plan::stencil_applies(model) {
            RouteKind::Stencil
        } else if forward_starts(model.len(), model.springs()).is_some() {
            RouteKind::Sweep
        } else {
            RouteKind::Gather
        };
        Plan::with_route(model, route)
    }

    /// Whether the stencil applies: every body is a lattice (a cuboid, or a mesh body's
    /// masked lattice, whose rows the stencil takes by their runs of particles).
    fn stencil_applies(model: &Model) -> bool {
        let lattices = model.lattices();
        !lattices.is_empty() && lattices.len() == model.bodies.len()
    }

    /// The plan of `model` for the current rayon pool by `route`; panics if it does not apply.
    pub(crate) fn with_route(model: &Model, route: RouteKind) -> Plan {
        let n = model.len();
        let threads = rayon::current_num_threads();
        let (bounds, route) = match route {
            RouteKind::Stencil => {
                assert!(Plan::stencil_applies(model), "a model of lattices only");
                // About one slab per thread on the whole, in proportion to each body's
                // particles; each costs its thread the springs from the two planes below it
                // again. A body's slabs hold about equal numbers of its particles.
                let stencils: Vec<Stencil> = model.lattices().iter().map(Stencil::new).collect();
                let mut bounds = vec![0];
                let mut slabs = Vec::new();
                for (l, stencil) in stencils.iter().enumerate() {
                    let planes = stencil.planes();
                    let (first, end) = (stencil.plane_start(0), stencil.plane_start(planes));
                    let share = (threads * (end - first) + n / 2) / n.max(1);
                    let count = share.clamp(1, planes);
                    let mut cuts: Vec<usize> = (0..=count)
                        .map(|c| {
                            let target = first + c * (end - first) / count;
                            (0..planes)
                                .find(|&k| stencil.plane_start(k) >= target)
                                .unwrap_or(planes)
                        })
                        .collect();
                    (cuts[0], cuts[count]) = (0, planes);
                    cuts.dedup();
                    for c in cuts.windows(2) {
                        let (k0, k1) = (c[0], c[1]);
                        let slab = Slab::new(stencil, l, k0, k1);
                        let (first, end) = slab.particles(stencil);
                        assert_eq!(first, *bounds.last().expect("bounds start at 0"));
                        bounds.push(end);
                        slabs.push(Mutex::new(slab));
                    }
                }
                assert_eq!(bounds.last(), Some(&n), "the lattices cover the particles");
                (bounds, Route::Stencil { stencils, slabs })
            }
            RouteKind::Sweep => {
                let springs = model.springs();
                let a_start = forward_starts(n, springs).expect("a forward model");
                // One chunk per thread (each boundary costs phase-A work), placed so that the
                // chunks' phase B take about equal time: a chunk computes the forces of its
                // springs before its tail (the last chunk: all of its springs), and sums all.
                let k = threads.min(n / MIN_CHUNK).max(1);
                let equal: Vec<usize> = (0..=k).map(|c| c * n / k).collect();
                let first_tails = tails(&a_start, &springs.b, &equal);
                let tail_springs =
                    |c: usize| (a_start[equal[c + 1]] - a_start[first_tails[c]]) as usize;
                let in_tails: usize = (0..k).map(tail_springs).sum();
                // Phase B costs each chunk its springs' sums and its particles' updates, plus
                // the forces of its springs before the tail: about half of a spring's cost is
                // its force, so a chunk gets half its tail's springs on top of an equal share.
                let work = (springs.len() - in_tails / 2) / k;
                let mut bounds = vec![0];
                let mut target = 0;
                for c in 0..k - 1 {
                    target += work + tail_springs(c) / 2;
                    let p = a_start.partition_point(|&s| (s as usize) < target);
                    bounds.push(p.clamp(bounds[c] + 1, n - (k - 1 - c)));
                }
                bounds.push(n);
                let tail = tails(&a_start, &springs.b, &bounds);
                let mut tail_offset = vec![0];
                let mut tail_reach = Vec::with_capacity(k);
                for c in 0..k {
                    let r = a_start[tail[c]] as usize..a_start[bounds[c + 1]] as usize;
                    tail_offset.push(tail_offset[c] + r.len());
                    tail_reach.push(springs.b[r].iter().map(|&b| b as usize).max().unwrap_or(0));
                }
                let forward = Forward {
                    tail_forces: vec![DVec3::ZERO; tail_offset[k]],
                    a_start,
                    tail,
                    tail_offset,
                    tail_reach,
                    sums: vec![Sum::ZERO; n],
                };
                (bounds, Route::Sweep(forward))
            }
            RouteKind::Gather => {
                // Gathers are independent: four chunks per thread balance the load.
                let k = (4 * threads).min(n / MIN_CHUNK).max(1);
                let per_spring = vec![DVec3::ZERO; model.spring_count()];
                (
                    (0..=k).map(|c| c * n / k).collect(),
                    Route::Gather { per_spring },
                )
            }
        };
        Plan {
            threads,
            bounds,
            route,
        }
    }

    /// The spring kernel of the plan's route for `model`: the stencil reads each offset's
    /// parameters from the lattice, the others the list.
    pub(crate) fn kernel(&self, model: &Model) -> Kernel {
        match self.route() {
            RouteKind::Stencil => Kernel::per_spring(),
            _ => Kernel::new(model.springs()),
        }
    }

    /// The route's name, with the instruction set its kernel uses
    /// ([`softbody_scene::Statistics::kernel`]).
    pub(crate) fn kernel_name(&self) -> &'static str {
        let avx2 = crate::spring_forces::avx2();
        match (self.route(), avx2) {
            (RouteKind::Stencil, _) => match self.stencil_isa() {
                Isa::Avx512 => "stencil-avx512",
                Isa::Avx2 => "stencil-avx2",
                Isa::Scalar => "stencil",
            },
            (RouteKind::Sweep, true) => "sweep-avx2",
            (RouteKind::Sweep, false) => "sweep",
            (RouteKind::Gather, _) => "gather",
        }
    }

    /// The narrowest path the stencil's bodies take (a mesh body's stops at AVX2).
    fn stencil_isa(&self) -> Isa {
        let Route::Stencil { stencils, .. } = &self.route else {
            return Isa::detect();
        };
        let isas = stencils.iter().map(Stencil::isa);
        isas.min_by_key(|&isa| isa as u8).unwrap_or(Isa::Scalar)
    }

    /// The route the plan takes.
    pub(crate) fn route(&self) -> RouteKind {
        match self.route {
            Route::Stencil { .. } => RouteKind::Stencil,
            Route::Sweep(_) => RouteKind::Sweep,
            Route::Gather { .. } => RouteKind::Gather,
        }
    }

    /// Whether the plan was made for the current rayon pool.
    pub(crate) fn fits(&self) -> bool {
        self.threads == rayon::current_num_threads()
    }

    /// Bytes held on the heap.
    pub(crate) fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        vec_bytes(&self.bounds)
            + match &self.route {
                Route::Stencil { slabs, .. } => slabs
                    .iter()
                    .map(|s| s.lock().map_or(0, |s| s.memory_bytes()))
                    .sum(),
                Route::Sweep(f) => {
                    vec_bytes(&f.a_start)
                        + vec_bytes(&f.tail)
                        + vec_bytes(&f.tail_offset)
                        + vec_bytes(&f.tail_reach)
                        + vec_bytes(&f.tail_forces)
                        + vec_bytes(&f.sums)
                }
                Route::Gather { per_spring } => vec_bytes(per_spring),
            }
    }
}

/// `a_start` when every spring has a < b < n and the springs are sorted by a; None otherwise.
fn forward_starts(n: usize, springs: &Springs) -> Option<Vec<u32>> {
    let (a, b) = (&springs.a, &springs.b);
    let forward = a.len() == b.len()
        && a.iter().zip(b).all(|(a, b)| a < b && (*b as usize) < n)
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

/// Each chunk's first particle with a spring reaching beyond the chunk (its end if none).
fn tails(a_start: &[u32], b: &[u32], bounds: &[usize]) -> Vec<usize> {
    bounds
        .windows(2)
        .map(|w| {
            let (start, end) = (w[0], w[1]);
            (start..end)
                .find(|&p| {
                    let r = a_start[p] as usize..a_start[p + 1] as usize;
                    b[r].iter().any(|&b| b as usize >= end)
                })
                .unwrap_or(end)
        })
        .collect()
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

/// Per-particle output arrays that a pass writes: one `&mut [DVec3]`, or a tuple of two or four.
pub(crate) trait Outputs {
    /// The arrays, or a range of particles of them.
    type Chunk: Send;
    /// One element of each.
    type Item<'a>;
    /// All of them.
    fn whole(self) -> Self::Chunk;
    /// Particles in `c`.
    fn len(c: &Self::Chunk) -> usize;
    /// The first `mid` particles of `c` and the rest.
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk);
    /// Element k of each.
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_>;
}

impl<'o> Outputs for &'o mut [DVec3] {
    type Chunk = &'o mut [DVec3];
    type Item<'a> = &'a mut DVec3;
    fn whole(self) -> Self::Chunk {
        self
    }
    fn len(c: &Self::Chunk) -> usize {
        c.len()
    }
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk) {
        c.split_at_mut(mid)
    }
    #[inline(always)]
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        &mut c[k]
    }
}

impl<'o> Outputs for (&'o mut [DVec3], &'o mut [DVec3]) {
    type Chunk = (&'o mut [DVec3], &'o mut [DVec3]);
    type Item<'a> = (&'a mut DVec3, &'a mut DVec3);
    fn whole(self) -> Self::Chunk {
        assert_eq!(self.0.len(), self.1.len());
        self
    }
    fn len(c: &Self::Chunk) -> usize {
        c.0.len()
    }
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk) {
        let (a0, a1) = c.0.split_at_mut(mid);
        let (b0, b1) = c.1.split_at_mut(mid);
        ((a0, b0), (a1, b1))
    }
    #[inline(always)]
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        (&mut c.0[k], &mut c.1[k])
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
    fn whole(self) -> Self::Chunk {
        let n = self.0.len();
        assert!(self.1.len() == n && self.2.len() == n && self.3.len() == n);
        self
    }
    fn len(c: &Self::Chunk) -> usize {
        c.0.len()
    }
    fn split_at(c: Self::Chunk, mid: usize) -> (Self::Chunk, Self::Chunk) {
        let (a0, a1) = c.0.split_at_mut(mid);
        let (b0, b1) = c.1.split_at_mut(mid);
        let (c0, c1) = c.2.split_at_mut(mid);
        let (d0, d1) = c.3.split_at_mut(mid);
        ((a0, b0, c0, d0), (a1, b1, c1, d1))
    }
    #[inline(always)]
    fn item(c: &mut Self::Chunk, k: usize) -> Self::Item<'_> {
        (&mut c.0[k], &mut c.1[k], &mut c.2[k], &mut c.3[k])
    }
}

/// The chunks of a pass: chunk c is particles `bounds[c]..bounds[c + 1]`.
struct Chunks<'a> {
    bounds: &'a [usize],
}

impl Chunks<'_> {
    /// Runs `leaf(c, sums, outputs)` for chunks `c0..c1` in parallel, each with its particles'
    /// part of `sums` and `outputs`; returns the least of their results.
    fn chunks<O: Outputs>(
        &self,
        c0: usize,
        c1: usize,
        sums: &mut [Sum],
        outputs: O::Chunk,
        leaf: &(impl Fn(usize, &mut [Sum], O::Chunk) -> Option<usize> + Sync),
    ) -> Option<usize> {
        if c1 - c0 == 1 {
            return leaf(c0, sums, outputs);
        }
        let mid = (c0 + c1) / 2;
        let at = self.bounds[mid] - self.bounds[c0];
        let (s0, s1) = sums.split_at_mut(at.min(sums.len()));
        let (o0, o1) = O::split_at(outputs, at);
        let (a, b) = rayon::join(
            || self.chunks::<O>(c0, mid, s0, o0, leaf),
            || self.chunks::<O>(mid, c1, s1, o1, leaf),
        );
        match (a, b) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

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

#[cfg(test)]
mod tests {
    use std::path::Path;

    use softbody_scene::{Scene, TriangleMesh};

    use super::*;
    use crate::spring_forces::{gather, spring_force};

    /// Cuboids of `resolutions` side by side (one body each), with every particle moved and
    /// moving differently, and one spring crushed to zero length.
    fn perturbed_bodies(resolutions: &[[u32; 3]]) -> (Model, Vec<DVec3>, Vec<DVec3>) {
        let mut text = String::new();
        for (b, [nx, ny, nz]) in resolutions.iter().enumerate() {
            text += &format!(
                "[[body]]\nname = \"b{b}\"\nkind = \"cuboid\"\ncenter = [{x}, 1.0, 0.0]\n\
                 size = [1.2, 1.0, 1.6]\nresolution = [{nx}, {ny}, {nz}]\nmass = 2.0\n\
                 structural = {{ stiffness = 2000.0, damping = 5.0 }}\n\
                 shear = {{ stiffness = 1500.0, damping = 4.0 }}\n\
                 bending = {{ stiffness = 700.0, damping = 3.0 }}\n",
                x = 3.0 * b as f64,
            );
        }
        perturbed(&text)
    }

    /// The bodies of `bodies` (TOML, beside the example scenes: mesh bodies may name their
    /// meshes), with every particle moved and moving differently, and one spring crushed to
    /// zero length.
    fn perturbed(bodies: &str) -> (Model, Vec<DVec3>, Vec<DVec3>) {
        perturbed_in(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes"),
            bodies,
        )
    }

    /// [`perturbed`], mesh files named from `dir`.
    fn perturbed_in(dir: &Path, bodies: &str) -> (Model, Vec<DVec3>, Vec<DVec3>) {
        let text = format!(
            "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 1e-5\nduration = 0.0\n{bodies}"
        );
        let scene = Scene::from_toml(&text, &dir.join("test.toml")).expect("valid scene");
        let (model, state) = Model::build(&scene);
        let wobble = |i: usize, a: f64, b: f64, c: f64| {
            let t = i as f64;
            DVec3::new((a * t).sin(), (b * t).cos(), (c * t).sin())
        };
        let mut x: Vec<DVec3> = (state.x.iter().enumerate())
            .map(|(i, &p)| p + 0.01 * wobble(i, 1.3, 0.7, 2.1))
            .collect();
        let v: Vec<DVec3> = (0..model.len()).map(|i| wobble(i, 0.9, 0.3, 1.7)).collect();
        let s = model.springs().len() / 2;
        x[model.springs().b[s] as usize] = x[model.springs().a[s] as usize];
        (model, x, v)
    }

    /// A 13×11×17 cube (2431 particles, up to 9 chunks), perturbed.
    fn perturbed_cube() -> (Model, Vec<DVec3>, Vec<DVec3>) {
        perturbed_bodies(&[[13, 11, 17]])
    }

    /// Every spring's force by the scalar definition, `spring_force`.
    fn scalar_forces(model: &Model, x: &[DVec3], v: &[DVec3]) -> Vec<DVec3> {
        let s = model.springs();
        (0..s.len())
            .map(|k| {
                let (a, b) = (s.a[k] as usize, s.b[k] as usize);
                spring_force(
                    x[a],
                    x[b],
                    v[a],
                    v[b],
                    s.rest[k],
                    s.stiffness[k],
                    s.damping[k],
                )
            })
            .collect()
    }

    /// Per-particle sums by the scalar definition: `spring_force` per spring, `gather` per
    /// particle.
    fn reference(model: &Model, x: &[DVec3], v: &[DVec3]) -> Vec<DVec3> {
        let per_spring = scalar_forces(model, x, v);
        (0..model.len())
            .map(|i| gather(model.adjacency(), &per_spring, i))
            .collect()
    }

    fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
        v.iter()
            .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
            .collect()
    }

    /// Every spring kernel (uniform or per-spring parameters, vector or scalar path) computes
    /// the bits of `spring_force`, including no force for the crushed spring.
    #[test]
    fn kernels_are_spring_force_bit_for_bit() {
        let (model, x, v) = perturbed_cube();
        let s = model.springs();
        let expected = scalar_forces(&model, &x, &v);
        assert_eq!(expected[s.len() / 2], DVec3::ZERO);
        assert!(expected.iter().filter(|f| **f != DVec3::ZERO).count() == s.len() - 1);
        for kernel in [Kernel::new(s), Kernel::per_spring()] {
            let mut out = vec![DVec3::splat(f64::NAN); s.len()];
            kernel.compute(s, &x, &v, &mut out);
            assert_eq!(bits(&out), bits(&expected), "{kernel:?}");
        }
    }

    /// Sums of a pass over `model` at (x, v) by `route` (the stencil on the path of `isa`, if
    /// given, else on the widest the CPU runs), on `threads` threads.
    fn pass_sums(
        model: &Model,
        x: &[DVec3],
        v: &[DVec3],
        (route, isa): (RouteKind, Option<Isa>),
        threads: usize,
    ) -> Vec<DVec3> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool");
        pool.install(|| {
            let mut plan = Plan::with_route(model, route);
            assert_eq!(plan.route(), route);
            if let (Route::Stencil { stencils, .. }, Some(isa)) = (&mut plan.route, isa) {
                stencils.iter_mut().for_each(|s| s.with_isa(isa));
            }
            let n = model.len();
            let (mut sums, mut seen) = (vec![DVec3::NAN; n], vec![DVec3::NAN; n]);
            let bad = pass(
                &mut plan,
                Kernel::new(model.springs()),
                model,
                (x, v),
                (&mut sums[..], &mut seen[..]),
                |i, f, (sum, at)| {
                    (*sum, *at) = (f, x[i]);
                    true
                },
            );
            assert_eq!(bad, None);
            assert_eq!(bits(&seen), bits(x), "every particle updated once");
            sums
        })
    }

    /// Every route (the stencil and the fused sweep for models of lattices, the plain route for
    /// any) hands every particle the bits of the scalar gather, for any number of threads and
    /// so of chunks.
    #[test]
    fn pass_sums_are_the_gather_for_any_thread_count() {
        let (forward, x, v) = perturbed_cube();
        assert_eq!(Plan::new(&forward).route(), RouteKind::Stencil);
        // The same springs with every third one reversed: no longer forward.
        let mut plain = forward.clone();
        let s = plain.springs_mut();
        for k in (0..s.len()).step_by(3) {
            (s.a[k], s.b[k]) = (s.b[k], s.a[k]);
        }
        assert_eq!(Plan::new(&plain).route(), RouteKind::Gather);
        let cases = [
            (&forward, RouteKind::Stencil),
            (&forward, RouteKind::Sweep),
            (&forward, RouteKind::Gather),
            (&plain, RouteKind::Gather),
        ];
        for (model, route) in cases {
            let expected = bits(&reference(model, &x, &v));
            for threads in [1, 2, 3, 4, 7] {
                let got = pass_sums(model, &x, &v, (route, None), threads);
                assert_eq!(bits(&got), expected, "{route:?}, {threads} threads");
            }
        }
    }

    /// The stencil (each of its paths that the CPU runs: scalar, AVX2, AVX-512) equals the
    /// scalar definition on lattices two and three particles wide along each axis (where
    /// bending springs are missing or single), on several bodies at once, and on a slab of
    /// several windows of planes, for 1 to 7 threads.
    #[test]
    fn the_stencil_is_the_gather_on_thin_and_several_lattices() {
        let shapes: [&[[u32; 3]]; 6] = [
            &[[3, 4, 29]],
            &[[2, 2, 2]],
            &[[3, 2, 5], [2, 3, 4]],
            &[[5, 3, 2], [2, 7, 3], [4, 4, 4]],
            &[[9, 2, 6]],
            &[[6, 5, 12], [3, 3, 3]],
        ];
        // A path the CPU lacks is skipped: it cannot run here.
        let isas = [Isa::Scalar, Isa::Avx2, Isa::Avx512];
        let isas: Vec<Isa> = isas.into_iter().filter(|isa| isa.runs()).collect();
        eprintln!("stencil paths tested: {isas:?}");
        for resolutions in shapes {
            let (model, x, v) = perturbed_bodies(resolutions);
            assert_eq!(model.lattices().len(), resolutions.len());
            let expected = bits(&reference(&model, &x, &v));
            for threads in 1..=7 {
                for &isa in &isas {
                    let route = (RouteKind::Stencil, Some(isa));
                    let got = pass_sums(&model, &x, &v, route, threads);
                    let what = format!("{resolutions:?}, {isa:?}, {threads} threads");
                    assert_eq!(bits(&got), expected, "{what}");
                }
            }
        }
    }

    /// Mesh bodies' masked lattices on the stencil (each path the CPU runs for them: scalar,
    /// AVX2) equal the scalar definition: rows of several runs (the torus's hole, the star's
    /// points), rows and planes without particles (three cubes apart in one mesh: empty planes
    /// between them, slabs of one cube or of none), next to a cuboid, for 1 to 7 threads.
    #[test]
    fn the_stencil_is_the_gather_on_mesh_bodies() {
        let mesh = |name: &str, file: &str, cell: f64, x: f64, rotation: [f64; 3]| {
            format!(
                "[[body]]\nname = \"{name}\"\nkind = \"mesh\"\nfile = \"{file}\"\ncell = {cell}\n\
                 center = [{x}, 1.0, 0.0]\nrotation = {rotation:?}\nmass = 3.0\n\
                 structural = {{ stiffness = 2000.0, damping = 5.0 }}\n\
                 shear = {{ stiffness = 1500.0, damping = 4.0 }}\n\
                 bending = {{ stiffness = 700.0, damping = 3.0 }}\n"
            )
        };
        let cuboid = "[[body]]\nname = \"c\"\nkind = \"cuboid\"\ncenter = [3.0, 1.0, 0.0]\n\
                      size = [0.5, 0.4, 0.3]\nresolution = [5, 4, 3]\nmass = 2.0\n\
                      structural = { stiffness = 900.0, damping = 2.0 }\n";
        let bodies = [
            mesh("torus", "torus.obj", 0.05, 0.0, [0.0, 0.0, 0.0]),
            mesh("torus", "torus.obj", 0.04, 0.0, [30.0, 20.0, 10.0])
                + &mesh("star", "star.obj", 0.06, 1.5, [10.0, 0.0, 70.0])
                + cuboid,
        ];
        // Three 0.3 m cubes, 0.3 m apart along z, as one mesh.
        let dir = tempfile::tempdir().expect("a temporary directory");
        let mut cubes = TriangleMesh::cube(DVec3::ZERO, 0.3);
        for lo in [DVec3::new(0.0, 0.05, 0.6), DVec3::new(0.0, 0.1, 1.2)] {
            let cube = TriangleMesh::cube(lo, 0.3);
            let first = cubes.vertices.len() as u32;
            cubes.vertices.extend(cube.vertices);
            (cubes.triangles).extend(cube.triangles.iter().map(|t| t.map(|v| v + first)));
        }
        let obj = cubes.to_obj("three cubes apart");
        std::fs::write(dir.path().join("cubes.obj"), obj).expect("written");
        let cubes = mesh("cubes", "cubes.obj", 0.05, 0.0, [0.0, 0.0, 10.0]);
        let isas = [Isa::Scalar, Isa::Avx2];
        let isas: Vec<Isa> = isas.into_iter().filter(|isa| isa.runs()).collect();
        let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        let cases = bodies
            .iter()
            .map(|text| (scenes.as_path(), text))
            .chain([(dir.path(), &cubes)]);
        for (dir, text) in cases {
            let (model, x, v) = perturbed_in(dir, text);
            assert!(model.lattices().iter().any(|l| l.mask.is_some()));
            if text == &cubes {
                let stencil = Stencil::new(&model.lattices()[0]);
                let empty = |k: usize| stencil.plane_start(k) == stencil.plane_start(k + 1);
                assert!((0..stencil.planes()).any(empty), "planes without particles");
            }
            assert_eq!(Plan::new(&model).route(), RouteKind::Stencil);
            let expected = bits(&reference(&model, &x, &v));
            for threads in 1..=7 {
                for &isa in &isas {
                    let route = (RouteKind::Stencil, Some(isa));
                    let got = pass_sums(&model, &x, &v, route, threads);
                    let what = format!("{} particles, {isa:?}, {threads} threads", model.len());
                    assert_eq!(bits(&got), expected, "{what}");
                }
            }
        }
    }
}
