//! [`Plan`]: what a solver will be, decided from the model, the options and the adapter's
//! limits before anything is allocated — the limits it runs under, the route of the springs and
//! their chunking, the dispatch grids — with every refusal (a scene beyond f32 or the adapter's
//! limits, implicit Euler without indirect dispatch) made here. The solver is then built from
//! the plan ([`crate::GpuSolver::with_options`]).

use softbody_scene::{Integrator, Model, State};

use crate::body_contact;
use crate::buffers::Route;
use crate::builder::{answer, fits};
use crate::chunks::{Chunking, SpringChunks};
use crate::device::Gpu;
use crate::grid::Grid;
use crate::integrators::entries;
use crate::layout::{CandidateGpu, LatticeBodyGpu, SpringBlockGpu, SpringGpu};
use crate::limits::{Need, check_chunks, check_f32, check_limits};
use crate::shaders::Stage;
use crate::terrain::{self, TerrainBuffers};
use crate::{GpuError, VEC4, WORKGROUP_SIZE};

/// Settings for tests: narrower dispatch grids and smaller storage bindings than the adapter's,
/// so that small scenes take the paths of very large ones.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GpuOptions {
    /// Dispatch grids at most this many workgroups wide (instead of the per-dimension limit).
    pub grid_width: Option<u32>,
    /// Storage bindings of at most this many bytes (instead of the adapter's
    /// `max_storage_buffer_binding_size`, if lower): per-spring arrays are split accordingly.
    pub max_binding_size: Option<u64>,
    /// The explicit integrators on the per-spring path even where the fused one applies, and
    /// implicit Euler's product A p in two passes (per spring, then per particle) even where
    /// the fused product fits, to compare the two.
    pub per_spring: bool,
    /// At most this many storage buffers per shader stage (instead of the adapter's
    /// `max_storage_buffers_per_shader_stage`, if lower): WebGPU's minimum of 8 makes the
    /// explicit integrators fall back to the per-spring path.
    pub max_storage_buffers: Option<u32>,
    /// The fused step through the spring records and the CSR adjacency (the spring list
    /// uploaded) even where every body is a lattice (which takes the stencil route, without
    /// the list), to compare the two.
    pub gather: bool,
}

/// A solver's plan.
pub(crate) struct Plan {
    /// The adapter's limits, lowered where the options say.
    pub limits: wgpu::Limits,
    /// The adapter, for messages.
    pub adapter: String,
    pub integrator: Integrator,
    /// Particles.
    pub n: u64,
    /// Springs on the device: none on the stencil route, which finds them on the lattices.
    pub m: u64,
    /// The terrain as the shaders read it.
    pub terrain: TerrainBuffers,
    pub route: Route,
    /// How the per-spring arrays are split.
    pub chunking: Chunking,
    /// Dispatch grids are rows of at most `width` workgroups, at most `max_rows` rows.
    pub width: u32,
    pub max_rows: u32,
    /// One thread per particle.
    pub particles: Grid,
    /// One thread per spring of each chunk.
    pub spring_grids: Vec<Grid>,
    /// The energies' partial sums of the springs: per spring workgroup, or on the stencil route
    /// per particle workgroup (`energy_lattices`).
    pub spring_groups: u64,
    /// Implicit Euler's product in two passes (per spring, then per particle) even where the
    /// fused product fits.
    pub two_pass: bool,
}

impl Plan {
    /// The plan of a solver of `model` from `state` on `gpu` with `options`, or why there can
    /// be none.
    pub fn new(
        gpu: &Gpu,
        model: &Model,
        state: &State,
        options: &GpuOptions,
    ) -> Result<Plan, GpuError> {
        let integrator = model.simulation.integrator;
        let mut limits = gpu.limits.clone();
        if let Some(cap) = options.max_binding_size {
            // As if the adapter allowed no more: the device itself keeps its limits.
            let limit = &mut limits.max_storage_buffer_binding_size;
            *limit = (*limit).min(cap);
        }
        if let Some(cap) = options.max_storage_buffers {
            let limit = &mut limits.max_storage_buffers_per_shader_stage;
            *limit = (*limit).min(cap);
        }
        let adapter = gpu.name();
        if integrator == Integrator::ImplicitEuler
            && !gpu
                .downlevel
                .contains(wgpu::DownlevelFlags::INDIRECT_EXECUTION)
        {
            return Err(GpuError::Unsupported(format!(
                "{adapter} cannot dispatch compute work indirectly, which the GPU's implicit-euler \
                 needs (its CG iterations stop on the device): use --backend cpu, or an explicit \
                 integrator"
            )));
        }
        check_f32(model, state)?;
        let n = model.len() as u64;
        let terrain = terrain::pack(&model.terrain);
        let (route, chunking) = route(model, options, &limits, &adapter)?;
        let m = match route {
            Route::Stencil => 0,
            Route::Gather | Route::PerSpring => model.spring_count() as u64,
        };
        check_limits(
            &limits,
            &adapter,
            &needs(model, &terrain, route),
            2 * n * VEC4,
            &[
                ("particle", n),
                ("spring", m),
                ("broad-phase bucket", body_contact::buckets(n)),
            ],
        )?;
        let max_rows = limits.max_compute_workgroups_per_dimension;
        let width = options
            .grid_width
            .map_or(max_rows, |w| w.clamp(1, max_rows));
        let grids = Grid::with_width(n, width, max_rows)
            .zip(SpringChunks::grids(chunking, m, width, max_rows));
        let Some((particles, spring_grids)) = grids else {
            // Only with a narrow test width: check_limits checked the adapter's.
            return Err(GpuError::Unsupported(format!(
                "the scene needs more than {max_rows} rows of {width} workgroups"
            )));
        };
        let spring_groups = match route {
            Route::Stencil => particles.groups(),
            Route::Gather | Route::PerSpring => m.div_ceil(WORKGROUP_SIZE),
        };
        Ok(Plan {
            limits,
            adapter,
            integrator,
            n,
            m,
            terrain,
            route,
            chunking,
            width,
            max_rows,
            particles,
            spring_grids,
            spring_groups,
            two_pass: options.per_spring,
        })
    }

