//! `shaders/spring_forces.wgsl` ↔ `softbody_cpu::spring_forces`: one force per spring,
//!
//! f_a = −[k_s(|d| − r) + k_d((v_a − v_b)·l)] l,  d = x_a − x_b,  l = d/|d|,
//!
//! written into the per-spring vectors (f_b = −f_a is the gather's), one dispatch per spring
//! chunk.

use crate::GpuError;
use crate::buffers::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// The spring forces of one state.
pub(crate) struct SpringForces {
    /// One call per spring chunk, with its grid.
    calls: Vec<(Call, Grid)>,
}

impl SpringForces {
    /// The spring forces of the state `(x, v)`: the solver's, or a stage state.
    pub fn new(s: Setup<'_>, x: &wgpu::Buffer, v: &wgpu::Buffer) -> Result<SpringForces, GpuError> {
        let calls = s.per_chunk(Stage::SpringForces, "spring_forces", |_, r| {
            r.buffer("x", x).buffer("v", v)
        })?;
        Ok(SpringForces {
            calls: calls
                .into_iter()
                .zip(s.chunks.grids.iter().copied())
                .collect(),
        })
    }

    /// Encodes the dispatches.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        for (call, grid) in &self.calls {
            call.run(pass, *grid);
        }
    }
}
