//! `shaders/system.wgsl` ↔ `softbody_cpu::integrators::implicit_euler::system`: implicit
//! Euler's linear system, linearised at the start of the step,
//!
//! A = M(1 + h·drag) − h ∂f/∂v − h² ∂f/∂x,  b = h (f + h ∂f/∂x v),
//!
//! kept matrix-free as one block B_s = β uuᵀ + γ I per spring (`assemble_springs`), gathered per
//! particle into b and the block-Jacobi preconditioner (`assemble_particles`); A p is one dispatch
//! (`shaders/fused_product.wgsl`: each particle computes its springs' terms as it gathers them),
//! or with `GpuOptions::per_spring` a per-spring product and a gather (`apply_springs`,
//! `apply_particles`): the same bits. The CG iterations' product of its direction c also
//! filters it and sums cᵀq (`apply_particles_curvature`, `shaders/shared/product.wgsl`). The fused
//! product of A Δv binds fewer storage buffers than `assemble_particles`, and that of c as
//! many plus one, for any chunk count (pinned by a reflection test): on an adapter whose limit
//! is the assembly's exactly, the product takes the two passes, whose gathers bind fewer.
//!
//! Where bodies touch, each pair in contact at the step's start whose penalty pushes there is a
//! block β nnᵀ too (β = h c + h² k) with the share ±h(F − h k (u·n)) n of b: `pair_system` and
//! `pair_products` (`shaders/body_contact.wgsl`, which searches the start grid) leave each
//! particle's pair terms for the `…_with_pairs` variants of the per-particle kernels.

use super::{Buffers, Slots};
use crate::GpuError;
use crate::body_contact::BodyContact;
use crate::buffers::Setup;
use crate::builder::answer;
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;

/// The product A p of one vector p, into q (for CG's direction c, S A c with cᵀq's partials).
struct Apply {
    /// One call per spring chunk (none for the fused product).
    springs: Vec<Call>,
    /// The pairs' terms, for models whose bodies touch.
    pairs: Option<Call>,
    particles: Call,
}

/// Which vector a product multiplies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Vector {
    /// Δv.
    Dv,
    /// CG's search direction c.
    C,
}

/// The assembly and the products A Δv and A c.
pub(crate) struct System {
    assemble_springs: Vec<Call>,
    /// The pairs' terms, for models whose bodies touch.
    assemble_pairs: Option<Call>,
    assemble_particles: Call,
    apply_dv: Apply,
    apply_c: Apply,
    spring_grids: Vec<Grid>,
    particles: Grid,
    /// The CG's indirect dispatch arguments.
    dispatch: wgpu::Buffer,
    /// Whether A p is the one-dispatch fused product.
    fused: bool,
}

impl System {
    /// The system's calls over the implicit buffers `im`, with the pairs of `contact` (for
    /// models whose bodies touch); the product fused unless `two_pass`.
    pub fn new(
        s: Setup<'_>,
        contact: Option<&BodyContact>,
        im: &Buffers,
        two_pass: bool,
    ) -> Result<System, GpuError> {
        // The per-spring kernels bind their chunk's blocks; the gathers all chunks (`im`).
        let per_chunk = |entry, p: &wgpu::Buffer| {
            s.per_chunk(Stage::System, entry, |c, r| {
                im.resources(r)
                    .buffer("blocks", &im.blocks[c])
                    .buffer("p", p)
            })
        };
        let gather = |stage, entry, p: &wgpu::Buffer| {
            let r = im.resources(s.buffers.resources()).buffer("p", p);
            let r = match (stage, s.buffers.list()) {
                // The spring records of every chunk, as the fused step binds them.
                (Stage::FusedProduct, Some(list)) => r.chunks("springs", "spring", &list.records),
                _ => r,
            };
            s.builder.call(stage, entry, &r)
        };
        // The pairs' kernels search the start grid: the contact's buffers with implicit Euler's.
        let pairs = |entry, p: &wgpu::Buffer| {
            contact
                .map(|contact| {
                    let r = im.resources(contact.resources(s.buffers)).buffer("p", p);
                    s.builder.call(Stage::BodyContact, entry, &r)
                })
                .transpose()
        };
        let (assemble, product, curvature) = match contact {
            Some(_) => (
                "assemble_particles_with_pairs",
                "apply_particles_with_pairs",
                "apply_particles_with_pairs_curvature",
            ),
            None => (
                "assemble_particles",
                "apply_particles",
                "apply_particles_curvature",
            ),
        };
        let fused = !two_pass && answer(s.builder.fits(Stage::FusedProduct, curvature))?;
        let apply = |entry, p| -> Result<Apply, GpuError> {
            Ok(Apply {
                springs: match fused {
                    true => Vec::new(),
                    false => per_chunk("apply_springs", p)?,
                },
                pairs: pairs("pair_products", p)?,
                particles: match fused {
                    true => gather(Stage::FusedProduct, entry, p)?,
                    false => gather(Stage::System, entry, p)?,
                },
            })
        };
        Ok(System {
            assemble_springs: per_chunk("assemble_springs", &im.dv)?,
            assemble_pairs: pairs("pair_system", &im.dv)?,
            assemble_particles: gather(Stage::System, assemble, &im.dv)?,
            apply_dv: apply(product, &im.dv)?,
            apply_c: apply(curvature, &im.c)?,
            spring_grids: s.chunks.grids.clone(),
            particles: s.particles,
            dispatch: im.dispatch.clone(),
            fused,
        })
    }

    /// Whether A p is the one-dispatch fused product.
    pub fn fused(&self) -> bool {
        self.fused
    }

    /// Linearises at the current (x, v): the spring blocks, b and the preconditioner.
    pub fn encode_assemble(&self, pass: &mut wgpu::ComputePass<'_>) {
        for (call, grid) in self.assemble_springs.iter().zip(&self.spring_grids) {
            call.run(pass, *grid);
        }
        if let Some(pairs) = &self.assemble_pairs {
            pairs.run(pass, self.particles);
        }
        self.assemble_particles.run(pass, self.particles);
    }

    /// q = A `vector`: on the full grids, or (`slots`) indirectly from the CG's argument slots,
    /// every chunk from the springs' slot (the largest chunk's grid; a shorter chunk's surplus
    /// threads return at once).
    pub fn encode_apply(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        vector: Vector,
        slots: Option<Slots>,
    ) {
        let apply = match vector {
            Vector::Dv => &self.apply_dv,
            Vector::C => &self.apply_c,
        };
        for (call, grid) in apply.springs.iter().zip(&self.spring_grids) {
            match slots {
                Some(slots) => call.run_indirect(pass, &self.dispatch, slots.springs),
                None => call.run(pass, *grid),
            }
        }
        for call in apply.pairs.iter().chain([&apply.particles]) {
            match slots {
                Some(slots) => call.run_indirect(pass, &self.dispatch, slots.particles),
                None => call.run(pass, self.particles),
            }
        }
    }
}
