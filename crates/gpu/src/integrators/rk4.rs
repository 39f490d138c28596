//! `shaders/rk4.wgsl` ↔ `softbody_cpu::integrators::rk4`: classic fourth-order Runge–Kutta on
//! y = (x, v), y' = (v, a(x, v)): k1 = y'(y), k2 = y'(y + h/2 k1), k3 = y'(y + h/2 k2),
//! k4 = y'(y + h k3), y ← y + h/6 (k1 + 2k2 + 2k3 + k4), the weighted sum accumulated as the
//! stages go.

use super::ExplicitStep;
use crate::builder::Setup;
use crate::forces::Accelerations;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::{GpuError, VEC4};

/// RK4: its stage state, running sums and calls.
pub(crate) struct Rk4 {
    forces: Accelerations,
    stage_forces: Accelerations,
    /// `rk4_first`, then the updates after the forces at each stage state.
    first: Call,
    after_stage: [Call; 3],
    grid: Grid,
}

impl Rk4 {
    /// Its stage and sum buffers and calls.
    pub fn new(s: Setup<'_>) -> Result<Rk4, GpuError> {
        let b = s.buffers;
        let vectors = |label| s.builder.storage(label, s.n, VEC4);
        let (stage_x, stage_v) = (vectors("stage_x"), vectors("stage_v"));
        let (sum_x, sum_v) = (vectors("sum_x"), vectors("sum_v"));
        let resources = b
            .resources()
            .buffer("stage_x", &stage_x)
            .buffer("stage_v", &stage_v)
            .buffer("sum_x", &sum_x)
            .buffer("sum_v", &sum_v);
        let call = |entry| s.builder.call(Stage::Rk4, entry, &resources);
        Ok(Rk4 {
            forces: Accelerations::new(s, &b.x, &b.v)?,
            stage_forces: Accelerations::new(s, &stage_x, &stage_v)?,
            first: call("rk4_first")?,
            after_stage: [call("rk4_second")?, call("rk4_third")?, call("rk4_last")?],
            grid: s.particles,
        })
    }
}

impl ExplicitStep for Rk4 {
    fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.forces.encode(pass);
        self.first.run(pass, self.grid);
        for update in &self.after_stage {
            self.stage_forces.encode(pass);
            update.run(pass, self.grid);
        }
    }
}
