//! Implicit Euler on the GPU: the host side of `shaders/system.wgsl`, `shaders/cg.wgsl` and
//! `shaders/implicit_euler.wgsl`, the twin of `softbody_cpu::integrators::implicit_euler`.
//!
//! # A step
//!
//! | submission | dispatches | read back |
//! |---|---|---|
//! | first | assemble (springs, particles) → candidates (terrain) → round → batch | scalars, changed |
//! | while CG runs | batch | scalars, changed |
//! | next round (active set changed) | round → batch | scalars, changed |
//! | last | finish → `check_finite` | nothing (the status at the end of `advance`) |
//!
//! where a round is `implicit_constrain` → `cg_start` → A Δv → `cg_residual` → `cg_begin`, and a
//! batch is a run of CG iterations (A c → `cg_curvature` → `cg_alpha` → `cg_advance` →
//! `cg_beta` → `cg_direction`; the first batch of a solve as many as the last solve took plus 2,
//! later ones [`ITERATIONS_PER_BATCH`]) followed, with terrain, by the active-set update
//! (A Δv → `implicit_active_set`). The iterations and the update are dispatched indirectly from
//! the argument slots the scalar kernels rewrite (`shaders/cg.wgsl`): iterations past
//! convergence are empty dispatches, and the update runs once, in the batch where the solve
//! ended. So a solve costs one submission and read-back of 68 bytes (the [`CgScalars`] and the
//! active set's `changed` word) when it takes no more iterations than the last one (plus 2), one
//! more per 16 iterations beyond, and a step at least one.
//!
//! The per-spring kernels (`assemble_springs`, `apply_springs`) run once per spring chunk
//! (`crate::solver`, "Spring chunks"), each with its chunk's springs, blocks and per-spring
//! vectors bound; the indirect ones all read the largest chunk's grid from the `SPRINGS` slot.
//! The gathers (`assemble_particles`, `apply_particles`) bind every chunk.
//!
//! The CG stopping rule is the CPU's (relative preconditioned residual, round-off growth, cap),
//! with the tolerance [`CG_TOLERANCE_F32`]: the CPU's 1e-8 is below what f32 resolves.

use softbody_scene::Statistics;
use softbody_scene::implicit::{ACTIVE_SET_ROUNDS, CG_MAX_ITERATIONS, Constraint};
use wgpu::util::DeviceExt;

use crate::layout::{CG_DISPATCH_WORDS, CandidateGpu, CgScalars, SpringBlockGpu, dispatch_slot};
use crate::shaders::{Access, BLOCK_CHUNK_BINDING, PER_SPRING_CHUNK_BINDING, Stage};
use crate::solver::{Grid, SpringChunks};

/// CG's relative tolerance on the GPU (preconditioned residual norm, as the CPU's
/// `CG_TOLERANCE`, which is 1e-8): f32 resolves about 6e-8 relative per operation, and the
/// recursively updated residual of an f32 CG drifts from the true one by about that times the
/// condition number, so 1e-5 is as far as a solve can usefully go; it is reached in a few dozen
/// iterations on the test scenes (see the adapter tests for the measured residuals).
pub const CG_TOLERANCE_F32: f32 = 1e-5;

/// CG iterations per batch (one submission and read-back of the scalars each) after a solve's
/// first, which is sized from the last solve's count (plus 2, between 4 and 4 × this).
pub const ITERATIONS_PER_BATCH: u32 = 16;

/// The first batch of a solve has the last solve's iterations plus this many (and at least 4):
/// consecutive solves take similar counts, so most solves need one submission, and few empty
/// dispatches (which software adapters do not get for free) are encoded.
const BATCH_MARGIN: u32 = 2;

/// Bytes of a `vec4<f32>`.
const VEC4: u64 = 16;

