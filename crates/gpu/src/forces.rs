//! `shaders/forces.wgsl` ↔ `softbody_cpu::forces`: a(x, v) = f(x, v)/m with
//!
//! f = m g − drag·m·v + Σ_springs ±f_s (gathered in ascending spring order) + contact and
//! friction (`shaders/shared/contact.wgsl` ↔ `softbody_cpu::contact`),
//!
//! after the spring forces of the same state, and for models whose bodies touch after the
//! pairs' penalty forces ([`crate::body_contact`]), which the springs' sum takes in; pinned
//! particles get a = 0.

use crate::GpuError;
use crate::body_contact::BodyContact;
use crate::buffers::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::spring_forces::SpringForces;

/// The accelerations of one state, into the solver's `a`.
pub(crate) struct Accelerations {
    spring_forces: SpringForces,
    /// The penalty forces between bodies, into `a`, for models whose bodies touch.
    pair_forces: Option<Call>,
    accelerations: Call,
    grid: Grid,
}

impl Accelerations {
    /// The accelerations at the state `(x, v)`: the solver's, or a stage state; with the
    /// penalty forces of the pairs of `contact`, for models whose bodies touch.
    pub fn new(
        s: Setup<'_>,
        contact: Option<&BodyContact>,
        x: &wgpu::Buffer,
        v: &wgpu::Buffer,
    ) -> Result<Accelerations, GpuError> {
        let resources = s.buffers.resources().buffer("x", x).buffer("v", v);
        let pair_forces = contact
            .map(|contact| contact.pair_forces(s, x, v))
            .transpose()?;
        let entry = if pair_forces.is_some() {
            "accelerations_with_pairs"
        } else {
            "accelerations"
        };
        Ok(Accelerations {
            spring_forces: SpringForces::new(s, x, v)?,
            pair_forces,
            accelerations: s.builder.call(Stage::Forces, entry, &resources)?,
            grid: s.particles,
        })
    }

    /// The spring forces alone.
    #[cfg(feature = "debug")]
    pub fn spring_forces(&self) -> &SpringForces {
        &self.spring_forces
    }

    /// Encodes the spring forces, the pair forces, then the accelerations.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.spring_forces.encode(pass);
        if let Some(pair_forces) = &self.pair_forces {
            pair_forces.run(pass, self.grid);
        }
        self.accelerations.run(pass, self.grid);
    }
}
