//! The GPU solver: buffers, pipelines, the per-step command sequence, and the read-backs.
//!
//! # A step
//!
//! Every step is a fixed sequence of dispatches in one compute pass (wgpu orders consecutive
//! dispatches: each is its own usage scope, so each sees what the previous wrote):
//!
//! | integrator | dispatches |
//! |---|---|
//! | explicit / symplectic Euler | forces(x, v) → update |
//! | midpoint | forces(x, v) → `midpoint_stage` → forces(stage) → `midpoint_update` |
//! | RK4 | forces(x, v) → `rk4_first` → forces(stage) → `rk4_second` → forces(stage) → `rk4_third` → forces(stage) → `rk4_last` |
//! | implicit Euler | assemble → candidates → (constrain → CG → active set)×rounds → finish: see [`crate::implicit`] |
//!
//! where forces(·) is `spring_forces` then `accelerations`, followed by `collision_response` (when
//! there is terrain) and `check_finite`. [`STEPS_PER_SUBMISSION`] steps go into one command
//! buffer; after each submission the host reads back the 12-byte status only. Implicit Euler
//! cannot know its CG iterations and active-set rounds in advance: it synchronises at least once
//! per step on a 68-byte read-back, and reads the status after [`STEPS_PER_SUBMISSION`] steps.
//!
//! # Spring chunks
//!
//! Per-spring arrays (the springs, the per-spring vectors, implicit Euler's blocks) grow with
//! the springs, about 13 per particle: a 100³ cube's 15.7 M springs need 314 MB of spring
//! records, more than one storage binding holds on many adapters (`max_storage_buffer_binding_size`
//! is 128 MiB on Mesa and a common default). So each is kept as `SpringChunks`: K buffers of
//! 2^k springs (the last one shorter), with 2^k the largest power of two whose widest per-spring
//! element (20 bytes, 32 with implicit Euler's blocks) fits one binding and one buffer
//! (`min(max_storage_buffer_binding_size, max_buffer_size)`); a scene that fits has one chunk.
//! Every per-spring kernel is dispatched once per chunk, with a bind group of that chunk's
//! buffers and its [`SpringChunk`] uniform (first spring, count, first energy partial). The
//! per-particle gathers bind all K chunks of what they gather and pick spring s's chunk as
//! `s >> k` (accessors generated per K, see [`crate::shaders::Chunking`]): the same reads in the
//! same order, so a chunked run is bit-identical to an unchunked one. K is bounded by the
//! storage buffers one kernel may bind (`max_storage_buffers_per_shader_stage`: the force
//! kernel binds 7 + K, implicit Euler's assembly 5 + 2K) and [`MAX_SPRING_CHUNKS`]; past that,
//! for the per-particle arrays (whole: 8.4 M particles per 128 MiB of `vec4`) and for the CSR
//! adjacency (whole: n + 1 + 2m words, 16.7 M springs per 128 MiB), the scene is refused with
//! the limit and the figures.
//!
//! # Instability
//!
//! `check_finite` records, on the device, the first step of the submission with a non-finite
//! value and the lowest particle holding one (see `shaders/check_finite.wgsl`). The step number
//! is known when the step is encoded: a constant uniform table holds 1, 2, …,
//! [`STEPS_PER_SUBMISSION`], one per aligned slot, and each step's check binds its slot with a
//! dynamic offset, which costs neither a dispatch nor a host write per step. The host resets the
//! status before each submission and reads it after it: an instability is reported with the
//! exact step, time and particle the CPU would report. The steps after it within the same
//! submission still run (the GPU cannot stop mid-submission), so after a
//! [`StepError::Unstable`] the state is that of the end of the submission, not of the failing
//! step; [`Solver::steps_taken`] is the failing step.
//!
//! # Read-backs
//!
//! Only on demand: [`Solver::state`] copies x and v into one mappable buffer (cached until the
//! next `advance`), [`Solver::energies`] runs the reductions of `energy.wgsl` and reads the
//! per-workgroup partial sums, which the host adds in order, in f64.

use std::sync::mpsc;

use glam::{DVec3, Vec3};
use softbody_scene::{
    Energies, Instability, Integrator, Model, Solver, State, Statistics, StepError,
};
use wgpu::util::DeviceExt;

use crate::device::Gpu;
use crate::implicit::{self, Implicit, Progress};
use crate::layout::{
    CandidateGpu, NONE, Params, SpringBlockGpu, SpringChunk, SpringGpu, Status, StepIndex,
};
use crate::shaders::{
    Access, BLOCK_CHUNK_BINDING, Chunking, MAX_SPRING_CHUNKS, PER_SPRING_CHUNK_BINDING, Stage,
    TERRAIN_BINDINGS,
};
use crate::terrain;
use crate::{GpuError, WORKGROUP_SIZE};

/// Steps encoded into one command buffer: enough to amortise a submission and a status
/// read-back, few enough that an instability stops the run soon after it happens.
pub const STEPS_PER_SUBMISSION: u64 = 256;

/// Bytes of a `vec4<f32>`.
const VEC4: u64 = 16;

/// A dispatch grid: `x · y` workgroups of [`WORKGROUP_SIZE`] threads covering `threads` threads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    /// Workgroups along x (at most the per-dimension limit).
    pub x: u32,
    /// Rows of workgroups (1 unless more than the per-dimension limit are needed).
    pub y: u32,
}

impl Grid {
    /// The grid for `threads` threads, or `None` if it would need more than `max_dim` rows of
    /// `max_dim` workgroups.
    pub fn new(threads: u64, max_dim: u32) -> Option<Grid> {
        Grid::with_width(threads, max_dim, max_dim)
    }

    /// The grid for `threads` threads in rows of at most `width` workgroups, or `None` if it
    /// would need more than `max_rows` rows.
    pub fn with_width(threads: u64, width: u32, max_rows: u32) -> Option<Grid> {
        let groups = threads.div_ceil(WORKGROUP_SIZE);
        let width = u64::from(width.max(1));
        if groups <= width {
            return Some(Grid {
                x: groups as u32,
                y: if groups == 0 { 0 } else { 1 },
            });
        }
        let rows = groups.div_ceil(width);
        (rows <= u64::from(max_rows)).then_some(Grid {
            x: width as u32,
            y: rows as u32,
        })
    }

    /// Workgroups in all (a 2-D grid may have a few more than needed; they return at once).
    pub fn groups(self) -> u64 {
        u64::from(self.x) * u64::from(self.y)
    }
}

/// Settings for tests: narrower dispatch grids and smaller storage bindings than the adapter's,
/// so that small scenes take the paths of very large ones.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GpuOptions {
    /// Dispatch grids at most this many workgroups wide (instead of the per-dimension limit).
    pub grid_width: Option<u32>,
    /// Storage bindings of at most this many bytes (instead of the adapter's
    /// `max_storage_buffer_binding_size`, if lower): per-spring arrays are split accordingly.
    pub max_binding_size: Option<u64>,
}

/// How the per-spring arrays are split into chunks (see the module documentation).
pub(crate) struct SpringChunks {
    /// The count and the springs per chunk.
    pub chunking: Chunking,
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

/// Which state a force evaluation reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Input {
    /// (x, v).
    Main,
    /// The stage state (stage_x, stage_v) of midpoint and RK4.
    Stage,
}

struct Buffers {
    params: wgpu::Buffer,
    x: wgpu::Buffer,
    v: wgpu::Buffer,
    a: wgpu::Buffer,
    /// Per-spring vectors, one buffer per chunk.
    per_spring: Vec<wgpu::Buffer>,
    /// Spring records, one buffer per chunk.
    springs: Vec<wgpu::Buffer>,
    adjacency: wgpu::Buffer,
    mass: wgpu::Buffer,
    stage_x: Option<wgpu::Buffer>,
    stage_v: Option<wgpu::Buffer>,
    sum_x: Option<wgpu::Buffer>,
    sum_v: Option<wgpu::Buffer>,
    status: wgpu::Buffer,
    /// [`StepIndex`] 1..=[`STEPS_PER_SUBMISSION`], one per `step_stride` bytes.
    step_indices: wgpu::Buffer,
    particle_partials: wgpu::Buffer,
    spring_partials: wgpu::Buffer,
    surfaces: wgpu::Buffer,
    terrain_data: wgpu::Buffer,
    readback: wgpu::Buffer,
}

