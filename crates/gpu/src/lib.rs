//! The GPU solver of `softbody`: the model of `softbody-scene` stepped by wgpu compute shaders,
//! in f32.
//!
//! The shaders live in the crate's `shaders/`, one file per stage, each named like its CPU twin
//! in `softbody-cpu` and stating the equation it implements, and the pieces they import in
//! `shaders/shared/`; they are compiled into the binary and composed per stage by [`shaders`]. [`GpuSolver`] implements the same
//! [`Solver`](softbody_scene::Solver) trait as the CPU solver, so the CLI and the run driver do not
//! know which one runs. The crate is laid out by stage like `softbody-cpu` (`spring_forces`,
//! `forces`, `collision_response`, `check_finite`, `energy`, `integrators/…`); `solver` wires
//! them into the per-step dispatch sequence (see ARCHITECTURE.md for the table of both
//! backends).
//!
//! Everything is a gather or an element-wise update, with no float atomics, and reductions add
//! per-workgroup partial sums in order (on the host for the energies, on the device for implicit
//! Euler's CG): a run repeats bit for bit on one adapter. Implicit Euler solves to
//! [`CG_TOLERANCE_F32`] instead of the CPU's 1e-8.
//! Results differ from the CPU's f64 by f32 rounding (see the adapter tests for the measured
//! agreement).
//!
//! Without an adapter [`GpuSolver::new`] fails with [`GpuError::NoAdapter`], which says which
//! backends were tried and how to get a software adapter.
//!
//! # Layers
//!
//! A module uses (`use crate::…`) only modules of its own layer or of the layers above it in
//! this table, and the crate root's own items (`GpuError`, `WORKGROUP_SIZE`, `VEC4`,
//! `STEPS_PER_SUBMISSION`), which every layer shares:
//!
//! | layer | modules | what they are |
//! |---|---|---|
//! | runtime and plain data | `device`, `submit`, `limits`, `layout`, `terrain`, `grid`, `chunks` | the adapter, its queue and what it allows; the host's twins of the WGSL structs and how the data is laid out for them |
//! | shaders and kernels | `compose`, `shaders`, `kernel` | the WGSL composed per stage; kernels, their bindings read from it |
//! | builder | `builder`, `buffers` | buffers and calls; the model and state on the device, and `Setup`, what a stage is built from |
//! | stages | `spring_forces`, `forces`, `collision_response`, `check_finite`, `energy`, `broad_phase`, `body_contact` | one module per stage of a step, each the twin of `softbody-cpu`'s |
//! | integrators | `integrators/…` | the steps, made of the stages |
//! | solver | `plan`, `solver`, `debug` | the plan of a solver, the solver built from it, the stage read-backs |
//!
//! What a stage needs of another (the forces the contact between bodies, say) is handed to it
//! by the layer that builds both, not kept in `Setup`.
#![warn(missing_docs)]

pub mod body_contact;
mod broad_phase;
mod buffers;
mod builder;
mod check_finite;
pub mod chunks;
mod collision_response;
mod compose;
#[cfg(feature = "debug")]
pub mod debug;
pub mod device;
mod energy;
mod forces;
pub mod grid;
mod integrators;
mod kernel;
pub mod layout;
mod limits;
mod plan;
pub mod shaders;
mod solver;
mod spring_forces;
mod submit;
pub mod terrain;

pub use device::{ADAPTER_VARIABLE, Gpu};
pub use grid::Grid;
pub use integrators::implicit_euler::CG_TOLERANCE_F32;
pub use plan::GpuOptions;
pub use solver::GpuSolver;

/// Steps encoded into one command buffer at most (the check's table of step numbers).
pub const STEPS_PER_SUBMISSION: u64 = 256;

/// Why [`GpuSolver`] takes no control forces (`Solver::set_controls`), as the run service says
/// it before the device opens.
pub const NO_CONTROLS: &str = "control forces are not built on the GPU backend yet; run on the CPU";

/// Threads per workgroup of every kernel (`WORKGROUP_SIZE` in `shaders/shared/common.wgsl`; the
/// kernels are checked against it when their pipelines are made).
pub const WORKGROUP_SIZE: u64 = 256;

/// Bytes of a `vec4<f32>`, the storage element of every vector.
const VEC4: u64 = 16;

/// Why the GPU solver could not be opened.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GpuError {
    /// No adapter (or none that runs compute shaders).
    #[error(
        "no GPU adapter found (backends tried: {tried}): {detail}; for a software adapter install \
         the Debian package mesa-vulkan-drivers (lavapipe, Vulkan), or run on the CPU with \
         --backend cpu"
    )]
    NoAdapter {
        /// The backends tried, e.g. "Vulkan, GL".
        tried: String,
        /// What wgpu said.
        detail: String,
    },
    /// The scene exceeds one of the adapter's limits.
    #[error(
        "the scene exceeds the GPU's {limit}: {what} needs {needed}, {adapter} allows \
         {available}; use a smaller scene or --backend cpu"
    )]
    Limit {
        /// The adapter.
        adapter: String,
        /// The wgpu limit, e.g. "max_storage_buffer_binding_size".
        limit: &'static str,
        /// What needs it.
        what: String,
        /// How much it needs, with the unit.
        needed: String,
        /// What the adapter allows.
        available: String,
    },
    /// The scene asks for something the GPU solver does not do.
    #[error("{0}")]
    Unsupported(String),
    /// The device could not be opened, or the buffers and pipelines not created.
    #[error("GPU failure on {adapter}: {message}")]
    Device {
        /// The adapter.
        adapter: String,
        /// What went wrong.
        message: String,
    },
}

impl GpuError {
    /// Whether no usable GPU was found: no adapter, or a device that cannot run the solver.
    /// `false` when the GPU works but refuses this scene (limits, unsupported integrator).
    pub fn no_usable_gpu(&self) -> bool {
        matches!(self, GpuError::NoAdapter { .. } | GpuError::Device { .. })
    }
}

#[cfg(test)]
mod wgsl_tests;
