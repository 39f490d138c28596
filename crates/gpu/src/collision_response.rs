//! `shaders/collision_response.wgsl` ↔ `softbody_cpu::collision_response`: after an explicit
//! step, a particle within the contact band of a surface has its approach velocity reflected
//! (scaled by the restitution) and is moved back onto the surface (x ← x − φN where φ < 0).

use crate::GpuError;
use crate::builder::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// The collision response of the solver's state.
pub(crate) struct CollisionResponse {
    call: Call,
    grid: Grid,
}

impl CollisionResponse {
    /// The response of the solver's state.
    pub fn new(s: Setup<'_>) -> Result<CollisionResponse, GpuError> {
        Ok(CollisionResponse {
            call: s.builder.call(
                Stage::CollisionResponse,
                "collision_response",
                &s.buffers.resources(),
            )?,
            grid: s.particles,
        })
    }

    /// Encodes the dispatch.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.call.run(pass, self.grid);
    }
}
