//! `shaders/collision_response.wgsl` ↔ `softbody_cpu::collision_response`: after an explicit
//! step, a particle within the contact band of a surface has its approach velocity reflected
//! (scaled by the restitution on a fresh impact only) and is moved back onto the surface
//! (x ← x − φN where φ < 0).
//!
//! Whether an impact is fresh depends on the particle at the start of the step (the bands it lay
//! in, its velocity): the CPU has the start state at hand; here each response leaves its
//! particle's final velocity and band mask (16 bytes per particle, `start`), which are the next
//! step's start. `contact_band` computes them from the state when there was no previous step
//! (the first, and after `set_state`).

use crate::GpuError;
use crate::buffers::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// The collision response of the solver's state and its record of the step's start.
pub(crate) struct CollisionResponse {
    /// Each particle's start of the step (velocity, band mask), which the fused step's last
    /// stage also reads and renews.
    pub start: wgpu::Buffer,
    call: Call,
    band: Call,
    grid: Grid,
}

impl CollisionResponse {
    /// The response of the solver's state.
    pub fn new(s: Setup<'_>) -> Result<CollisionResponse, GpuError> {
        let start = s.builder.storage("start", s.n, 16);
        let resources = s.buffers.resources().buffer("start", &start);
        let stage = Stage::CollisionResponse;
        Ok(CollisionResponse {
            call: s.builder.call(stage, "collision_response", &resources)?,
            band: s.builder.call(stage, "contact_band", &resources)?,
            grid: s.particles,
            start,
        })
    }

    /// Encodes the start record of the state, for a state that no response left.
    pub fn encode_band(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.band.run(pass, self.grid);
    }

    /// Encodes the response.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.call.run(pass, self.grid);
    }
}