/// The buffers the implicit path shares with the rest of the solver.
pub(crate) struct Shared<'a> {
    pub params: &'a wgpu::Buffer,
    pub x: &'a wgpu::Buffer,
    pub v: &'a wgpu::Buffer,
    pub mass: &'a wgpu::Buffer,
    /// One buffer per spring chunk.
    pub springs: &'a [wgpu::Buffer],
    pub adjacency: &'a wgpu::Buffer,
    /// One buffer per spring chunk.
    pub per_spring: &'a [wgpu::Buffer],
    pub terrain_layout: &'a wgpu::BindGroupLayout,
    pub terrain: &'a wgpu::BindGroup,
    pub chunks: &'a SpringChunks,
}

/// A pipeline with its bind groups: one, or for a per-spring kernel one per spring chunk.
struct Bound {
    pipeline: wgpu::ComputePipeline,
    groups: Vec<wgpu::BindGroup>,
}

/// How a kernel is dispatched.
#[derive(Clone, Copy)]
enum Run {
    Direct(Grid),
    /// From the slot at this byte offset of the dispatch buffer.
    Indirect(u64),
}

struct Kernels {
    assemble_springs: Bound,
    assemble_particles: Bound,
    /// A Δv (into q).
    apply_springs_dv: Bound,
    apply_particles_dv: Bound,
    /// A c (into q).
    apply_springs_c: Bound,
    apply_particles_c: Bound,
    cg_start: Bound,
    cg_residual: Bound,
    cg_begin: Bound,
    cg_curvature: Bound,
    cg_alpha: Bound,
    cg_advance: Bound,
    cg_beta: Bound,
    cg_direction: Bound,
    candidates: Bound,
    constrain: Bound,
    active_set: Bound,
    finish: Bound,
}

/// Implicit Euler's buffers, kernels and counters.
pub(crate) struct Implicit {
    pub b: wgpu::Buffer,
    pub rhs: wgpu::Buffer,
    pub z: wgpu::Buffer,
    pub dv: wgpu::Buffer,
    pub q: wgpu::Buffer,
    pub diag: wgpu::Buffer,
    pub constraints: wgpu::Buffer,
    pub scalars: wgpu::Buffer,
    pub changed: wgpu::Buffer,
    dispatch: wgpu::Buffer,
    /// Filled by the solver's candidates kernel only with terrain.
    pub has_terrain: bool,
    terrain: wgpu::BindGroup,
    kernels: Kernels,
    particle_grid: Grid,
    /// Each spring chunk's grid.
    spring_grids: Vec<Grid>,
    /// Iterations of the last solve.
    last_iterations: u32,
    /// Counters over the run.
    pub statistics: Statistics,
}

/// What one read-back after a batch says.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Progress {
    pub scalars: CgScalars,
    pub changed: bool,
}

impl Progress {
    /// Bytes read back: the scalars, then the changed word.
    pub const BYTES: u64 = std::mem::size_of::<CgScalars>() as u64 + 4;

    pub fn parse(bytes: &[u8]) -> Progress {
        let size = std::mem::size_of::<CgScalars>();
        Progress {
            scalars: bytemuck::pod_read_unaligned(&bytes[..size]),
            changed: bytemuck::pod_read_unaligned::<u32>(&bytes[size..size + 4]) != 0,
        }
    }
}

/// The (binding, access) table of a layout entry list.
pub(crate) fn layout_entries(bindings: &[(u32, Access)]) -> Vec<wgpu::BindGroupLayoutEntry> {
    bindings
        .iter()
        .map(|&(binding, access)| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: match access {
                    Access::Uniform | Access::DynamicUniform => wgpu::BufferBindingType::Uniform,
                    Access::Read => wgpu::BufferBindingType::Storage { read_only: true },
                    Access::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                },
                has_dynamic_offset: access == Access::DynamicUniform,
                min_binding_size: None,
            },
            count: None,
        })
        .collect()
}

