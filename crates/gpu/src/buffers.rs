//! The model and state on the device: the buffers every stage shares, the table that binds
//! them by the names the shaders use, and [`Setup`], what a stage is built from.
//!
//! Vectors are `vec4<f32>` (w = 0); masses are `vec2(m, 1/m)` and the CSR adjacency is its
//! offsets followed by its entries in one `u32` buffer, which keeps the force kernel at 8
//! storage buffers with the terrain's (WebGPU's guaranteed minimum).
//!
//! The springs are on the device as the run's [`Route`] reads them ([`SpringBuffers`]): on the
//! stencil route only the lattices' tables, which is what makes it lean (no spring record, no
//! adjacency, no per-spring vector: 20 + 8 + 16 bytes per spring, about 13 springs per
//! particle, and the list is never built on the host either); on the fused gather's the
//! spring list (records and adjacency); on the per-spring route also what its kernels write
//! ([`PerSpringWrites`]).

use glam::{DVec3, Vec3};
use softbody_scene::{Model, State};

use crate::builder::Builder;
use crate::chunks::SpringChunks;
use crate::grid::Grid;
use crate::kernel::{Call, Resources};
use crate::layout::{LatticeBodyGpu, Params, SpringGpu, Status, StepIndex};
use crate::shaders::Stage;
use crate::{GpuError, STEPS_PER_SUBMISSION, VEC4};

/// How a run finds each particle's springs, and so what the device holds of them: decided
/// once, before anything is allocated (`crate::plan`); the buffers uploaded and the integrator
/// built follow it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Route {
    /// The explicit integrators fused, finding the springs on the lattices (`stencil.wgsl`):
    /// neither the host nor the device holds a spring list.
    Stencil,
    /// The explicit integrators fused, gathering through the spring records and the CSR
    /// adjacency (`fused_gather.wgsl`): nothing per spring is written.
    Gather,
    /// The spring list and what the per-spring kernels write into (the per-spring vectors, the
    /// accelerations): the per-spring path and implicit Euler.
    PerSpring,
}

/// What a stage is built from: the builder, the model's buffers, the spring chunks and the
/// particle grid. (What one stage needs of another, the contact between bodies say, is passed
/// to it beside this.)
#[derive(Clone, Copy)]
pub(crate) struct Setup<'a> {
    /// Buffers and kernels.
    pub builder: &'a Builder,
    /// The model and state.
    pub buffers: &'a ModelBuffers,
    /// How the per-spring arrays are split.
    pub chunks: &'a SpringChunks,
    /// One thread per particle.
    pub particles: Grid,
    /// Particles.
    pub n: u64,
}

impl<'a> Setup<'a> {
    /// Calls of a per-spring kernel, one per spring chunk, each with that chunk's buffers
    /// ([`ModelBuffers::chunk_resources`]) and what `extra` adds to them.
    pub fn per_chunk<'r>(
        &self,
        stage: Stage,
        entry: &'static str,
        extra: impl Fn(usize, Resources<'r>) -> Resources<'r>,
    ) -> Result<Vec<Call>, GpuError>
    where
        'a: 'r,
    {
        let tables =
            (0..self.chunks.len()).map(|c| extra(c, self.buffers.chunk_resources(self.chunks, c)));
        self.builder.calls(stage, entry, tables)
    }
}

/// The buffers of the model and state.
pub(crate) struct ModelBuffers {
    /// [`Params`].
    pub params: wgpu::Buffer,
    /// Positions.
    pub x: wgpu::Buffer,
    /// Velocities.
    pub v: wgpu::Buffer,
    /// (m, 1/m) per particle.
    pub mass: wgpu::Buffer,
    /// The springs, as the route reads them.
    pub springs: SpringBuffers,
    /// The instability record of a submission.
    pub status: wgpu::Buffer,
    /// [`StepIndex`] 1..=[`STEPS_PER_SUBMISSION`], one per `step_stride` bytes.
    pub step_indices: wgpu::Buffer,
    /// Bytes between consecutive [`StepIndex`] slots (the uniform offset alignment).
    pub step_stride: u64,
    /// Per-workgroup partial sums of the particle energies.
    pub particle_partials: wgpu::Buffer,
    /// Per-workgroup partial sums of the spring energies (per spring workgroup, or on the
    /// stencil route per particle workgroup: [`crate::energy`]).
    pub spring_partials: wgpu::Buffer,
}

