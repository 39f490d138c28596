//! `shaders/explicit.wgsl` with `fused` ↔ `softbody_cpu::pipeline`: the explicit integrators with
//! one dispatch per stage — each thread gathers its springs' forces from its neighbours, updates
//! its particle, and after a step's last stage responds to the terrain and checks finiteness — in
//! place of the per-spring path's spring forces → gather → update → collision response → check (5
//! dispatches per symplectic-Euler step, 2 + 3 per further force evaluation).
//!
//! | integrator | dispatches of a step |
//! |---|---|
//! | explicit / symplectic Euler | y → y' (the second pair; the next step goes back) |
//! | midpoint | `midpoint_stage` y → y_m, `midpoint_update` y_m → y |
//! | RK4 | `rk4_first` y → y₁, `rk4_second` y₁ → y₂, `rk4_third` y₂ → y₁, `rk4_last` y₁ → y |
//!
//! A kernel reads its neighbours from one pair of buffers and writes another, so no thread
//! reads what another writes. The Euler methods have a single stage, so their steps alternate
//! between the solver's (x, v) and a second pair; a submission of an odd number of steps ends
//! with a copy back, so that every submission starts and ends in (x, v), where the energies,
//! the read-backs and `set_state` find the state ([`Fused::end_batch`]; the solver makes
//! batches even where it can, [`Fused::steps_per_cycle`]). Midpoint and RK4 end their steps in
//! place: their last stage reads the neighbours from a stage state and writes only its own
//! particle of (x, v).
//!
//! On the stencil route ([`crate::buffers::Route`]: every body a lattice, cuboids and mesh
//! bodies) the kernels find their springs on the lattices (`Stage::FusedStencil`,
//! `shaders/shared/stencil.wgsl`): per body a table of its offsets' parameters and their two
//! orders, per mesh body its mask, and no spring record or adjacency read — the same sums bit for
//! bit ("fused stencil"; otherwise "fused gather").

use std::sync::Arc;

use softbody_scene::Integrator;

use super::entries;
use crate::buffers::{Setup, SpringBuffers};
use crate::grid::Grid;
use crate::kernel::{Call, Resources, Traffic};
use crate::shaders::Stage;
use crate::{GpuError, STEPS_PER_SUBMISSION, VEC4};

/// A pair of position and velocity buffers.
type Pair<'a> = (&'a wgpu::Buffer, &'a wgpu::Buffer);

/// An explicit integrator as fused stages.
pub(crate) struct Fused {
    /// The calls of consecutive steps, one list per step of the cycle (two steps for the Euler
    /// methods, one for midpoint and RK4); each list's last call ends the step.
    cycle: Vec<Vec<Call>>,
    /// The Euler methods' second pair.
    other: Option<(wgpu::Buffer, wgpu::Buffer)>,
    /// The solver's (x, v).
    state: (wgpu::Buffer, wgpu::Buffer),
    /// Bytes of one of (x, v).
    bytes: u64,
    traffic: Arc<Traffic>,
    grid: Grid,
    /// Bytes between the step index slots.
    stride: u64,
    /// Whether the springs are found on the lattices.
    stencil: bool,
}

