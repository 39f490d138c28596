//! `shaders/explicit.wgsl` (without `fused`) ↔ `softbody_cpu::integrators::{explicit_euler,
//! symplectic_euler, midpoint, rk4}`: the explicit integrators on the per-spring path, each
//! stage of a method the forces of a state ([`Accelerations`]: the spring forces per spring,
//! then the gather) followed by the stage's update, one thread per particle:
//!
//! | integrator | dispatches of a step |
//! |---|---|
//! | explicit / symplectic Euler | forces(x, v) → update |
//! | midpoint | forces(x, v) → `midpoint_stage` → forces(stage) → `midpoint_update` |
//! | RK4 | forces(x, v) → `rk4_first` → forces(stage) → `rk4_second` → forces(stage) → `rk4_third` → forces(stage) → `rk4_last` |
//!
//! The first stage evaluates the forces at the solver's (x, v), each further one at the stage
//! state the previous update wrote; RK4 keeps its weighted sum in two more buffers as the stages
//! go. The path serves models whose bodies touch (their pair forces need the broad phase's grid
//! of each stage's state) and adapters that cannot bind the fused kernels' buffers.

use softbody_scene::Integrator;

use super::entries;
use crate::body_contact::BodyContact;
use crate::buffers::Setup;
use crate::forces::Accelerations;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::{GpuError, VEC4};

/// An explicit integrator on the per-spring path: its stage buffers and calls.
pub(crate) struct PerSpring {
    /// The accelerations at the solver's state, then (for the methods of several stages) at
    /// the stage state.
    forces: Vec<Accelerations>,
    /// Each stage's update, in the order of a step.
    updates: Vec<Call>,
    grid: Grid,
}

impl PerSpring {
    /// `integrator`'s stage state (midpoint, RK4) and running sums (RK4), and its calls; the
    /// forces add the pairs' of `contact`.
    pub fn new(
        s: Setup<'_>,
        contact: Option<&BodyContact>,
        integrator: Integrator,
    ) -> Result<PerSpring, GpuError> {
        let b = s.buffers;
        let entries = entries(integrator);
        let vectors = |label| s.builder.storage(label, s.n, VEC4);
        let stage = (entries.len() > 1).then(|| (vectors("stage_x"), vectors("stage_v")));
        let sums = (integrator == Integrator::Rk4).then(|| (vectors("sum_x"), vectors("sum_v")));
        let mut resources = b.resources();
        let mut forces = vec![Accelerations::new(s, contact, &b.x, &b.v)?];
        if let Some((x, v)) = &stage {
            resources = resources.buffer("stage_x", x).buffer("stage_v", v);
            forces.push(Accelerations::new(s, contact, x, v)?);
        }
        if let Some((x, v)) = &sums {
            resources = resources.buffer("sum_x", x).buffer("sum_v", v);
        }
        let updates = entries
            .iter()
            .map(|entry| s.builder.call(Stage::Explicit, entry, &resources))
            .collect::<Result<_, _>>()?;
        Ok(PerSpring {
            forces,
            updates,
            grid: s.particles,
        })
    }

    /// Encodes one step's force evaluations and updates.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>) {
        for (k, update) in self.updates.iter().enumerate() {
            self.forces[k.min(1)].encode(pass);
            update.run(pass, self.grid);
        }
    }
}