    /// Terrain surfaces.
    pub fn surfaces(&self) -> u32 {
        self.terrain.surfaces.len() as u32
    }
}

/// The route of `model` on an adapter with `limits`, and the chunking of its spring list (one
/// empty chunk on the stencil route). The explicit integrators run fused ([`fused_applies`])
/// where the adapter can bind the fused kernels (reflected from their WGSL): on the stencil
/// where every body is a lattice and `options` do not ask for the gather, else on the gather.
/// Everything else takes the per-spring route.
fn route(
    model: &Model,
    options: &GpuOptions,
    limits: &wgpu::Limits,
    adapter: &str,
) -> Result<(Route, Chunking), GpuError> {
    let integrator = model.simulation.integrator;
    let implicit = integrator == Integrator::ImplicitEuler;
    let stride = if implicit {
        std::mem::size_of::<SpringBlockGpu>()
    } else {
        std::mem::size_of::<SpringGpu>()
    } as u64;
    let fused = fused_applies(integrator, model.contact.enabled(), options.per_spring);
    let entries = entries(integrator);
    // Whether `stage`'s fused kernels fit; a limit is an answer, anything else an error.
    let fit = |stage, chunking| answer(fits(limits, adapter, stage, entries, chunking));
    let lattices = model.lattices().len() == model.bodies.len();
    if fused && lattices && !options.gather && fit(Stage::FusedStencil, Chunking::ONE)? {
        return Ok((
            Route::Stencil,
            check_chunks(limits, adapter, 0, stride, implicit)?,
        ));
    }
    let springs = model.spring_count() as u64;
    let chunking = check_chunks(limits, adapter, springs, stride, implicit)?;
    let route = if fused && fit(Stage::FusedStep, chunking)? {
        Route::Gather
    } else {
        Route::PerSpring
    };
    Ok((route, chunking))
}

/// Whether `integrator` runs fused unless the adapter cannot bind the fused kernels: an
/// explicit integrator, bodies that do not touch (`contact`: their pair forces need the broad
/// phase of each stage's state), and `per_spring` not asking for the per-spring path.
fn fused_applies(integrator: Integrator, contact: bool, per_spring: bool) -> bool {
    integrator != Integrator::ImplicitEuler && !contact && !per_spring
}

/// The storage buffers the scene needs on `route`, as [`crate::limits::check_limits`] checks them:
/// the per-particle arrays, the springs (the lattices on the stencil route, the adjacency
/// otherwise), the terrain and the integrator's own.
fn needs(model: &Model, packed: &TerrainBuffers, route: Route) -> Vec<Need> {
    let n = model.len() as u64;
    let need = |what, count, stride| Need {
        what,
        count,
        stride,
    };
    let mut needs = vec![
        need("positions", n, VEC4),
        need("velocities", n, VEC4),
        need("masses", n, 8),
    ];
    match route {
        Route::Stencil => {
            let lattices = model.lattices();
            needs.push(need(
                "lattice bodies",
                lattices.len() as u64,
                std::mem::size_of::<LatticeBodyGpu>() as u64,
            ));
            needs.push(need(
                "lattice points",
                LatticeBodyGpu::point_words(lattices),
                4,
            ));
        }
        Route::Gather | Route::PerSpring => {
            let m = model.spring_count() as u64;
            if route == Route::PerSpring {
                needs.push(need("accelerations", n, VEC4));
            }
            // The per-spring arrays are chunked (check_chunks); the adjacency, a gather's
            // index, stays whole: 2 words per spring, 16.7 M springs per 128 MiB.
            needs.push(need("adjacency", n + 1 + 2 * m, 4));
        }
    }
    needs.extend([
        need(
            "terrain surfaces",
            packed.surfaces.len() as u64,
            std::mem::size_of::<terrain::SurfaceGpu>() as u64,
        ),
        need("terrain data", packed.data.len() as u64, 4),
    ]);
    use softbody_scene::Integrator::*;
    match model.simulation.integrator {
        Midpoint | Rk4 => {
            needs.push(need("stage positions", n, VEC4));
            needs.push(need("stage velocities", n, VEC4));
        }
        ExplicitEuler | SymplecticEuler => {}
        ImplicitEuler => {
            needs.push(need("preconditioner blocks", 2 * n, VEC4));
            needs.push(need(
                "contact candidates",
                n,
                std::mem::size_of::<CandidateGpu>() as u64,
            ));
        }
    }
    if model.simulation.integrator == Rk4 {
        needs.push(need("RK4 position sums", n, VEC4));
        needs.push(need("RK4 velocity sums", n, VEC4));
    }
    if model.contact.enabled() {
        needs.extend(
            body_contact::needs(model)
                .into_iter()
                .map(|(what, count, stride)| need(what, count, stride)),
        );
    }
    needs
}