struct Pipelines {
    spring_forces: wgpu::ComputePipeline,
    accelerations: wgpu::ComputePipeline,
    /// The integrator's entry points, in [`Stage::entry_points`] order (none for implicit Euler,
    /// whose kernels [`Implicit`] holds).
    update: Vec<wgpu::ComputePipeline>,
    collision_response: wgpu::ComputePipeline,
    check_finite: wgpu::ComputePipeline,
    energy_particles: wgpu::ComputePipeline,
    energy_springs: wgpu::ComputePipeline,
}

struct BindGroups {
    /// Per input, one group per spring chunk.
    spring_forces: [Vec<wgpu::BindGroup>; 2],
    forces: [Option<wgpu::BindGroup>; 2],
    terrain: wgpu::BindGroup,
    update: Option<wgpu::BindGroup>,
    collision_response: wgpu::BindGroup,
    check_finite: wgpu::BindGroup,
    /// One per spring chunk (the particle energies use the first).
    energy: Vec<wgpu::BindGroup>,
}

/// The GPU backend: the model in device buffers, stepped by compute shaders in f32.
pub struct GpuSolver {
    model: Model,
    gpu: Gpu,
    buffers: Buffers,
    pipelines: Pipelines,
    groups: BindGroups,
    /// Implicit Euler's buffers and kernels.
    implicit: Option<Implicit>,
    particle_grid: Grid,
    chunks: SpringChunks,
    n_surfaces: u32,
    /// Bytes between consecutive [`StepIndex`] slots (the uniform offset alignment).
    step_stride: u64,
    /// Host copy of the state, valid while `state_fresh`.
    state: State,
    state_fresh: bool,
    steps: u64,
    /// The first device failure; every later call reports it again.
    failed: Option<String>,
}

/// A storage buffer the scene needs: what it holds, elements, bytes per element.
struct Need {
    what: &'static str,
    count: u64,
    stride: u64,
}

impl Need {
    fn bytes(&self) -> u64 {
        self.count.saturating_mul(self.stride)
    }
}

fn limit_error(
    adapter: &str,
    limit: &'static str,
    what: String,
    needed: String,
    available: String,
) -> GpuError {
    GpuError::Limit {
        adapter: adapter.to_owned(),
        limit,
        what,
        needed,
        available,
    }
}

