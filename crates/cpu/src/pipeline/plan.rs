//! A pass's plan: which route it takes (stencil, sweep or gather), the chunk boundaries for
//! the thread count, and each route's scratch.

use std::sync::Mutex;

use glam::DVec3;
use softbody_scene::{Model, Springs};

use super::MIN_CHUNK;
use crate::spring_forces::stencil::{Slab, Stencil};
use crate::spring_forces::{Isa, Kernel, Sum};

/// How a model's particles are split into chunks, made once per thread count, and the scratch
/// of the passes.
#[derive(Debug, Clone)]
pub(crate) struct Plan {
    /// Rayon threads the plan was made for.
    threads: usize,
    /// Chunk c is particles `bounds[c]..bounds[c + 1]`.
    pub(super) bounds: Vec<usize>,
    pub(super) route: Route,
}

/// How a pass finds each particle's springs.
#[derive(Debug)]
pub(super) enum Route {
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
pub(super) struct Forward {
    /// `a_start[p]..a_start[p + 1]` are the springs starting at p.
    pub(super) a_start: Vec<u32>,
    /// Per chunk, its first tail particle (its end when no spring reaches beyond it).
    pub(super) tail: Vec<usize>,
    /// Chunk c's tail springs' forces are `tail_forces[tail_offset[c]..tail_offset[c + 1]]`.
    pub(super) tail_offset: Vec<usize>,
    /// Per chunk, the largest second end among its tail springs (0 when none).
    pub(super) tail_reach: Vec<usize>,
    /// Forces of the tail springs, chunk after chunk.
    pub(super) tail_forces: Vec<DVec3>,
    /// Each particle's running sum of spring forces.
    pub(super) sums: Vec<Sum>,
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