/// The constraint as `constraints[i]` holds it: (n, kind) with kind 0 free, 1 normal, 2 fixed.
pub(crate) fn constraint_vec4(c: Constraint) -> [f32; 4] {
    match c {
        Constraint::Free => [0.0; 4],
        Constraint::Normal(n) => {
            let n = n.as_vec3();
            [n.x, n.y, n.z, 1.0]
        }
        Constraint::Fixed => [0.0, 0.0, 0.0, 2.0],
    }
}

impl Implicit {
    /// Buffers and kernels for `model`, sharing the solver's state and model buffers.
    pub fn new(
        device: &wgpu::Device,
        shared: &Shared<'_>,
        n: u64,
        has_terrain: bool,
        particle_grid: Grid,
    ) -> Implicit {
        let chunks = shared.chunks;
        let chunking = chunks.chunking;
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        let empty = |label: &str, bytes: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.max(VEC4),
                usage: storage,
                mapped_at_creation: false,
            })
        };
        let init = |label: &str, contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let vectors = n * VEC4;
        let b = empty("b", vectors);
        let rhs = empty("rhs", vectors);
        let z = empty("z", vectors);
        let dv = empty("dv", vectors);
        let q = empty("q", vectors);
        let r = empty("r", vectors);
        let c = empty("c", vectors);
        let diag = empty("diag", 2 * vectors);
        let constraints = empty("constraints", vectors);
        let blocks: Vec<wgpu::Buffer> = chunks
            .ranges
            .iter()
            .map(|&(_, count)| {
                empty(
                    "blocks",
                    count * std::mem::size_of::<SpringBlockGpu>() as u64,
                )
            })
            .collect();
        // Zeroed: no particle was touching before the first step.
        let candidates = empty("candidates", n * std::mem::size_of::<CandidateGpu>() as u64);
        let partials = empty("cg partials", particle_grid.groups().max(1) * 8);
        let settings = CgScalars {
            tolerance: CG_TOLERANCE_F32,
            max_iterations: CG_MAX_ITERATIONS,
            n_partials: particle_grid.groups() as u32,
            particle_grid: [particle_grid.x, particle_grid.y],
            spring_grid: [chunks.largest_grid().x, chunks.largest_grid().y],
            ..CgScalars::default()
        };
        let scalars = init("cg scalars", bytemuck::bytes_of(&settings), storage);
        let dispatch = init(
            "cg dispatch",
            &[0u8; CG_DISPATCH_WORDS * 4],
            storage | wgpu::BufferUsages::INDIRECT,
        );
        let changed = empty("changed", 4);

        // A kernel with one bind group per list of (binding, resource) besides params.
        let (s_springs, s_per_spring) = (shared.springs, shared.per_spring);
        let kernel_groups = |stage: Stage,
                             entry: &str,
                             lists: Vec<Vec<(u32, wgpu::BindingResource)>>|
         -> Bound {
            let k = stage.kernel(entry);
            let mut table = stage.kernel_bindings(&k);
            table.extend(stage.chunk_bindings(entry, chunking));
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(k.entry),
                entries: &layout_entries(&table),
            });
            let mut layouts = vec![Some(&layout)];
            if k.terrain {
                layouts.push(Some(shared.terrain_layout));
            }
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(k.entry),
                bind_group_layouts: &layouts,
                immediate_size: 0,
            });
            // One module per kernel keeps the code simple; the drivers cache the compilation.
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(stage.file()),
                source: wgpu::ShaderSource::Wgsl(stage.source_chunked(chunking).into()),
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(k.entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(k.entry),
                compilation_options: Default::default(),
                cache: None,
            });
            let groups = lists
                .into_iter()
                .map(|list| {
                    let entries: Vec<wgpu::BindGroupEntry> =
                        std::iter::once((0, shared.params.as_entire_binding()))
                            .chain(list)
                            .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
                            .collect();
                    device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some(k.entry),
                        layout: &layout,
                        entries: &entries,
                    })
                })
                .collect();
            Bound { pipeline, groups }
        };
        let kernel = |stage: Stage, entry: &str, buffers: &[(u32, &wgpu::Buffer)]| -> Bound {
            let list = buffers
                .iter()
                .map(|&(binding, buffer)| (binding, buffer.as_entire_binding()))
                .collect();
            kernel_groups(stage, entry, vec![list])
        };
        // A per-spring kernel (system.wgsl): `buffers` lists the bindings shared by all chunks;
        // each chunk's group has its springs (6), blocks (7), per-spring vectors (8) and
        // `SpringChunk` uniform (13).
        let spring_kernel = |entry: &str, buffers: &[(u32, &wgpu::Buffer)]| -> Bound {
            let lists = (0..chunks.len())
                .map(|c| {
                    let mut list: Vec<(u32, wgpu::BindingResource)> = buffers
                        .iter()
                        .map(|&(binding, buffer)| (binding, buffer.as_entire_binding()))
                        .collect();
                    list.extend([
                        (6, s_springs[c].as_entire_binding()),
                        (7, blocks[c].as_entire_binding()),
                        (8, s_per_spring[c].as_entire_binding()),
                        (13, chunks.uniform(c)),
                    ]);
                    list.sort_by_key(|&(binding, _)| binding);
                    list
                })
                .collect();
            kernel_groups(Stage::System, entry, lists)
        };
        // A gathering kernel: the per-spring vectors' (and with `blocks`, the blocks') chunks
        // past the first at their extra bindings.
        let gather_kernel = |entry: &str, buffers: &[(u32, &wgpu::Buffer)], with_blocks: bool| {
            let mut list: Vec<(u32, wgpu::BindingResource)> = buffers
                .iter()
                .map(|&(binding, buffer)| (binding, buffer.as_entire_binding()))
                .collect();
            let extra = shared.per_spring.iter().zip(&blocks).skip(1);
            for (at, (per_spring, block)) in (0u32..).zip(extra) {
                list.push((
                    PER_SPRING_CHUNK_BINDING + at,
                    per_spring.as_entire_binding(),
                ));
                if with_blocks {
                    list.push((BLOCK_CHUNK_BINDING + at, block.as_entire_binding()));
                }
            }
            list.sort_by_key(|&(binding, _)| binding);
            kernel_groups(Stage::System, entry, vec![list])
        };
        let s = shared;
        let cg = Stage::Cg;
        let ie = Stage::ImplicitEuler;
        let apply_springs = |p: &wgpu::Buffer| spring_kernel("apply_springs", &[(9, p)]);
        let apply_particles = |p: &wgpu::Buffer| {
            gather_kernel(
                "apply_particles",
                &[
                    (3, &s.per_spring[0]),
                    (4, s.adjacency),
                    (9, p),
                    (10, &q),
                    (12, &diag),
                ],
                false,
            )
        };
        let scalar = |entry: &str| {
            kernel(
                cg,
                entry,
                &[(9, &partials), (10, &scalars), (11, &dispatch)],
            )
        };
        let kernels = Kernels {
            assemble_springs: spring_kernel("assemble_springs", &[(1, s.x), (2, s.v)]),
            assemble_particles: gather_kernel(
                "assemble_particles",
                &[
                    (2, s.v),
                    (3, &s.per_spring[0]),
                    (4, s.adjacency),
                    (5, s.mass),
                    (7, &blocks[0]),
                    (11, &b),
                    (12, &diag),
                ],
                true,
            ),
            apply_springs_dv: apply_springs(&dv),
            apply_particles_dv: apply_particles(&dv),
            apply_springs_c: apply_springs(&c),
            apply_particles_c: apply_particles(&c),
            cg_start: kernel(cg, "cg_start", &[(1, &constraints), (2, &z), (3, &dv)]),
            cg_residual: kernel(
                cg,
                "cg_residual",
                &[
                    (1, &constraints),
                    (4, &rhs),
                    (5, &q),
                    (6, &r),
                    (7, &c),
                    (8, &diag),
                    (9, &partials),
                ],
            ),
            cg_begin: scalar("cg_begin"),
            cg_curvature: kernel(
                cg,
                "cg_curvature",
                &[(1, &constraints), (5, &q), (7, &c), (9, &partials)],
            ),
            cg_alpha: scalar("cg_alpha"),
            cg_advance: kernel(
                cg,
                "cg_advance",
                &[
                    (3, &dv),
                    (5, &q),
                    (6, &r),
                    (7, &c),
                    (8, &diag),
                    (9, &partials),
                    (10, &scalars),
                ],
            ),
            cg_beta: scalar("cg_beta"),
            cg_direction: kernel(
                cg,
                "cg_direction",
                &[
                    (1, &constraints),
                    (6, &r),
                    (7, &c),
                    (8, &diag),
                    (10, &scalars),
                ],
            ),
            candidates: kernel(
                ie,
                "implicit_candidates",
                &[(1, s.x), (2, s.v), (3, s.mass), (5, &b), (8, &candidates)],
            ),
            constrain: kernel(
                ie,
                "implicit_constrain",
                &[
                    (2, s.v),
                    (3, s.mass),
                    (4, &rhs),
                    (5, &b),
                    (8, &candidates),
                    (9, &constraints),
                    (10, &z),
                ],
            ),
            active_set: kernel(
                ie,
                "implicit_active_set",
                &[
                    (2, s.v),
                    (3, s.mass),
                    (4, &rhs),
                    (6, &dv),
                    (7, &q),
                    (8, &candidates),
                    (11, &changed),
                ],
            ),
            finish: kernel(ie, "implicit_finish", &[(1, s.x), (2, s.v), (6, &dv)]),
        };
        Implicit {
            b,
            rhs,
            z,
            dv,
            q,
            diag,
            constraints,
            scalars,
            changed,
            dispatch,
            has_terrain,
            terrain: shared.terrain.clone(),
            kernels,
            particle_grid,
            spring_grids: chunks.grids.clone(),
            last_iterations: ITERATIONS_PER_BATCH,
            statistics: Statistics::default(),
        }
    }

    /// Dispatches a one-group kernel.
    fn run(&self, pass: &mut wgpu::ComputePass<'_>, k: &Bound, how: Run, terrain: bool) {
        self.run_group(pass, &k.pipeline, &k.groups[0], how, terrain);
    }

    /// Dispatches a per-spring kernel once per chunk: directly on each chunk's grid, or
    /// indirectly from the slot at byte `slot` of the dispatch buffer.
    fn run_springs(&self, pass: &mut wgpu::ComputePass<'_>, k: &Bound, slot: Option<u64>) {
        for (group, &grid) in k.groups.iter().zip(&self.spring_grids) {
            let how = slot.map_or(Run::Direct(grid), Run::Indirect);
            self.run_group(pass, &k.pipeline, group, how, false);
        }
    }

    fn run_group(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        pipeline: &wgpu::ComputePipeline,
        group: &wgpu::BindGroup,
        how: Run,
        terrain: bool,
    ) {
        if let Run::Direct(grid) = how
            && grid.groups() == 0
        {
            return;
        }
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        if terrain {
            pass.set_bind_group(1, &self.terrain, &[]);
        }
        match how {
            Run::Direct(grid) => pass.dispatch_workgroups(grid.x, grid.y, 1),
            Run::Indirect(offset) => pass.dispatch_workgroups_indirect(&self.dispatch, offset),
        }
    }

    /// Linearises at the current (x, v): b, the spring blocks and the preconditioner; with
    /// terrain, the contact candidates.
    pub fn encode_assemble(&self, pass: &mut wgpu::ComputePass<'_>) {
        let k = &self.kernels;
        let p = Run::Direct(self.particle_grid);
        self.run_springs(pass, &k.assemble_springs, None);
        self.run(pass, &k.assemble_particles, p, false);
        if self.has_terrain {
            self.run(pass, &k.candidates, p, true);
        }
    }

    /// A solve's start: constraints, z and rhs from the candidates (unless `constrain` is
    /// false: the tests write them), the warm start, the residual and the scalars.
    pub fn encode_round(&self, pass: &mut wgpu::ComputePass<'_>, constrain: bool) {
        let k = &self.kernels;
        let p = Run::Direct(self.particle_grid);
        if constrain {
            self.run(pass, &k.constrain, p, false);
        }
        self.run(pass, &k.cg_start, p, false);
        self.run_springs(pass, &k.apply_springs_dv, None);
        self.run(pass, &k.apply_particles_dv, p, false);
        self.run(pass, &k.cg_residual, p, false);
        self.run(pass, &k.cg_begin, Run::Direct(Grid { x: 1, y: 1 }), false);
    }

    /// Iterations for the first batch of a solve (`first`) or a later one.
    pub fn batch(&self, first: bool) -> u32 {
        if first {
            (self.last_iterations + BATCH_MARGIN).clamp(4, 4 * ITERATIONS_PER_BATCH)
        } else {
            ITERATIONS_PER_BATCH
        }
    }

    /// `iterations` CG iterations (empty once the solve is done), then, with terrain, the
    /// active-set update (empty until the solve is done).
    pub fn encode_batch(&self, pass: &mut wgpu::ComputePass<'_>, iterations: u32) {
        let k = &self.kernels;
        let particles = Run::Indirect(dispatch_slot::PARTICLES);
        let springs = Some(dispatch_slot::SPRINGS);
        // Direct: they write the indirect arguments (and return at once when done).
        let scalar = Run::Direct(Grid { x: 1, y: 1 });
        for _ in 0..iterations {
            self.run_springs(pass, &k.apply_springs_c, springs);
            self.run(pass, &k.apply_particles_c, particles, false);
            self.run(pass, &k.cg_curvature, particles, false);
            self.run(pass, &k.cg_alpha, scalar, false);
            self.run(pass, &k.cg_advance, particles, false);
            self.run(pass, &k.cg_beta, scalar, false);
            self.run(pass, &k.cg_direction, particles, false);
        }
        if self.has_terrain {
            let particles = Run::Indirect(dispatch_slot::FINISHED_PARTICLES);
            let springs = Some(dispatch_slot::FINISHED_SPRINGS);
            self.run_springs(pass, &k.apply_springs_dv, springs);
            self.run(pass, &k.apply_particles_dv, particles, false);
            self.run(pass, &k.active_set, particles, false);
        }
    }

    /// v ← v + Δv, x ← x + h v.
    pub fn encode_finish(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.run(
            pass,
            &self.kernels.finish,
            Run::Direct(self.particle_grid),
            false,
        );
    }

    /// A Δv into q (for the system twin test, with Δv uploaded as p).
    pub fn encode_apply_dv(&self, pass: &mut wgpu::ComputePass<'_>) {
        let k = &self.kernels;
        self.run_springs(pass, &k.apply_springs_dv, None);
        self.run(
            pass,
            &k.apply_particles_dv,
            Run::Direct(self.particle_grid),
            false,
        );
    }

    /// Counts a finished solve.
    pub fn record(&mut self, scalars: &CgScalars) {
        let st = &mut self.statistics;
        st.cg_iterations += u64::from(scalars.iterations);
        st.cg_solves += 1;
        st.cg_max_residual = st.cg_max_residual.max(scalars.relative_residual());
        self.last_iterations = scalars.iterations;
    }
}

/// Solves per step at most (the CPU's).
pub(crate) const ROUNDS: u32 = ACTIVE_SET_ROUNDS;
