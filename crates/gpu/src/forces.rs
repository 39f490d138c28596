//! `shaders/forces.wgsl` ↔ `softbody_cpu::forces`: a(x, v) = f(x, v)/m with
//!
//! f = m g − drag·m·v + Σ_springs ±f_s (gathered in ascending spring order) + contact and
//! friction (`shaders/contact.wgsl` ↔ `softbody_cpu::contact`),
//!
//! after the spring forces of the same state; pinned particles get a = 0.

use crate::GpuError;
use crate::builder::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::spring_forces::SpringForces;

/// The accelerations of one state, into the solver's `a`.
pub(crate) struct Accelerations {
    spring_forces: SpringForces,
    accelerations: Call,
    grid: Grid,
}

impl Accelerations {
    /// The accelerations at the state `(x, v)`: the solver's, or a stage state.
    pub fn new(
        s: Setup<'_>,
        x: &wgpu::Buffer,
        v: &wgpu::Buffer,
    ) -> Result<Accelerations, GpuError> {
        let resources = s.buffers.resources().buffer("x", x).buffer("v", v);
        Ok(Accelerations {
            spring_forces: SpringForces::new(s, x, v)?,
            accelerations: s.builder.call(Stage::Forces, "accelerations", &resources)?,
            grid: s.particles,
        })
    }

    /// The spring forces alone.
    #[cfg(feature = "debug")]
    pub fn spring_forces(&self) -> &SpringForces {
        &self.spring_forces
    }

    /// Encodes the spring forces, then the accelerations.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.spring_forces.encode(pass);
        self.accelerations.run(pass, self.grid);
    }
}
