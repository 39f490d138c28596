//! `shaders/check_finite.wgsl` ↔ `softbody_cpu::first_non_finite`: the instability check after
//! every step.
//!
//! It records, on the device, the first step of the submission with a non-finite value and
//! the lowest particle holding one. The step number is known when the step is encoded: a
//! constant uniform table holds 1, 2, …, [`STEPS_PER_SUBMISSION`], one per aligned slot, and
//! each step's check binds its slot with a dynamic offset, which costs neither a dispatch nor a
//! host write per step. The host resets the status before each submission and reads it after
//! it: an instability is reported with the exact step, time and particle the CPU would report.

use crate::buffers::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::{GpuError, STEPS_PER_SUBMISSION};

/// The instability check of the solver's state.
pub(crate) struct CheckFinite {
    call: Call,
    grid: Grid,
    /// Bytes between the step index slots.
    stride: u64,
}

impl CheckFinite {
    /// The check of the solver's state.
    pub fn new(s: Setup<'_>) -> Result<CheckFinite, GpuError> {
        Ok(CheckFinite {
            call: s
                .builder
                .call(Stage::CheckFinite, "check_finite", &s.buffers.resources())?,
            grid: s.particles,
            stride: s.buffers.step_stride,
        })
    }

    /// Encodes the check of step `k` (0-based) of a submission.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>, k: u64) {
        debug_assert!(k < STEPS_PER_SUBMISSION);
        self.call
            .run_at(pass, self.grid, &[(k * self.stride) as u32]);
    }
}