/// Refuses a scene that exceeds the adapter's limits, naming the limit and the figures.
fn check_limits(
    limits: &wgpu::Limits,
    adapter: &str,
    needs: &[Need],
    readback_bytes: u64,
    threads: &[(&'static str, u64)],
) -> Result<(), GpuError> {
    // What every kernel needs whatever the scene: checked first, as they say the adapter cannot
    // run the solver at all.
    let fixed: [(&'static str, u64, u64, &str); 6] = [
        (
            "max_compute_invocations_per_workgroup",
            u64::from(limits.max_compute_invocations_per_workgroup),
            WORKGROUP_SIZE,
            "threads per workgroup",
        ),
        (
            "max_compute_workgroup_size_x",
            u64::from(limits.max_compute_workgroup_size_x),
            WORKGROUP_SIZE,
            "threads along x",
        ),
        (
            "max_compute_workgroup_storage_size",
            u64::from(limits.max_compute_workgroup_storage_size),
            WORKGROUP_SIZE * 8,
            "bytes of workgroup memory (the energy reduction)",
        ),
        (
            "max_storage_buffers_per_shader_stage",
            u64::from(limits.max_storage_buffers_per_shader_stage),
            8,
            "storage buffers (the force kernel)",
        ),
        (
            "max_bind_groups",
            u64::from(limits.max_bind_groups),
            2,
            "bind groups",
        ),
        (
            "max_bindings_per_bind_group",
            u64::from(limits.max_bindings_per_bind_group),
            // The limit bounds binding numbers, not counts: system.wgsl numbers up to 13.
            14,
            "binding numbers in one group (0 to 13)",
        ),
    ];
    for (limit, available, needed, unit) in fixed {
        if available < needed {
            return Err(limit_error(
                adapter,
                limit,
                "the solver's kernels".to_owned(),
                format!("{needed} {unit}"),
                format!("{available}"),
            ));
        }
    }
    for need in needs {
        let bytes = need.bytes();
        for (limit, available) in [
            (
                "max_storage_buffer_binding_size",
                limits.max_storage_buffer_binding_size,
            ),
            ("max_buffer_size", limits.max_buffer_size),
        ] {
            if bytes > available {
                return Err(limit_error(
                    adapter,
                    limit,
                    format!(
                        "the {} buffer ({} × {} bytes)",
                        need.what, need.count, need.stride
                    ),
                    format!("{bytes} bytes"),
                    format!("{available} bytes"),
                ));
            }
        }
    }
    if readback_bytes > limits.max_buffer_size {
        return Err(limit_error(
            adapter,
            "max_buffer_size",
            "the read-back buffer (positions and velocities)".to_owned(),
            format!("{readback_bytes} bytes"),
            format!("{} bytes", limits.max_buffer_size),
        ));
    }
    let max_dim = limits.max_compute_workgroups_per_dimension;
    for &(what, count) in threads {
        if Grid::new(count, max_dim).is_none() {
            return Err(limit_error(
                adapter,
                "max_compute_workgroups_per_dimension",
                format!("one thread per {what} ({count})"),
                format!(
                    "{} workgroups of {WORKGROUP_SIZE}",
                    count.div_ceil(WORKGROUP_SIZE)
                ),
                format!("{max_dim} × {max_dim} workgroups"),
            ));
        }
    }
    Ok(())
}

/// The bytes one per-spring chunk may have: the smaller of the binding and buffer limits, and
/// which limit that is.
fn chunk_cap(limits: &wgpu::Limits) -> (&'static str, u64) {
    let binding = limits.max_storage_buffer_binding_size;
    if binding <= limits.max_buffer_size {
        ("max_storage_buffer_binding_size", binding)
    } else {
        ("max_buffer_size", limits.max_buffer_size)
    }
}

/// How to split `springs` springs whose widest per-spring element has `stride` bytes (20, or
/// 32 with implicit Euler's blocks, `implicit`), or why they cannot be split on this adapter,
/// naming the limit and the figures.
fn check_chunks(
    limits: &wgpu::Limits,
    adapter: &str,
    springs: u64,
    stride: u64,
    implicit: bool,
) -> Result<Chunking, GpuError> {
    let (cap_limit, cap) = chunk_cap(limits);
    let Some(chunking) = plan_chunks(springs, stride, cap) else {
        return Err(limit_error(
            adapter,
            cap_limit,
            format!("a chunk of {WORKGROUP_SIZE} springs ({stride} bytes each)"),
            format!("{} bytes", WORKGROUP_SIZE * stride),
            format!("{cap} bytes"),
        ));
    };
    if chunking.count == 1 {
        return Ok(chunking);
    }
    let k = chunking.count;
    let what = || {
        format!(
            "{springs} springs ({stride} bytes each) in {k} chunks of {} (one per {cap}-byte              binding, the {cap_limit})",
            1u64 << chunking.shift
        )
    };
    if k > MAX_SPRING_CHUNKS {
        return Err(limit_error(
            adapter,
            cap_limit,
            what(),
            format!("{k} chunks"),
            format!("{cap} bytes per binding, for at most {MAX_SPRING_CHUNKS} chunks"),
        ));
    }
    // The force gather binds x, v, adjacency, mass, a, two terrain buffers and every chunk of
    // the per-spring vectors; implicit Euler's assembly v, adjacency, mass, b, diag and every
    // chunk of the vectors and of the blocks.
    let storage = if implicit {
        (7 + k).max(5 + 2 * k)
    } else {
        7 + k
    };
    if storage > limits.max_storage_buffers_per_shader_stage {
        return Err(limit_error(
            adapter,
            "max_storage_buffers_per_shader_stage",
            what(),
            format!("{storage} storage buffers in one kernel (the per-particle gather)"),
            format!("{}", limits.max_storage_buffers_per_shader_stage),
        ));
    }
    let first = if implicit {
        BLOCK_CHUNK_BINDING
    } else {
        PER_SPRING_CHUNK_BINDING
    };
    let bindings = first + k - 1;
    if bindings > limits.max_bindings_per_bind_group {
        return Err(limit_error(
            adapter,
            "max_bindings_per_bind_group",
            what(),
            format!("binding numbers up to {}", bindings - 1),
            format!("{}", limits.max_bindings_per_bind_group),
        ));
    }
    Ok(chunking)
}

fn vec4s(v: &[DVec3]) -> Vec<[f32; 4]> {
    v.iter()
        .map(|p| {
            let p = p.as_vec3();
            [p.x, p.y, p.z, 0.0]
        })
        .collect()
}

/// Bytes of at least one element: wgpu refuses to bind an empty buffer.
fn at_least(bytes: &[u8], element: usize) -> Vec<u8> {
    if bytes.is_empty() {
        vec![0; element]
    } else {
        bytes.to_vec()
    }
}

impl GpuSolver {
    /// Opens a device and uploads `model` and `state`.
    ///
    /// Fails with [`GpuError::NoAdapter`] when no adapter is found, [`GpuError::Limit`] when the
    /// scene exceeds the adapter's limits, [`GpuError::Unsupported`] for implicit Euler on an
    /// adapter without indirect dispatch (`DownlevelFlags::INDIRECT_EXECUTION`), and
    /// [`GpuError::Device`] when the device or the pipelines cannot be created.
    pub fn new(model: Model, state: State) -> Result<GpuSolver, GpuError> {
        Self::with_options(model, state, GpuOptions::default())
    }

    /// [`GpuSolver::new`], with dispatch grids at most `width` workgroups wide (instead of the
    /// adapter's per-dimension limit), so that tests can run the 2-D grids of very large scenes
    /// on small ones.
    #[doc(hidden)]
    pub fn with_grid_width(
        model: Model,
        state: State,
        width: Option<u32>,
    ) -> Result<GpuSolver, GpuError> {
        Self::with_options(
            model,
            state,
            GpuOptions {
                grid_width: width,
                ..GpuOptions::default()
            },
        )
    }

    /// [`GpuSolver::new`] with test settings (see [`GpuOptions`]).
    #[doc(hidden)]
    pub fn with_options(
        model: Model,
        mut state: State,
        options: GpuOptions,
    ) -> Result<GpuSolver, GpuError> {
        let integrator = model.simulation.integrator;
        let implicit = integrator == Integrator::ImplicitEuler;
        let mut gpu = Gpu::open()?;
        if let Some(cap) = options.max_binding_size {
            // As if the adapter allowed no more: the device itself keeps its limits.
            let limit = &mut gpu.limits.max_storage_buffer_binding_size;
            *limit = (*limit).min(cap);
        }
        let width = options.grid_width;
        let adapter = gpu.name();
        if implicit
            && !gpu
                .downlevel
                .contains(wgpu::DownlevelFlags::INDIRECT_EXECUTION)
        {
            return Err(GpuError::Unsupported(format!(
                "{adapter} cannot dispatch compute work indirectly, which the GPU's implicit-euler \
                 needs (its CG iterations stop on the device): use --backend cpu, or an explicit \
                 integrator"
            )));
        }
        let n = model.len() as u64;
        let m = model.springs.len() as u64;
        let packed = terrain::pack(&model.terrain);
        let multi_stage = matches!(integrator, Integrator::Midpoint | Integrator::Rk4);
        let rk4 = integrator == Integrator::Rk4;
        let max_dim = gpu.limits.max_compute_workgroups_per_dimension;
        let width = width.map_or(max_dim, |w| w.clamp(1, max_dim));

        let need = |what, count, stride| Need {
            what,
            count,
            stride,
        };
        let mut needs = vec![
            need("positions", n, VEC4),
            need("velocities", n, VEC4),
            need("accelerations", n, VEC4),
            need("masses", n, 8),
            // The per-spring arrays are chunked (check_chunks); the adjacency, a gather's
            // index, stays whole: 2 words per spring, 16.7 M springs per 128 MiB.
            need("adjacency", n + 1 + 2 * m, 4),
            need(
                "terrain surfaces",
                packed.surfaces.len() as u64,
                std::mem::size_of::<terrain::SurfaceGpu>() as u64,
            ),
            need("terrain data", packed.data.len() as u64, 4),
        ];
        if multi_stage {
            needs.push(need("stage positions", n, VEC4));
            needs.push(need("stage velocities", n, VEC4));
        }
        if rk4 {
            needs.push(need("RK4 position sums", n, VEC4));
            needs.push(need("RK4 velocity sums", n, VEC4));
        }
        if implicit {
            needs.push(need("preconditioner blocks", 2 * n, VEC4));
            needs.push(need(
                "contact candidates",
                n,
                std::mem::size_of::<CandidateGpu>() as u64,
            ));
        }
        check_limits(
            &gpu.limits,
            &adapter,
            &needs,
            2 * n * VEC4,
            &[("particle", n), ("spring", m)],
        )?;
        let spring_stride = if implicit {
            std::mem::size_of::<SpringBlockGpu>()
        } else {
            std::mem::size_of::<SpringGpu>()
        } as u64;
        let chunking = check_chunks(&gpu.limits, &adapter, m, spring_stride, implicit)?;
        let ranges: Vec<(u64, u64)> = if chunking.count == 1 {
            vec![(0, m)]
        } else {
            let per = 1u64 << chunking.shift;
            (0..u64::from(chunking.count))
                .map(|c| (c * per, per.min(m - c * per)))
                .collect()
        };
        let grids: Option<Vec<Grid>> = ranges
            .iter()
            .map(|&(_, count)| Grid::with_width(count, width, max_dim))
            .collect();
        let (particle_grid, spring_grids) = match (Grid::with_width(n, width, max_dim), grids) {
            (Some(p), Some(s)) => (p, s),
            // Only with a narrow test width: check_limits checked the adapter's.
            _ => {
                return Err(GpuError::Unsupported(format!(
                    "the scene needs more than {max_dim} rows of {width} workgroups"
                )));
            }
        };
        let particle_partials = particle_grid.groups().max(1) * 8;
        // One per workgroup of springs: chunks are whole workgroups long (but the last), and
        // the idle workgroups of a 2-D grid write none.
        let spring_partials = m.div_ceil(WORKGROUP_SIZE).max(1) * 4;
        // Holds x and v (state) or the energy partials; for implicit Euler the CG progress, or
        // (for its stage tests) four vectors per particle. The stage tests' per-spring
        // read-backs enlarge it on demand (`submit_and_read`).
        let mut readback_bytes = (2 * n * VEC4)
            .max(particle_partials + spring_partials)
            .max(std::mem::size_of::<Status>() as u64);
        if implicit {
            readback_bytes = readback_bytes.max(4 * n * VEC4 + Progress::BYTES);
        }

        let device = &gpu.device;
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
        let n_surfaces = packed.surfaces.len() as u32;
        let step_stride = u64::from(gpu.limits.min_uniform_buffer_offset_alignment)
            .max(std::mem::size_of::<StepIndex>() as u64);
        let chunk_stride = u64::from(gpu.limits.min_uniform_buffer_offset_alignment)
            .max(std::mem::size_of::<SpringChunk>() as u64);
        let mut table = vec![0u8; (ranges.len() as u64 * chunk_stride) as usize];
        for (c, &(base, count)) in ranges.iter().enumerate() {
            let at = c * chunk_stride as usize;
            let record = SpringChunk {
                base: base as u32,
                count: count as u32,
                first_group: (base / WORKGROUP_SIZE) as u32,
                _pad: 0,
            };
            table[at..at + std::mem::size_of::<SpringChunk>()]
                .copy_from_slice(bytemuck::bytes_of(&record));
        }
        let chunks = SpringChunks {
            chunking,
            ranges,
            grids: spring_grids,
            table: gpu
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("spring chunks"),
                    contents: &table,
                    usage: wgpu::BufferUsages::UNIFORM,
                }),
            stride: chunk_stride,
        };
        let built = Self::build(
            step_stride,
            &gpu,
            &model,
            &state,
            &packed,
            n_surfaces,
            particle_partials,
            spring_partials,
            readback_bytes,
            particle_grid,
            &chunks,
        );
        // Scopes pop in reverse order.
        let errors = [
            pollster::block_on(internal.pop()),
            pollster::block_on(memory.pop()),
            pollster::block_on(validation.pop()),
        ];
        if let Some(e) = errors.into_iter().flatten().next() {
            return Err(GpuError::Device {
                adapter,
                message: format!("cannot set up the solver: {e}"),
            });
        }
        let (buffers, pipelines, groups, implicit) = built;
        // The host copy is what the device holds: the state rounded to f32.
        for p in state.x.iter_mut().chain(state.v.iter_mut()) {
            *p = p.as_vec3().as_dvec3();
        }
        Ok(GpuSolver {
            model,
            gpu,
            buffers,
            pipelines,
            groups,
            implicit,
            particle_grid,
            chunks,
            n_surfaces,
            step_stride,
            state,
            state_fresh: true,
            steps: 0,
            failed: None,
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn build(
        step_stride: u64,
        gpu: &Gpu,
        model: &Model,
        state: &State,
        packed: &terrain::TerrainBuffers,
        n_surfaces: u32,
        particle_partials: u64,
        spring_partials: u64,
        readback_bytes: u64,
        particle_grid: Grid,
        chunks: &SpringChunks,
    ) -> (Buffers, Pipelines, BindGroups, Option<Implicit>) {
        let device = &gpu.device;
        let integrator = model.simulation.integrator;
        let multi_stage = matches!(integrator, Integrator::Midpoint | Integrator::Rk4);
        let rk4 = integrator == Integrator::Rk4;
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        let init = |label: &str, bytes: &[u8], element: usize| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: &at_least(bytes, element),
                usage: storage,
            })
        };
        let empty = |label: &str, bytes: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.max(VEC4),
                usage: storage,
                mapped_at_creation: false,
            })
        };
        let n = model.len() as u64;
        let x = vec4s(&state.x);
        let v = vec4s(&state.v);
        let mut adjacency = model.adjacency.offsets.clone();
        adjacency.extend_from_slice(&model.adjacency.entries);
        let mass: Vec<[f32; 2]> = model
            .mass
            .iter()
            .zip(&model.inv_mass)
            .map(|(&m, &w)| [m as f32, w as f32])
            .collect();
        let springs = SpringGpu::pack(&model.springs);
        let spring_size = std::mem::size_of::<SpringGpu>();
        let spring_chunks: Vec<wgpu::Buffer> = chunks
            .ranges
            .iter()
            .map(|&(base, count)| {
                let (base, count) = (base as usize, count as usize);
                init(
                    "springs",
                    bytemuck::cast_slice(&springs[base..base + count]),
                    spring_size,
                )
            })
            .collect();
        let per_spring_chunks: Vec<wgpu::Buffer> = chunks
            .ranges
            .iter()
            .map(|&(_, count)| empty("per_spring", count * VEC4))
            .collect();
        let params = Params::new(model, n_surfaces);
        let mut step_indices = vec![0u8; (STEPS_PER_SUBMISSION * step_stride) as usize];
        for k in 0..STEPS_PER_SUBMISSION {
            let at = (k * step_stride) as usize;
            let index = StepIndex {
                step: k as u32 + 1,
                _pad: [0; 3],
            };
            step_indices[at..at + std::mem::size_of::<StepIndex>()]
                .copy_from_slice(bytemuck::bytes_of(&index));
        }
        let buffers = Buffers {
            params: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            }),
            x: init("x", bytemuck::cast_slice(&x), 16),
            v: init("v", bytemuck::cast_slice(&v), 16),
            a: empty("a", n * VEC4),
            per_spring: per_spring_chunks,
            springs: spring_chunks,
            adjacency: init("adjacency", bytemuck::cast_slice(&adjacency), 4),
            mass: init("mass", bytemuck::cast_slice(&mass), 8),
            stage_x: multi_stage.then(|| empty("stage_x", n * VEC4)),
            stage_v: multi_stage.then(|| empty("stage_v", n * VEC4)),
            sum_x: rk4.then(|| empty("sum_x", n * VEC4)),
            sum_v: rk4.then(|| empty("sum_v", n * VEC4)),
            status: init("status", bytemuck::bytes_of(&Status::RESET), 16),
            step_indices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("step_indices"),
                contents: &step_indices,
                usage: wgpu::BufferUsages::UNIFORM,
            }),
            particle_partials: empty("particle_partials", particle_partials),
            spring_partials: empty("spring_partials", spring_partials),
            surfaces: init(
                "surfaces",
                bytemuck::cast_slice(packed.surfaces_for_binding()),
                std::mem::size_of::<terrain::SurfaceGpu>(),
            ),
            terrain_data: init("terrain_data", bytemuck::cast_slice(&packed.data), 4),
            readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: readback_bytes.next_multiple_of(8),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        };

        let layout_of = |label: &str, bindings: &[(u32, Access)]| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &implicit::layout_entries(bindings),
            })
        };
        let terrain_layout = layout_of("terrain", TERRAIN_BINDINGS);
        // One module per stage, one pipeline per entry point; returns the group-0 layout.
        let chunking = chunks.chunking;
        let stage = |stage: Stage| -> (wgpu::BindGroupLayout, Vec<wgpu::ComputePipeline>) {
            // The module's bindings and, for the force gather, the per-spring chunks past the
            // first.
            let mut table = stage.bindings().to_vec();
            for entry in stage.entry_points() {
                table.extend(stage.chunk_bindings(entry, chunking));
            }
            let layout = layout_of(stage.file(), &table);
            let mut layouts = vec![Some(&layout)];
            if stage.uses_terrain() {
                layouts.push(Some(&terrain_layout));
            }
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(stage.file()),
                bind_group_layouts: &layouts,
                immediate_size: 0,
            });
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(stage.file()),
                source: wgpu::ShaderSource::Wgsl(stage.source_chunked(chunking).into()),
            });
            let pipelines = stage
                .entry_points()
                .iter()
                .map(|entry| {
                    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some(entry),
                        layout: Some(&pipeline_layout),
                        module: &module,
                        entry_point: Some(entry),
                        compilation_options: Default::default(),
                        cache: None,
                    })
                })
                .collect();
            (layout, pipelines)
        };
        let (spring_layout, mut spring_pipes) = stage(Stage::SpringForces);
        let (forces_layout, mut forces_pipes) = stage(Stage::Forces);
        let update_stage = match integrator {
            Integrator::ExplicitEuler => Some(Stage::ExplicitEuler),
            Integrator::SymplecticEuler => Some(Stage::SymplecticEuler),
            Integrator::Midpoint => Some(Stage::Midpoint),
            Integrator::Rk4 => Some(Stage::Rk4),
            Integrator::ImplicitEuler => None,
        };
        let (update_layout, update) = match update_stage.map(stage) {
            Some((layout, pipelines)) => (Some(layout), pipelines),
            None => (None, Vec::new()),
        };
        let (collision_layout, mut collision_pipes) = stage(Stage::CollisionResponse);
        let (check_layout, mut check_pipes) = stage(Stage::CheckFinite);
        let (energy_layout, mut energy_pipes) = stage(Stage::Energy);
        let check_finite = check_pipes.pop().expect("one entry point");
        let energy_springs = energy_pipes.pop().expect("two entry points");
        let energy_particles = energy_pipes.pop().expect("two entry points");
        let pipelines = Pipelines {
            spring_forces: spring_pipes.pop().expect("one entry point"),
            accelerations: forces_pipes.pop().expect("one entry point"),
            update,
            collision_response: collision_pipes.pop().expect("one entry point"),
            check_finite,
            energy_particles,
            energy_springs,
        };

        let b = &buffers;
        let group = |label: &str, layout: &wgpu::BindGroupLayout, list: &[&wgpu::Buffer]| {
            let entries: Vec<wgpu::BindGroupEntry> = list
                .iter()
                .enumerate()
                .map(|(i, buffer)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: buffer.as_entire_binding(),
                })
                .collect();
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout,
                entries: &entries,
            })
        };
        let group_at =
            |label: &str, layout: &wgpu::BindGroupLayout, list: &[(u32, wgpu::BindingResource)]| {
                let entries: Vec<wgpu::BindGroupEntry> = list
                    .iter()
                    .map(|(binding, resource)| wgpu::BindGroupEntry {
                        binding: *binding,
                        resource: resource.clone(),
                    })
                    .collect();
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(label),
                    layout,
                    entries: &entries,
                })
            };
        // The per-spring vectors' chunks past the first, at their gather bindings.
        let extra_per_spring = |first: u32| -> Vec<(u32, wgpu::BindingResource)> {
            b.per_spring
                .iter()
                .enumerate()
                .skip(1)
                .map(|(c, buffer)| (first + c as u32 - 1, buffer.as_entire_binding()))
                .collect()
        };
        let spring_forces_groups = |label: &str, x: &wgpu::Buffer, v: &wgpu::Buffer| {
            (0..chunks.len())
                .map(|c| {
                    group_at(
                        label,
                        &spring_layout,
                        &[
                            (0, b.params.as_entire_binding()),
                            (1, x.as_entire_binding()),
                            (2, v.as_entire_binding()),
                            (3, b.springs[c].as_entire_binding()),
                            (4, b.per_spring[c].as_entire_binding()),
                            (5, chunks.uniform(c)),
                        ],
                    )
                })
                .collect::<Vec<_>>()
        };
        let forces_group = |label: &str, x: &wgpu::Buffer, v: &wgpu::Buffer| {
            let mut list = vec![
                (0, b.params.as_entire_binding()),
                (1, x.as_entire_binding()),
                (2, v.as_entire_binding()),
                (3, b.per_spring[0].as_entire_binding()),
                (4, b.adjacency.as_entire_binding()),
                (5, b.mass.as_entire_binding()),
                (6, b.a.as_entire_binding()),
            ];
            list.extend(extra_per_spring(PER_SPRING_CHUNK_BINDING));
            group_at(label, &forces_layout, &list)
        };
        let stage_xv = b.stage_x.as_ref().zip(b.stage_v.as_ref());
        let update_group = update_layout.as_ref().map(|update_layout| {
            match (
                update_stage,
                stage_xv,
                b.sum_x.as_ref().zip(b.sum_v.as_ref()),
            ) {
                (Some(Stage::Rk4), Some((sx, sv)), Some((ux, uv))) => group(
                    "rk4",
                    update_layout,
                    &[&b.params, &b.x, &b.v, &b.a, sx, sv, ux, uv],
                ),
                (Some(Stage::Midpoint), Some((sx, sv)), _) => group(
                    "midpoint",
                    update_layout,
                    &[&b.params, &b.x, &b.v, &b.a, sx, sv],
                ),
                _ => group("euler", update_layout, &[&b.params, &b.x, &b.v, &b.a]),
            }
        });
        let groups = BindGroups {
            spring_forces: [
                spring_forces_groups("spring_forces(x, v)", &b.x, &b.v),
                stage_xv
                    .map(|(sx, sv)| spring_forces_groups("spring_forces(stage)", sx, sv))
                    .unwrap_or_default(),
            ],
            forces: [
                Some(forces_group("accelerations(x, v)", &b.x, &b.v)),
                stage_xv.map(|(sx, sv)| forces_group("accelerations(stage)", sx, sv)),
            ],
            terrain: group("terrain", &terrain_layout, &[&b.surfaces, &b.terrain_data]),
            update: update_group,
            collision_response: group(
                "collision_response",
                &collision_layout,
                &[&b.params, &b.x, &b.v, &b.mass],
            ),
            check_finite:
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("check_finite"),
                    layout: &check_layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: b.params.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: b.x.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: b.v.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: b.status.as_entire_binding(),
                        },
                        // One slot; the dispatch picks which by its dynamic offset.
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                buffer: &b.step_indices,
                                offset: 0,
                                size: std::num::NonZeroU64::new(
                                    std::mem::size_of::<StepIndex>() as u64
                                ),
                            }),
                        },
                    ],
                }),
            energy: (0..chunks.len())
                .map(|c| {
                    group_at(
                        "energy",
                        &energy_layout,
                        &[
                            (0, b.params.as_entire_binding()),
                            (1, b.x.as_entire_binding()),
                            (2, b.v.as_entire_binding()),
                            (3, b.mass.as_entire_binding()),
                            (4, b.springs[c].as_entire_binding()),
                            (5, b.particle_partials.as_entire_binding()),
                            (6, b.spring_partials.as_entire_binding()),
                            (7, chunks.uniform(c)),
                        ],
                    )
                })
                .collect(),
        };
        let implicit = (integrator == Integrator::ImplicitEuler).then(|| {
            let shared = implicit::Shared {
                params: &b.params,
                x: &b.x,
                v: &b.v,
                mass: &b.mass,
                springs: &b.springs,
                adjacency: &b.adjacency,
                per_spring: &b.per_spring,
                terrain_layout: &terrain_layout,
                terrain: &groups.terrain,
                chunks,
            };
            Implicit::new(device, &shared, n, n_surfaces > 0, particle_grid)
        });
        (buffers, pipelines, groups, implicit)
    }

    /// The adapter, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) via Vulkan".
    pub fn adapter(&self) -> String {
        self.gpu.name()
    }

    /// The limits the device runs under (with [`GpuOptions::max_binding_size`] applied).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.gpu.limits
    }

    /// (first spring, springs) of each chunk the per-spring arrays are split into: one unless
    /// they exceed a storage binding (see the module documentation).
    pub fn spring_chunks(&self) -> &[(u64, u64)] {
        &self.chunks.ranges
    }

    /// Replaces the state (uploads it); the step count stays.
    pub fn set_state(&mut self, state: &State) -> Result<(), StepError> {
        self.healthy()?;
        let n = self.model.len();
        if state.x.len() != n || state.v.len() != n {
            return Err(StepError::Device(format!(
                "set_state: the state has {} positions and {} velocities, the model {n} particles",
                state.x.len(),
                state.v.len()
            )));
        }
        if n > 0 {
            let queue = &self.gpu.queue;
            queue.write_buffer(&self.buffers.x, 0, bytemuck::cast_slice(&vec4s(&state.x)));
            queue.write_buffer(&self.buffers.v, 0, bytemuck::cast_slice(&vec4s(&state.v)));
        }
        self.state_fresh = false;
        Ok(())
    }

    fn healthy(&mut self) -> Result<(), StepError> {
        if self.failed.is_none() {
            self.failed = self.gpu.errors.get();
        }
        match &self.failed {
            Some(e) => Err(StepError::Device(format!("{e} (on {})", self.gpu.name()))),
            None => Ok(()),
        }
    }

    fn fail(&mut self, message: String) -> StepError {
        if self.failed.is_none() {
            self.failed = Some(message);
        }
        StepError::Device(format!(
            "{} (on {})",
            self.failed.as_deref().unwrap_or_default(),
            self.gpu.name()
        ))
    }

    fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        pipeline: &wgpu::ComputePipeline,
        group: &wgpu::BindGroup,
        terrain: bool,
        grid: Grid,
    ) {
        if grid.groups() == 0 {
            return;
        }
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        if terrain {
            pass.set_bind_group(1, &self.groups.terrain, &[]);
        }
        pass.dispatch_workgroups(grid.x, grid.y, 1);
    }

    /// Spring forces, then accelerations, of the chosen state.
    fn encode_accelerations(&self, pass: &mut wgpu::ComputePass<'_>, input: Input) {
        let i = input as usize;
        let Some(forces) = &self.groups.forces[i] else {
            unreachable!("stage bind groups exist for the multi-stage integrators")
        };
        let p = &self.pipelines;
        self.encode_spring_forces(pass, input);
        self.dispatch(pass, &p.accelerations, forces, true, self.particle_grid);
    }

    /// Spring forces of the chosen state, chunk by chunk.
    fn encode_spring_forces(&self, pass: &mut wgpu::ComputePass<'_>, input: Input) {
        let groups = &self.groups.spring_forces[input as usize];
        for (group, &grid) in groups.iter().zip(&self.chunks.grids) {
            self.dispatch(pass, &self.pipelines.spring_forces, group, false, grid);
        }
    }

    /// Step `k` (0-based) of a submission.
    fn encode_step(&self, pass: &mut wgpu::ComputePass<'_>, k: u64) {
        let p = &self.pipelines;
        let grid = self.particle_grid;
        let Some(update) = &self.groups.update else {
            unreachable!("implicit Euler steps through Implicit")
        };
        match self.model.simulation.integrator {
            Integrator::ExplicitEuler | Integrator::SymplecticEuler => {
                self.encode_accelerations(pass, Input::Main);
                self.dispatch(pass, &p.update[0], update, false, grid);
            }
            Integrator::Midpoint => {
                self.encode_accelerations(pass, Input::Main);
                self.dispatch(pass, &p.update[0], update, false, grid);
                self.encode_accelerations(pass, Input::Stage);
                self.dispatch(pass, &p.update[1], update, false, grid);
            }
            Integrator::Rk4 => {
                self.encode_accelerations(pass, Input::Main);
                self.dispatch(pass, &p.update[0], update, false, grid);
                for k in 1..4 {
                    self.encode_accelerations(pass, Input::Stage);
                    self.dispatch(pass, &p.update[k], update, false, grid);
                }
            }
            Integrator::ImplicitEuler => unreachable!("implicit Euler steps through Implicit"),
        }
        if self.n_surfaces > 0 {
            self.dispatch(
                pass,
                &p.collision_response,
                &self.groups.collision_response,
                true,
                grid,
            );
        }
        self.encode_check(pass, k);
    }

    /// The instability check of step `k` (0-based) of a submission.
    fn encode_check(&self, pass: &mut wgpu::ComputePass<'_>, k: u64) {
        let grid = self.particle_grid;
        if grid.groups() > 0 {
            pass.set_pipeline(&self.pipelines.check_finite);
            let offset = (k * self.step_stride) as u32;
            pass.set_bind_group(0, &self.groups.check_finite, &[offset]);
            pass.dispatch_workgroups(grid.x, grid.y, 1);
        }
    }

    /// Encodes `encode` into one compute pass of a new command encoder.
    fn encode_pass(
        &self,
        label: &str,
        encode: impl FnOnce(&mut wgpu::ComputePass<'_>),
    ) -> wgpu::CommandEncoder {
        let mut encoder = self.encoder(label);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(label),
                timestamp_writes: None,
            });
            encode(&mut pass);
        }
        encoder
    }

    fn implicit(&self) -> &Implicit {
        self.implicit
            .as_ref()
            .expect("the implicit buffers exist for implicit Euler")
    }

    /// Submits `encoder` (after resetting the active set's `changed` word) and reads the CG
    /// progress back.
    fn implicit_progress(&mut self, encoder: wgpu::CommandEncoder) -> Result<Progress, StepError> {
        let (scalars, changed) = {
            let im = self.implicit();
            (im.scalars.clone(), im.changed.clone())
        };
        let size = std::mem::size_of::<crate::layout::CgScalars>() as u64;
        let bytes = self.submit_and_read(encoder, &[(&scalars, size), (&changed, 4)])?;
        Ok(Progress::parse(&bytes))
    }

    /// Runs CG batches until the solve begun in `encoder` is done; returns the last progress.
    fn implicit_solve(&mut self, encoder: wgpu::CommandEncoder) -> Result<Progress, StepError> {
        let changed = self.implicit().changed.clone();
        self.gpu
            .queue
            .write_buffer(&changed, 0, bytemuck::bytes_of(&0u32));
        let mut progress = self.implicit_progress(encoder)?;
        while progress.scalars.done == 0 {
            let encoder = self.encode_pass("cg batch", |pass| {
                let im = self.implicit();
                im.encode_batch(pass, im.batch(false));
            });
            progress = self.implicit_progress(encoder)?;
        }
        let scalars = progress.scalars;
        if let Some(im) = self.implicit.as_mut() {
            im.record(&scalars);
        }
        Ok(progress)
    }

    /// Step `k` (0-based) of an `advance` chunk of implicit Euler (see [`crate::implicit`]).
    fn implicit_step(&mut self, k: u64) -> Result<(), StepError> {
        if self.model.is_empty() {
            return Ok(());
        }
        let im = self.implicit();
        let contacts = im.has_terrain;
        let encoder = self.encode_pass("implicit step", |pass| {
            let im = self.implicit();
            im.encode_assemble(pass);
            im.encode_round(pass, true);
            im.encode_batch(pass, im.batch(true));
        });
        let mut progress = self.implicit_solve(encoder)?;
        let mut rounds = 1;
        while contacts && progress.changed && rounds < implicit::ROUNDS {
            let encoder = self.encode_pass("active-set round", |pass| {
                let im = self.implicit();
                im.encode_round(pass, true);
                im.encode_batch(pass, im.batch(true));
            });
            progress = self.implicit_solve(encoder)?;
            rounds += 1;
        }
        let encoder = self.encode_pass("implicit finish", |pass| {
            self.implicit().encode_finish(pass);
            self.encode_check(pass, k);
        });
        self.gpu.queue.submit([encoder.finish()]);
        Ok(())
    }

    /// Submits `encoder` after appending copies of `sources` (buffer, bytes) into the read-back
    /// buffer, waits, and returns the bytes.
    fn submit_and_read(
        &mut self,
        mut encoder: wgpu::CommandEncoder,
        sources: &[(&wgpu::Buffer, u64)],
    ) -> Result<Vec<u8>, StepError> {
        let total: u64 = sources.iter().map(|&(_, bytes)| bytes).sum();
        if total > self.buffers.readback.size() {
            // Only the stage tests read more than the state (per-spring vectors).
            self.buffers.readback = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: total.next_multiple_of(8),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
        }
        let mut offset = 0;
        for &(buffer, bytes) in sources {
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(buffer, 0, &self.buffers.readback, offset, bytes);
                offset += bytes;
            }
        }
        let index = self.gpu.queue.submit([encoder.finish()]);
        if offset == 0 {
            return Ok(Vec::new());
        }
        let readback = self.buffers.readback.clone();
        let slice = readback.slice(0..offset);
        let (sender, receiver) = mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        if let Err(e) = self.gpu.device.poll(wgpu::PollType::Wait {
            submission_index: Some(index),
            timeout: None,
        }) {
            self.healthy()?;
            return Err(self.fail(format!("the GPU did not finish its work: {e}")));
        }
        let mut mapped = receiver.try_recv();
        if mapped.is_err() {
            // The map callback runs in a later poll on some backends.
            let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
            mapped = receiver.try_recv();
        }
        self.healthy()?;
        match mapped {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(self.fail(format!("cannot read results back: {e}"))),
            Err(_) => return Err(self.fail("the read-back never completed".to_owned())),
        }
        let bytes = match slice.get_mapped_range() {
            Ok(view) => view.to_vec(),
            Err(e) => return Err(self.fail(format!("cannot read results back: {e}"))),
        };
        readback.unmap();
        Ok(bytes)
    }

    /// The status after a submission of steps.
    fn read_status(&mut self, encoder: wgpu::CommandEncoder) -> Result<Status, StepError> {
        let status = self.buffers.status.clone();
        let size = std::mem::size_of::<Status>();
        let bytes = self.submit_and_read(encoder, &[(&status, size as u64)])?;
        Ok(bytemuck::pod_read_unaligned(&bytes[..size]))
    }

    /// Runs one dispatch sequence outside a step and reads `sources` back: for the stage tests.
    fn run_and_read(
        &mut self,
        encode: impl FnOnce(&Self, &mut wgpu::ComputePass<'_>),
        sources: &[(&wgpu::Buffer, u64)],
    ) -> Result<Vec<u8>, StepError> {
        self.healthy()?;
        let mut encoder = self.encoder("stage");
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("stage"),
                timestamp_writes: None,
            });
            encode(self, &mut pass);
        }
        self.submit_and_read(encoder, sources)
    }

    /// Spring forces of the current state, f_a per spring: runs `spring_forces` alone.
    #[doc(hidden)]
    pub fn debug_spring_forces(&mut self) -> Result<Vec<Vec3>, StepError> {
        let per_spring = self.buffers.per_spring.clone();
        let sources: Vec<(&wgpu::Buffer, u64)> = per_spring
            .iter()
            .zip(&self.chunks.ranges)
            .map(|(buffer, &(_, count))| (buffer, count * VEC4))
            .collect();
        let bytes = self.run_and_read(
            |s, pass| s.encode_spring_forces(pass, Input::Main),
            &sources,
        )?;
        Ok(to_vec3(&bytes))
    }

    /// Accelerations of the current state: runs `spring_forces` and `accelerations` alone.
    #[doc(hidden)]
    pub fn debug_accelerations(&mut self) -> Result<Vec<Vec3>, StepError> {
        let a = self.buffers.a.clone();
        let n = self.model.len() as u64;
        let bytes = self.run_and_read(
            |s, pass| s.encode_accelerations(pass, Input::Main),
            &[(&a, n * VEC4)],
        )?;
        Ok(to_vec3(&bytes))
    }

    /// Implicit Euler's system at the current state, and its product with `p`: runs the assembly
    /// and one product alone. Returns b, the inverse diagonal blocks (`diag`: P⁻¹xx, P⁻¹yy,
    /// P⁻¹zz, m(1 + h·drag), P⁻¹xy, P⁻¹xz, P⁻¹yz, 0 per particle) and A p.
    #[doc(hidden)]
    pub fn debug_implicit_system(&mut self, p: &[DVec3]) -> Result<ImplicitSystem, StepError> {
        let n = self.model.len() as u64;
        let Some(im) = &self.implicit else {
            return Err(StepError::Device("not an implicit-euler solver".to_owned()));
        };
        let (b, diag, q) = (im.b.clone(), im.diag.clone(), im.q.clone());
        self.gpu
            .queue
            .write_buffer(&im.dv, 0, bytemuck::cast_slice(&vec4s(p)));
        let bytes = self.run_and_read(
            |s, pass| {
                let im = s.implicit();
                im.encode_assemble(pass);
                im.encode_apply_dv(pass);
            },
            &[(&b, n * VEC4), (&diag, 2 * n * VEC4), (&q, n * VEC4)],
        )?;
        let (b, rest) = bytes.split_at((n * VEC4) as usize);
        let (diag, q) = rest.split_at((2 * n * VEC4) as usize);
        Ok((to_vec3(b), bytemuck::pod_collect_to_vec(diag), to_vec3(q)))
    }

    /// One CG solve of implicit Euler's system at the current state with the given
    /// constraints, right-hand side, prescribed Δv and warm start (the twin of
    /// `softbody_cpu::integrators::implicit_euler::cg::solve`): returns Δv and the scalars it
    /// ended with.
    #[doc(hidden)]
    pub fn debug_implicit_solve(
        &mut self,
        constraints: &[softbody_scene::implicit::Constraint],
        rhs: &[DVec3],
        z: &[DVec3],
        dv: &[DVec3],
    ) -> Result<(Vec<DVec3>, crate::layout::CgScalars), StepError> {
        self.healthy()?;
        let n = self.model.len() as u64;
        let Some(im) = &self.implicit else {
            return Err(StepError::Device("not an implicit-euler solver".to_owned()));
        };
        let queue = &self.gpu.queue;
        let packed: Vec<[f32; 4]> = constraints
            .iter()
            .map(|&c| implicit::constraint_vec4(c))
            .collect();
        queue.write_buffer(&im.constraints, 0, bytemuck::cast_slice(&packed));
        queue.write_buffer(&im.rhs, 0, bytemuck::cast_slice(&vec4s(rhs)));
        queue.write_buffer(&im.z, 0, bytemuck::cast_slice(&vec4s(z)));
        queue.write_buffer(&im.dv, 0, bytemuck::cast_slice(&vec4s(dv)));
        let dv = im.dv.clone();
        let encoder = self.encode_pass("cg solve", |pass| {
            let im = self.implicit();
            im.encode_assemble(pass);
            im.encode_round(pass, false);
            im.encode_batch(pass, im.batch(true));
        });
        let progress = self.implicit_solve(encoder)?;
        let encoder = self.encoder("read dv");
        let bytes = self.submit_and_read(encoder, &[(&dv, n * VEC4)])?;
        Ok((to_dvec3(&bytes), progress.scalars))
    }

    /// Destroys the device, as a driver reset would lose it: for the failure tests.
    #[doc(hidden)]
    pub fn debug_destroy_device(&self) {
        self.gpu.device.destroy();
    }

    /// Runs `collision_response` alone on the current state.
    #[doc(hidden)]
    pub fn debug_collision_response(&mut self) -> Result<(), StepError> {
        self.state_fresh = false;
        self.run_and_read(
            |s, pass| {
                s.dispatch(
                    pass,
                    &s.pipelines.collision_response,
                    &s.groups.collision_response,
                    true,
                    s.particle_grid,
                )
            },
            &[],
        )?;
        self.healthy()
    }
}