/// The springs on the device.
pub(crate) enum SpringBuffers {
    /// The stencil route: each lattice body's table and the mesh bodies' masks
    /// (`lattice_bodies`, `lattice_points` of `shaders/shared/lattice.wgsl`).
    Lattices {
        bodies: wgpu::Buffer,
        points: wgpu::Buffer,
    },
    /// Every other route.
    List(SpringList),
}

/// The spring list on the device and, on the per-spring route, what the per-spring kernels
/// write.
pub(crate) struct SpringList {
    /// CSR offsets then entries.
    pub adjacency: wgpu::Buffer,
    /// Spring records, one buffer per chunk.
    pub records: Vec<wgpu::Buffer>,
    /// The per-spring route's: `None` on the fused gather, which writes nothing per spring.
    pub writes: Option<PerSpringWrites>,
}

/// What the per-spring kernels write.
pub(crate) struct PerSpringWrites {
    /// Accelerations of the last force evaluation (the per-spring path's gather).
    pub a: wgpu::Buffer,
    /// Per-spring vectors (forces, implicit Euler's products), one buffer per chunk.
    pub per_spring: Vec<wgpu::Buffer>,
}

impl ModelBuffers {
    /// Uploads `model` and `state` (rounded to f32) for `route`: on the stencil route the
    /// lattices, otherwise the spring list split into `chunks`, with `spring_groups` energy
    /// partial sums of the springs.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        builder: &Builder,
        model: &Model,
        state: &State,
        route: Route,
        chunks: &SpringChunks,
        n_surfaces: u32,
        particle_groups: u64,
        spring_groups: u64,
        uniform_alignment: u32,
    ) -> ModelBuffers {
        let mass: Vec<[f32; 2]> = model
            .mass
            .iter()
            .zip(&model.inv_mass)
            .map(|(&m, &w)| [m as f32, w as f32])
            .collect();
        let step_stride = u64::from(uniform_alignment).max(std::mem::size_of::<StepIndex>() as u64);
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
        let params = Params::new(model, n_surfaces);
        let springs = match route {
            Route::Stencil => {
                let (bodies, points) = LatticeBodyGpu::pack(model.lattices());
                SpringBuffers::Lattices {
                    bodies: builder.storage_init(
                        "lattice_bodies",
                        bytemuck::cast_slice(&bodies),
                        std::mem::size_of::<LatticeBodyGpu>(),
                    ),
                    points: builder.storage_init(
                        "lattice_points",
                        bytemuck::cast_slice(&points),
                        4,
                    ),
                }
            }
            Route::Gather | Route::PerSpring => SpringBuffers::List(SpringList::new(
                builder,
                model,
                chunks,
                route == Route::PerSpring,
            )),
        };
        ModelBuffers {
            params: builder.init(
                "params",
                bytemuck::bytes_of(&params),
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            x: builder.storage_init("x", bytemuck::cast_slice(&vec4s(&state.x)), 16),
            v: builder.storage_init("v", bytemuck::cast_slice(&vec4s(&state.v)), 16),
            mass: builder.storage_init("mass", bytemuck::cast_slice(&mass), 8),
            springs,
            status: builder.storage_init("status", bytemuck::bytes_of(&Status::RESET), 16),
            step_indices: builder.init("step_indices", &step_indices, wgpu::BufferUsages::UNIFORM),
            step_stride,
            particle_partials: builder.storage("particle_partials", particle_groups, 8),
            spring_partials: builder.storage("spring_partials", spring_groups, 4),
        }
    }

    /// The spring list, `None` on the stencil route.
    pub fn list(&self) -> Option<&SpringList> {
        match &self.springs {
            SpringBuffers::List(list) => Some(list),
            SpringBuffers::Lattices { .. } => None,
        }
    }

    /// The buffers by their shader names, as the per-particle kernels bind them: the state,
    /// the model (the lattices, or the adjacency and the per-spring vectors' chunks for the
    /// gathers), the status and the step index (one slot: the dispatch picks which by its
    /// dynamic offset), the energy partials.
    pub fn resources(&self) -> Resources<'_> {
        let resources = Resources::default()
            .buffer("params", &self.params)
            .buffer("x", &self.x)
            .buffer("v", &self.v)
            .buffer("mass", &self.mass)
            .buffer("status", &self.status)
            .resource(
                "step_index",
                wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &self.step_indices,
                    offset: 0,
                    size: std::num::NonZeroU64::new(std::mem::size_of::<StepIndex>() as u64),
                }),
            )
            .buffer("particle_partials", &self.particle_partials)
            .buffer("spring_partials", &self.spring_partials);
        match &self.springs {
            SpringBuffers::Lattices { bodies, points } => resources
                .buffer("lattice_bodies", bodies)
                .buffer("lattice_points", points),
            SpringBuffers::List(list) => {
                let resources = resources.buffer("adjacency", &list.adjacency);
                match &list.writes {
                    Some(w) => resources.buffer("a", &w.a).chunks(
                        "per_spring",
                        "per_spring",
                        &w.per_spring,
                    ),
                    None => resources,
                }
            }
        }
    }

    /// [`ModelBuffers::resources`] as a per-spring kernel of chunk `c` binds them: its springs,
    /// its per-spring vectors (`per_spring`, or `per_spring_out` in `system.wgsl`) and its
    /// [`SpringChunk`](crate::layout::SpringChunk) uniform (`chunk`). On the stencil route,
    /// which has no per-spring array, only the latter: a per-spring kernel then fails to bind.
    pub fn chunk_resources<'a>(&'a self, chunks: &'a SpringChunks, c: usize) -> Resources<'a> {
        let resources = self.resources().resource("chunk", chunks.uniform(c));
        let Some(list) = self.list() else {
            return resources;
        };
        let resources = resources.buffer("springs", &list.records[c]);
        match &list.writes {
            Some(w) => resources
                .buffer("per_spring", &w.per_spring[c])
                .buffer("per_spring_out", &w.per_spring[c]),
            None => resources,
        }
    }
}

