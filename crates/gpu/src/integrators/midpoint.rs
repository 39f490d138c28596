//! `shaders/midpoint.wgsl` ↔ `softbody_cpu::integrators::midpoint`: y_m = y + (h/2) y'(y),
//! then y ← y + h y'(y_m), on y = (x, v), y' = (v, a(x, v)).

use super::ExplicitStep;
use crate::builder::Setup;
use crate::forces::Accelerations;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::{GpuError, VEC4};

/// The midpoint method: its stage state y_m and calls.
pub(crate) struct Midpoint {
    forces: Accelerations,
    stage_forces: Accelerations,
    to_midpoint: Call,
    update: Call,
    grid: Grid,
}

impl Midpoint {
    /// Its stage buffers and calls.
    pub fn new(s: Setup<'_>) -> Result<Midpoint, GpuError> {
        let b = s.buffers;
        let stage_x = s.builder.storage("stage_x", s.n, VEC4);
        let stage_v = s.builder.storage("stage_v", s.n, VEC4);
        let resources = b
            .resources()
            .buffer("stage_x", &stage_x)
            .buffer("stage_v", &stage_v);
        Ok(Midpoint {
            forces: Accelerations::new(s, &b.x, &b.v)?,
            stage_forces: Accelerations::new(s, &stage_x, &stage_v)?,
            to_midpoint: s
                .builder
                .call(Stage::Midpoint, "midpoint_stage", &resources)?,
            update: s
                .builder
                .call(Stage::Midpoint, "midpoint_update", &resources)?,
            grid: s.particles,
        })
    }
}

impl ExplicitStep for Midpoint {
    fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.forces.encode(pass);
        self.to_midpoint.run(pass, self.grid);
        self.stage_forces.encode(pass);
        self.update.run(pass, self.grid);
    }
}
