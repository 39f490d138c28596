//! `shaders/cg.wgsl` ↔ `softbody_cpu::integrators::implicit_euler::cg`: filtered,
//! block-Jacobi-preconditioned conjugate gradients for A Δv = rhs, the CPU's loop operation for
//! operation in f32, its scalars on the device.
//!
//! A solve starts with a round (`cg_start`: the warm start; A Δv; `cg_residual`; `cg_begin`),
//! then runs batches of iterations (A c → `cg_curvature` → `cg_advance` → `cg_direction`: four
//! dispatches besides the product's; the workgroups of `cg_advance` each compute α from the
//! partial sums of cᵀq, and those of `cg_direction` β from those of rᵀP⁻¹r, which spares two
//! one-workgroup kernels per iteration). The product, `cg_curvature` and `cg_advance` are
//! dispatched indirectly from the argument slots that `cg_begin` and `cg_direction` rewrite:
//! full grids while the solve runs, empty ones once it is done, so a batch of iterations is one
//! submission whatever the solve needs. `cg_direction` binds those slots, so it runs on the full
//! grid, whose workgroups return at once once the solve is done.

use super::system::{System, Vector};
use super::{Buffers, SLOTS_RUNNING};
use crate::GpuError;
use crate::builder::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// The CG kernels' calls.
pub(crate) struct Cg {
    start: Call,
    residual: Call,
    begin: Call,
    curvature: Call,
    advance: Call,
    direction: Call,
    particles: Grid,
    dispatch: wgpu::Buffer,
}

/// The one workgroup of the scalar kernels.
const ONE: Grid = Grid { x: 1, y: 1 };

impl Cg {
    /// The CG's calls over the implicit buffers `im`.
    pub fn new(s: Setup<'_>, im: &Buffers) -> Result<Cg, GpuError> {
        let resources = im.resources(s.buffers.resources());
        let call = |entry| s.builder.call(Stage::Cg, entry, &resources);
        Ok(Cg {
            start: call("cg_start")?,
            residual: call("cg_residual")?,
            begin: call("cg_begin")?,
            curvature: call("cg_curvature")?,
            advance: call("cg_advance")?,
            direction: call("cg_direction")?,
            particles: s.particles,
            dispatch: im.dispatch.clone(),
        })
    }

    /// A solve's start: the warm start, the residual and the scalars.
    pub fn encode_start(&self, pass: &mut wgpu::ComputePass<'_>, system: &System) {
        self.start.run(pass, self.particles);
        system.encode_apply(pass, Vector::Dv, None);
        self.residual.run(pass, self.particles);
        self.begin.run(pass, ONE);
    }

    /// `iterations` iterations, empty once the solve is done.
    pub fn encode_iterations(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        system: &System,
        iterations: u32,
    ) {
        let particles = SLOTS_RUNNING.particles;
        for _ in 0..iterations {
            system.encode_apply(pass, Vector::C, Some(SLOTS_RUNNING));
            self.curvature.run_indirect(pass, &self.dispatch, particles);
            self.advance.run_indirect(pass, &self.dispatch, particles);
            // Direct: it writes the indirect arguments (and returns at once when done).
            self.direction.run(pass, self.particles);
        }
    }
}
