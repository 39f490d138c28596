//! `shaders/cg.wgsl` ↔ `softbody_cpu::integrators::implicit_euler::cg`: filtered,
//! block-Jacobi-preconditioned conjugate gradients for A Δv = rhs, the CPU's loop operation for
//! operation in f32, its scalars on the device.
//!
//! A solve starts with the warm start's projection on the last three steps' Δv (`Projection`:
//! eleven dispatches, four of them products) and a round (`cg_start`: the warm start; A Δv;
//! `cg_residual`; `cg_begin`),
//! then runs batches of iterations of three dispatches: the product of the direction c, which
//! also filters q = S A c and writes cᵀq's partial sums (`apply_particles_curvature`,
//! `shaders/shared/product.wgsl`), `cg_advance`, whose workgroups each compute α from those partial
//! sums, and `cg_direction`, whose workgroups each compute β from those of rᵀP⁻¹r. (Kernels of
//! their own for cᵀq, α and β took three more.) The product and `cg_advance` are dispatched
//! indirectly from the argument slots that `cg_begin` and `cg_direction` rewrite:
//! full grids while the solve runs, empty ones once it is done, so a batch of iterations is one
//! submission whatever the solve needs. `cg_direction` binds those slots, so it runs on the full
//! grid, whose workgroups return at once once the solve is done.

use super::system::{System, Vector};
use super::{Buffers, SLOTS_RUNNING};
use crate::GpuError;
use crate::buffers::Setup;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// The warm start projection's calls (`cg.wgsl`, the CPU's `project_warm_start`).
struct Projection {
    start: Call,
    rhs: Call,
    /// Row j of the Gram matrix, after the product of basis vector j.
    gram: [Call; 3],
    solve: Call,
    combine: Call,
}

/// The CG kernels' calls.
pub(crate) struct Cg {
    projection: Projection,
    start: Call,
    residual: Call,
    begin: Call,
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
            projection: Projection {
                start: call("cg_project_start")?,
                rhs: call("cg_project_rhs")?,
                gram: [
                    call("cg_project_gram_0")?,
                    call("cg_project_gram_1")?,
                    call("cg_project_gram_2")?,
                ],
                solve: call("cg_project_solve")?,
                combine: call("cg_project_combine")?,
            },
            start: call("cg_start")?,
            residual: call("cg_residual")?,
            begin: call("cg_begin")?,
            advance: call("cg_advance")?,
            direction: call("cg_direction")?,
            particles: s.particles,
            dispatch: im.dispatch.clone(),
        })
    }

    /// A solve's start: the warm start projected on the earlier solutions, the residual and
    /// the scalars.
    pub fn encode_start(&self, pass: &mut wgpu::ComputePass<'_>, system: &System) {
        let p = &self.projection;
        p.start.run(pass, self.particles);
        system.encode_apply(pass, Vector::Dv, None);
        p.rhs.run(pass, self.particles);
        for gram in &p.gram {
            system.encode_apply(pass, Vector::C, None);
            gram.run(pass, self.particles);
        }
        p.solve.run(pass, ONE);
        p.combine.run(pass, self.particles);
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
            // q = S A c and cᵀq's partial sums.
            system.encode_apply(pass, Vector::C, Some(SLOTS_RUNNING));
            self.advance.run_indirect(pass, &self.dispatch, particles);
            // Direct: it writes the indirect arguments (and returns at once when done).
            self.direction.run(pass, self.particles);
        }
    }
}