/// What [`GpuSolver::debug_implicit_system`] reads back: b, the `diag` pairs, A p.
pub type ImplicitSystem = (Vec<Vec3>, Vec<[f32; 8]>, Vec<Vec3>);

fn to_vec3(bytes: &[u8]) -> Vec<Vec3> {
    let v: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(bytes);
    v.iter().map(|p| Vec3::new(p[0], p[1], p[2])).collect()
}

fn to_dvec3(bytes: &[u8]) -> Vec<DVec3> {
    to_vec3(bytes).into_iter().map(|p| p.as_dvec3()).collect()
}

impl Solver for GpuSolver {
    fn backend(&self) -> &'static str {
        "gpu"
    }

    fn device(&self) -> String {
        self.gpu.name()
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn advance(&mut self, steps: u64) -> Result<(), StepError> {
        self.healthy()?;
        if steps == 0 {
            return Ok(());
        }
        self.state_fresh = false;
        let mut done = 0;
        while done < steps {
            let batch = (steps - done).min(STEPS_PER_SUBMISSION);
            // Ordered before the submission's commands.
            self.gpu.queue.write_buffer(
                &self.buffers.status,
                0,
                bytemuck::bytes_of(&Status::RESET),
            );
            let encoder = if self.implicit.is_some() {
                // Each step synchronises on its CG read-backs; the status is read at the end.
                for k in 0..batch {
                    self.implicit_step(k)?;
                }
                self.encoder("status")
            } else {
                self.encode_pass("steps", |pass| {
                    for k in 0..batch {
                        self.encode_step(pass, k);
                    }
                })
            };
            let status = self.read_status(encoder)?;
            if status.bad_step != NONE {
                let step = self.steps + u64::from(status.bad_step);
                self.steps = step;
                let particle = status.bad_particle;
                return Err(StepError::Unstable(Instability {
                    step,
                    time: step as f64 * self.model.simulation.dt,
                    particle,
                    what: if status.bad_position == particle {
                        "has a non-finite position"
                    } else {
                        "has a non-finite velocity"
                    }
                    .to_owned(),
                }));
            }
            done += batch;
            self.steps += batch;
        }
        Ok(())
    }

    fn steps_taken(&self) -> u64 {
        self.steps
    }

    fn state(&mut self) -> Result<&State, StepError> {
        self.healthy()?;
        if !self.state_fresh {
            let n = self.model.len() as u64;
            let (x, v) = (self.buffers.x.clone(), self.buffers.v.clone());
            let encoder = self.encoder("read state");
            let bytes = self.submit_and_read(encoder, &[(&x, n * VEC4), (&v, n * VEC4)])?;
            let half = (n * VEC4) as usize;
            self.state.x = to_dvec3(&bytes[..half]);
            self.state.v = to_dvec3(&bytes[half..]);
            self.state_fresh = true;
        }
        Ok(&self.state)
    }

    fn energies(&mut self) -> Result<Energies, StepError> {
        let (pp, sp) = (
            self.buffers.particle_partials.clone(),
            self.buffers.spring_partials.clone(),
        );
        let particle_bytes = self.particle_grid.groups() * 8;
        let spring_bytes = (self.model.springs.len() as u64).div_ceil(WORKGROUP_SIZE) * 4;
        let bytes = self.run_and_read(
            |s, pass| {
                let p = &s.pipelines;
                let g = &s.groups.energy;
                s.dispatch(pass, &p.energy_particles, &g[0], false, s.particle_grid);
                for (group, &grid) in g.iter().zip(&s.chunks.grids) {
                    s.dispatch(pass, &p.energy_springs, group, false, grid);
                }
            },
            &[(&pp, particle_bytes), (&sp, spring_bytes)],
        )?;
        let (particles, springs) = bytes.split_at(particle_bytes as usize);
        let particles: Vec<[f32; 2]> = bytemuck::pod_collect_to_vec(particles);
        let springs: Vec<f32> = bytemuck::pod_collect_to_vec(springs);
        let (mut kinetic, mut gravitational, mut elastic) = (0.0f64, 0.0f64, 0.0f64);
        for p in &particles {
            kinetic += f64::from(p[0]);
            gravitational += f64::from(p[1]);
        }
        for &s in &springs {
            elastic += f64::from(s);
        }
        Ok(Energies {
            kinetic: 0.5 * kinetic,
            gravitational: -gravitational,
            elastic: 0.5 * elastic,
        })
    }

    fn statistics(&self) -> Statistics {
        let implicit = self
            .implicit
            .as_ref()
            .map(|im| im.statistics.clone())
            .unwrap_or_default();
        Statistics {
            steps: self.steps,
            ..implicit
        }
    }

    fn sync(&mut self) -> Result<(), StepError> {
        self.healthy()?;
        if let Err(e) = self.gpu.device.poll(wgpu::PollType::wait_indefinitely()) {
            return Err(self.fail(format!("the GPU did not finish its work: {e}")));
        }
        self.healthy()
    }

    fn set_state(&mut self, state: &State) -> Result<(), StepError> {
        GpuSolver::set_state(self, state)
    }

    fn memory_bytes(&self) -> u64 {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grids_go_two_dimensional_past_the_per_dimension_limit() {
        let g = |threads| Grid::new(threads, 65_535);
        assert_eq!(g(0), Some(Grid { x: 0, y: 0 }));
        assert_eq!(g(1), Some(Grid { x: 1, y: 1 }));
        assert_eq!(g(256), Some(Grid { x: 1, y: 1 }));
        assert_eq!(g(257), Some(Grid { x: 2, y: 1 }));
        assert_eq!(g(65_535 * 256), Some(Grid { x: 65_535, y: 1 }));
        assert_eq!(g(65_535 * 256 + 1), Some(Grid { x: 65_535, y: 2 }));
        // u32::MAX particles: 16,777,216 workgroups in 257 rows.
        let most = g(u64::from(u32::MAX)).unwrap();
        assert_eq!((most.x, most.y), (65_535, 257));
        assert!(most.groups() * WORKGROUP_SIZE >= u64::from(u32::MAX));
        assert_eq!(Grid::new(65_535u64 * 65_535 * 256 + 1, 65_535), None);
    }

    fn needs(particles: u64) -> Vec<Need> {
        vec![Need {
            what: "positions",
            count: particles,
            stride: VEC4,
        }]
    }

    #[test]
    fn limits_are_named_with_their_figures() {
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: 1 << 27,
            ..wgpu::Limits::default()
        };
        let ok = check_limits(&limits, "test adapter", &needs(1 << 23), 0, &[]);
        assert_eq!(ok, Ok(()));
        let e = check_limits(&limits, "test adapter", &needs((1 << 23) + 1), 0, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffer_binding_size"), "{e}");
        assert!(
            e.contains("the positions buffer (8388609 × 16 bytes) needs 134217744 bytes"),
            "{e}"
        );
        assert!(e.contains("test adapter allows 134217728 bytes"), "{e}");
        assert!(e.contains("--backend cpu"), "{e}");

        let e = check_limits(
            &limits,
            "a",
            &[],
            0,
            &[("spring", 65_535u64 * 65_535 * 256 + 1)],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("max_compute_workgroups_per_dimension"), "{e}");

        let small = wgpu::Limits {
            max_storage_buffers_per_shader_stage: 4,
            ..wgpu::Limits::default()
        };
        let e = check_limits(&small, "a", &[], 0, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffers_per_shader_stage"), "{e}");
        assert!(e.contains("needs 8 storage buffers"), "{e}");

        let e = check_limits(&limits, "a", &[], limits.max_buffer_size + 1, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_buffer_size"), "{e}");
    }

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

    #[test]
    fn chunks_past_what_a_kernel_can_bind_are_refused_with_the_figures() {
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: 1 << 27,
            max_buffer_size: 1 << 30,
            max_storage_buffers_per_shader_stage: 16,
            ..wgpu::Limits::default()
        };
        // 4 chunks: the force gather binds 11, implicit Euler's assembly 13 storage buffers.
        let ok = check_chunks(&limits, "a", 15_700_000, 20, false).unwrap();
        assert_eq!(ok.count, 4);
        assert_eq!(
            check_chunks(&limits, "a", 15_700_000, 32, true)
                .unwrap()
                .count,
            4
        );
        // 6 chunks: 13 for the force gather, but 17 for the implicit assembly.
        let m = 6 * (1 << 22) - 1;
        assert_eq!(check_chunks(&limits, "a", m, 20, false).unwrap().count, 6);
        let e = check_chunks(&limits, "GL adapter", m, 32, true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffers_per_shader_stage"), "{e}");
        assert!(
            e.contains("25165823 springs (32 bytes each) in 6 chunks of 4194304"),
            "{e}"
        );
        assert!(e.contains("needs 17 storage buffers"), "{e}");
        assert!(e.contains("GL adapter allows 16"), "{e}");
        // More chunks than the gathers have bindings for.
        let wide = wgpu::Limits {
            max_storage_buffers_per_shader_stage: 64,
            ..limits.clone()
        };
        let e = check_chunks(&wide, "a", 17 << 22, 20, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffer_binding_size"), "{e}");
        assert!(e.contains("needs 17 chunks"), "{e}");
        // The smaller of the binding and buffer limits is named.
        let small_buffers = wgpu::Limits {
            max_buffer_size: 1000,
            ..limits
        };
        let e = check_chunks(&small_buffers, "a", 1_000_000, 20, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_buffer_size"), "{e}");
        assert!(
            e.contains("a chunk of 256 springs (20 bytes each) needs 5120 bytes"),
            "{e}"
        );
    }
}