impl SpringList {
    /// The spring list of `model` (built on the host if it was not) split into `chunks`, and
    /// with `writes` the per-spring kernels' buffers.
    fn new(builder: &Builder, model: &Model, chunks: &SpringChunks, writes: bool) -> SpringList {
        let mut adjacency = model.adjacency().offsets.clone();
        adjacency.extend_from_slice(&model.adjacency().entries);
        let springs = SpringGpu::pack(model.springs());
        let spring_size = std::mem::size_of::<SpringGpu>();
        SpringList {
            adjacency: builder.storage_init("adjacency", bytemuck::cast_slice(&adjacency), 4),
            records: chunks
                .ranges
                .iter()
                .map(|&(base, count)| {
                    let (base, count) = (base as usize, count as usize);
                    builder.storage_init(
                        "springs",
                        bytemuck::cast_slice(&springs[base..base + count]),
                        spring_size,
                    )
                })
                .collect(),
            writes: writes.then(|| PerSpringWrites {
                a: builder.storage("a", model.len() as u64, VEC4),
                per_spring: chunks
                    .ranges
                    .iter()
                    .map(|&(_, count)| builder.storage("per_spring", count, VEC4))
                    .collect(),
            }),
        }
    }
}

/// Positions or velocities as the shaders store them.
pub(crate) fn vec4s(v: &[DVec3]) -> Vec<[f32; 4]> {
    v.iter()
        .map(|p| {
            let p = p.as_vec3();
            [p.x, p.y, p.z, 0.0]
        })
        .collect()
}

/// `vec4<f32>` bytes back as vectors.
pub(crate) fn to_vec3(bytes: &[u8]) -> Vec<Vec3> {
    let v: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(bytes);
    v.iter().map(|p| Vec3::new(p[0], p[1], p[2])).collect()
}

/// `vec4<f32>` bytes back as f64 vectors.
pub(crate) fn to_dvec3(bytes: &[u8]) -> Vec<DVec3> {
    to_vec3(bytes).into_iter().map(|p| p.as_dvec3()).collect()
}