impl Fused {
    /// `integrator` fused, with the collision response's record of each step's start in
    /// `start` (None without terrain), gathering by the stencil of the lattices where the
    /// buffers hold them (the stencil route), through the spring records otherwise. Fails with
    /// [`GpuError::Limit`] before allocating anything where the adapter cannot bind its
    /// kernels' buffers: the per-spring path then serves.
    pub fn new(
        s: Setup<'_>,
        integrator: Integrator,
        start: Option<&wgpu::Buffer>,
    ) -> Result<Fused, GpuError> {
        let b = s.buffers;
        let (stage, stencil) = match &b.springs {
            SpringBuffers::Lattices { .. } => (Stage::FusedStencil, true),
            SpringBuffers::List(_) => (Stage::FusedStep, false),
        };
        let entries = entries(integrator);
        for entry in entries {
            s.builder.fits(stage, entry)?;
        }
        let pair = |label: &str| {
            (
                s.builder.storage(&format!("{label}_x"), s.n, VEC4),
                s.builder.storage(&format!("{label}_v"), s.n, VEC4),
            )
        };
        // Without terrain the kernels never touch `start`, but bind it.
        let placeholder;
        let start = match start {
            Some(start) => start,
            None => {
                placeholder = s.builder.storage("start", 1, 16);
                &placeholder
            }
        };
        // The lattices are among the buffers' own resources; the gather reads every chunk of
        // the spring records.
        let resources = b.resources().buffer("start", start);
        let resources = match b.list() {
            Some(list) => resources.chunks("springs", "spring", &list.records),
            None => resources,
        };
        let call = |r: &Resources<'_>, entry, from: Pair<'_>, to: Pair<'_>| {
            let r = r
                .clone()
                .buffer("x", from.0)
                .buffer("v", from.1)
                .buffer("x_next", to.0)
                .buffer("v_next", to.1);
            s.builder.call(stage, entry, &r)
        };
        let y = (&b.x, &b.v);
        let mut other = None;
        let cycle = match integrator {
            Integrator::ExplicitEuler | Integrator::SymplecticEuler => {
                let entry = entries[0];
                let next = pair("next");
                let y_next = (&next.0, &next.1);
                let cycle = vec![
                    vec![call(&resources, entry, y, y_next)?],
                    vec![call(&resources, entry, y_next, y)?],
                ];
                other = Some(next);
                cycle
            }
            Integrator::Midpoint => {
                let stage = pair("stage");
                let y_m = (&stage.0, &stage.1);
                vec![vec![
                    call(&resources, "midpoint_stage", y, y_m)?,
                    call(&resources, "midpoint_update", y_m, y)?,
                ]]
            }
            Integrator::Rk4 => {
                let (first, second) = (pair("stage"), pair("stage2"));
                let (y1, y2) = ((&first.0, &first.1), (&second.0, &second.1));
                let (sum_x, sum_v) = pair("sum");
                let r = resources
                    .buffer("base_x", &b.x)
                    .buffer("base_v", &b.v)
                    .buffer("sum_x", &sum_x)
                    .buffer("sum_v", &sum_v);
                vec![vec![
                    call(&r, "rk4_first", y, y1)?,
                    call(&r, "rk4_second", y1, y2)?,
                    call(&r, "rk4_third", y2, y1)?,
                    call(&r, "rk4_last", y1, y)?,
                ]]
            }
            Integrator::ImplicitEuler => unreachable!("implicit Euler is not fused"),
        };
        Ok(Fused {
            cycle,
            other,
            state: (b.x.clone(), b.v.clone()),
            bytes: s.n * VEC4,
            traffic: Arc::clone(s.builder.traffic()),
            grid: s.particles,
            stride: b.step_stride,
            stencil,
        })
    }

    /// The design, for `Statistics::kernel`.
    pub fn kernel(&self) -> &'static str {
        if self.stencil {
            "fused stencil"
        } else {
            "fused gather"
        }
    }

    /// Steps after which the state is back in the solver's (x, v) without a copy.
    pub fn steps_per_cycle(&self) -> u64 {
        self.cycle.len() as u64
    }

    /// Encodes step `k` (0-based) of a submission: its stages, the last with the step's slot
    /// of the finiteness record.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>, k: u64) {
        debug_assert!(k < STEPS_PER_SUBMISSION);
        let calls = &self.cycle[(k % self.steps_per_cycle()) as usize];
        let (last, stages) = calls.split_last().expect("a step has a stage");
        for call in stages {
            call.run(pass, self.grid);
        }
        last.run_at(pass, self.grid, &[(k * self.stride) as u32]);
    }

    /// After a submission of `steps` steps: brings the state back into the solver's (x, v)
    /// where an odd number of Euler steps left it in the second pair.
    pub fn end_batch(&self, encoder: &mut wgpu::CommandEncoder, steps: u64) {
        let Some((x, v)) = &self.other else {
            return;
        };
        if steps % 2 == 1 {
            encoder.copy_buffer_to_buffer(x, 0, &self.state.0, 0, self.bytes);
            encoder.copy_buffer_to_buffer(v, 0, &self.state.1, 0, self.bytes);
            self.traffic.copied(4 * self.bytes);
        }
    }
}
