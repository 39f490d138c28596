//! The model and state on the device: the buffers every stage shares, and the table that binds
//! them by the names the shaders use.
//!
//! Vectors are `vec4<f32>` (w = 0); masses are `vec2(m, 1/m)` and the CSR adjacency is its
//! offsets followed by its entries in one `u32` buffer, which keeps the force kernel at 8
//! storage buffers with the terrain's (WebGPU's guaranteed minimum).

use glam::{DVec3, Vec3};
use softbody_scene::{Model, State};

use crate::builder::Builder;
use crate::chunks::SpringChunks;
use crate::kernel::Resources;
use crate::layout::{Params, SpringGpu, Status, StepIndex};
use crate::{STEPS_PER_SUBMISSION, VEC4, WORKGROUP_SIZE};

/// The buffers of the model and state.
pub(crate) struct ModelBuffers {
    /// [`Params`].
    pub params: wgpu::Buffer,
    /// Positions.
    pub x: wgpu::Buffer,
    /// Velocities.
    pub v: wgpu::Buffer,
    /// Accelerations of the last force evaluation.
    pub a: wgpu::Buffer,
    /// (m, 1/m) per particle.
    pub mass: wgpu::Buffer,
    /// CSR offsets then entries.
    pub adjacency: wgpu::Buffer,
    /// Spring records, one buffer per chunk.
    pub springs: Vec<wgpu::Buffer>,
    /// Per-spring vectors (forces, implicit Euler's products), one buffer per chunk.
    pub per_spring: Vec<wgpu::Buffer>,
    /// The instability record of a submission.
    pub status: wgpu::Buffer,
    /// [`StepIndex`] 1..=[`STEPS_PER_SUBMISSION`], one per `step_stride` bytes.
    pub step_indices: wgpu::Buffer,
    /// Bytes between consecutive [`StepIndex`] slots (the uniform offset alignment).
    pub step_stride: u64,
    /// Per-workgroup partial sums of the particle energies.
    pub particle_partials: wgpu::Buffer,
    /// Per-workgroup partial sums of the spring energies.
    pub spring_partials: wgpu::Buffer,
}

impl ModelBuffers {
    /// Uploads `model` and `state` (rounded to f32), split into `chunks`.
    pub fn new(
        builder: &Builder,
        model: &Model,
        state: &State,
        chunks: &SpringChunks,
        n_surfaces: u32,
        particle_groups: u64,
        uniform_alignment: u32,
    ) -> ModelBuffers {
        let n = model.len() as u64;
        let mut adjacency = model.adjacency().offsets.clone();
        adjacency.extend_from_slice(&model.adjacency().entries);
        let mass: Vec<[f32; 2]> = model
            .mass
            .iter()
            .zip(&model.inv_mass)
            .map(|(&m, &w)| [m as f32, w as f32])
            .collect();
        let springs = SpringGpu::pack(model.springs());
        let spring_size = std::mem::size_of::<SpringGpu>();
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
        ModelBuffers {
            params: builder.init(
                "params",
                bytemuck::bytes_of(&params),
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            x: builder.storage_init("x", bytemuck::cast_slice(&vec4s(&state.x)), 16),
            v: builder.storage_init("v", bytemuck::cast_slice(&vec4s(&state.v)), 16),
            a: builder.storage("a", n, VEC4),
            mass: builder.storage_init("mass", bytemuck::cast_slice(&mass), 8),
            adjacency: builder.storage_init("adjacency", bytemuck::cast_slice(&adjacency), 4),
            springs: chunks
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
            per_spring: chunks
                .ranges
                .iter()
                .map(|&(_, count)| builder.storage("per_spring", count, VEC4))
                .collect(),
            status: builder.storage_init("status", bytemuck::bytes_of(&Status::RESET), 16),
            step_indices: builder.init("step_indices", &step_indices, wgpu::BufferUsages::UNIFORM),
            step_stride,
            particle_partials: builder.storage("particle_partials", particle_groups, 8),
            spring_partials: builder.storage(
                "spring_partials",
                (model.springs().len() as u64).div_ceil(WORKGROUP_SIZE),
                4,
            ),
        }
    }

    /// The buffers by their shader names, as the per-particle kernels bind them: the state,
    /// the model, the per-spring vectors' chunks for the gathers, the status and the step index
    /// (one slot: the dispatch picks which by its dynamic offset), the energy partials.
    pub fn resources(&self) -> Resources<'_> {
        Resources::default()
            .buffer("params", &self.params)
            .buffer("x", &self.x)
            .buffer("v", &self.v)
            .buffer("a", &self.a)
            .buffer("mass", &self.mass)
            .buffer("adjacency", &self.adjacency)
            .chunks("per_spring", "per_spring", &self.per_spring)
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
            .buffer("spring_partials", &self.spring_partials)
    }

    /// [`ModelBuffers::resources`] as a per-spring kernel of chunk `c` binds them: its springs,
    /// its per-spring vectors (`per_spring`, or `per_spring_out` in `system.wgsl`) and its
    /// [`SpringChunk`](crate::layout::SpringChunk) uniform (`chunk`).
    pub fn chunk_resources<'a>(&'a self, chunks: &'a SpringChunks, c: usize) -> Resources<'a> {
        self.resources()
            .buffer("springs", &self.springs[c])
            .buffer("per_spring", &self.per_spring[c])
            .buffer("per_spring_out", &self.per_spring[c])
            .resource("chunk", chunks.uniform(c))
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
