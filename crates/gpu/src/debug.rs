//! Stage read-backs for the twin tests (feature `debug`): each stage run alone on the solver's
//! current state, its output read back, so that a test can compare it with the CPU twin on the
//! same input. Not for production use: each builds its calls anew.

use std::sync::Arc;

use glam::{DVec3, Vec3, Vec4};
use softbody_scene::implicit::Constraint;
use softbody_scene::{State, StepError};

use crate::body_contact::BodyContact;
use crate::broad_phase::Snapshot;
use crate::buffers::{PerSpringWrites, Setup, to_dvec3, to_vec3, vec4s};
use crate::builder::Builder;
use crate::collision_response::CollisionResponse;
use crate::device::Gpu;
use crate::forces::Accelerations;
use crate::grid::Grid;
use crate::integrators::Stepper;
use crate::integrators::implicit_euler::ImplicitEuler;
use crate::kernel::Resources;
use crate::layout::{CgScalars, constraint_vec4};
use crate::shaders::Stage;
use crate::submit::Submitter;
use crate::terrain::TerrainBuffers;
use crate::{GpuError, GpuSolver, VEC4, chunks::Chunking};

/// What [`GpuSolver::debug_implicit_system`] reads back: b, the `diag` pairs (P⁻¹xx, P⁻¹yy,
/// P⁻¹zz, m(1 + h·drag), P⁻¹xy, P⁻¹xz, P⁻¹yz, 0 per particle) and A p.
pub type ImplicitSystem = (Vec<Vec3>, Vec<[f32; 8]>, Vec<Vec3>);

fn setup_error(e: GpuError) -> StepError {
    StepError::Device(e.to_string())
}

impl GpuSolver {
    fn setup(&self) -> Setup<'_> {
        Setup {
            builder: &self.builder,
            buffers: &self.buffers,
            chunks: &self.chunks,
            particles: self.particles,
            n: self.model_len(),
        }
    }

    fn model_len(&self) -> u64 {
        softbody_scene::Solver::model(self).len() as u64
    }

    /// The submitter, ready for a stage run outside a step (which leaves the host copy of the
    /// state stale).
    fn stage_submitter(&mut self) -> Result<&mut Submitter, StepError> {
        self.state_fresh = false;
        self.submitter.healthy()?;
        Ok(&mut self.submitter)
    }

    /// What the per-spring kernels write, which the per-spring read-backs need: an error on
    /// the routes that write nothing per spring (the stencil and the fused gather).
    fn writes(&self) -> Result<&PerSpringWrites, StepError> {
        self.buffers
            .list()
            .and_then(|list| list.writes.as_ref())
            .ok_or_else(|| {
                StepError::Invalid(
                    "the solver runs the fused step, which writes nothing per spring and keeps \
                     no buffers for the per-spring kernels: open it with GpuOptions::per_spring"
                        .to_owned(),
                )
            })
    }

    /// Spring forces of the current state, f_a per spring: `spring_forces` alone (not on the
    /// stencil route).
    pub fn debug_spring_forces(&mut self) -> Result<Vec<Vec3>, StepError> {
        let per_spring = self.writes()?.per_spring.clone();
        let forces = {
            let s = self.setup();
            Accelerations::new(s, self.body_contact.as_ref(), &s.buffers.x, &s.buffers.v)
                .map_err(setup_error)?
        };
        let sources: Vec<(&wgpu::Buffer, u64)> = per_spring
            .iter()
            .zip(&self.chunks.ranges)
            .map(|(buffer, &(_, count))| (buffer, count * VEC4))
            .collect();
        let submitter = self.stage_submitter()?;
        let encoder =
            submitter.encode_pass("spring forces", |pass| forces.spring_forces().encode(pass));
        Ok(to_vec3(&submitter.submit_and_read(encoder, &sources)?))
    }

    /// Accelerations of the current state: `spring_forces` and `accelerations` alone (not on
    /// the stencil route).
    pub fn debug_accelerations(&mut self) -> Result<Vec<Vec3>, StepError> {
        let (a, n) = (self.writes()?.a.clone(), self.model_len());
        let forces = {
            let s = self.setup();
            Accelerations::new(s, self.body_contact.as_ref(), &s.buffers.x, &s.buffers.v)
                .map_err(setup_error)?
        };
        let submitter = self.stage_submitter()?;
        let encoder = submitter.encode_pass("accelerations", |pass| forces.encode(pass));
        Ok(to_vec3(
            &submitter.submit_and_read(encoder, &[(&a, n * VEC4)])?,
        ))
    }

    /// Runs `collision_response` alone on the current state.
    ///
    /// The step is taken to have started at `x_start` with the state's velocities: which bands
    /// held it, and the velocity change since, decide which impacts are fresh.
    pub fn debug_collision_response(&mut self, x_start: &[DVec3]) -> Result<(), StepError> {
        let response = CollisionResponse::new(self.setup()).map_err(setup_error)?;
        let x = self.buffers.x.clone();
        let kept = self.builder.storage("kept x", x.size() / VEC4, VEC4);
        let submitter = self.stage_submitter()?;
        // The start record of x_start, then the response of the current positions.
        let mut copy = submitter.encoder("keep x");
        copy.copy_buffer_to_buffer(&x, 0, &kept, 0, x.size());
        submitter.submit(copy);
        submitter
            .queue()
            .write_buffer(&x, 0, bytemuck::cast_slice(&vec4s(x_start)));
        let band = submitter.encode_pass("band", |pass| response.encode_band(pass));
        submitter.submit(band);
        let mut encoder = submitter.encoder("collision response");
        encoder.copy_buffer_to_buffer(&kept, 0, &x, 0, x.size());
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("collision response"),
                timestamp_writes: None,
            });
            response.encode(&mut pass);
        }
        submitter.submit_and_read(encoder, &[])?;
        submitter.healthy()
    }

    /// The contact between bodies, or an error for a model whose bodies cannot touch.
    fn body_contact(&self) -> Result<&BodyContact, StepError> {
        self.body_contact
            .as_ref()
            .ok_or_else(|| StepError::Invalid("the model's bodies cannot touch".to_owned()))
    }

    /// The pairs (i, j), i < j, sorted, in contact in the current state as the response finds
    /// them: the grid of the state and a probe of each particle's partners.
    pub fn debug_contact_pairs(&mut self) -> Result<Vec<[u32; 2]>, StepError> {
        /// Partners j > i read back per particle.
        const CAPACITY: u64 = 64;
        let n = self.model_len();
        let contact = self.body_contact()?;
        let builder = &self.builder;
        let count = builder.storage("probe_count", n, 4);
        let found = builder.storage("probe_pairs", n * CAPACITY, 4);
        let probe = builder
            .call(
                Stage::PairsProbe,
                "pairs_probe",
                &contact
                    .resources(&self.buffers)
                    .buffer("probe_count", &count)
                    .buffer("probe_pairs", &found),
            )
            .map_err(setup_error)?;
        let grid = self.particles;
        let encoder = self.submitter.encode_pass("contact pairs", |pass| {
            contact.encode_grid(pass, Snapshot::End);
            probe.run(pass, grid);
        });
        self.state_fresh = false;
        self.submitter.healthy()?;
        let bytes = self
            .submitter
            .submit_and_read(encoder, &[(&count, n * 4), (&found, n * CAPACITY * 4)])?;
        let words: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes);
        let (counts, found) = words.split_at(n as usize);
        let mut pairs = Vec::new();
        for (i, (&k, partners)) in counts
            .iter()
            .zip(found.chunks_exact(CAPACITY as usize))
            .enumerate()
        {
            if u64::from(k) > CAPACITY {
                return Err(StepError::Invalid(format!(
                    "particle {i} has {k} partners, more than the probe's {CAPACITY}"
                )));
            }
            pairs.extend(partners[..k as usize].iter().map(|&j| [i as u32, j]));
        }
        pairs.sort_unstable();
        Ok(pairs)
    }

    /// The penalty forces between bodies at the current state, of the pairs in contact there:
    /// the grid of the state as a step's start, then `pair_forces` alone.
    pub fn debug_pair_forces(&mut self) -> Result<Vec<Vec3>, StepError> {
        let n = self.model_len();
        let contact = self.body_contact()?;
        let b = &self.buffers;
        let forces = contact
            .pair_forces(self.setup(), &b.x, &b.v)
            .map_err(setup_error)?;
        let grid = self.particles;
        let encoder = self.submitter.encode_pass("pair forces", |pass| {
            contact.encode_start(pass);
            forces.run(pass, grid);
        });
        let a = self.writes()?.a.clone();
        let submitter = self.stage_submitter()?;
        Ok(to_vec3(
            &submitter.submit_and_read(encoder, &[(&a, n * VEC4)])?,
        ))
    }

    /// Runs the response between bodies alone on the current state, as the end of a step that
    /// started at `start`.
    pub fn debug_body_contact_response(&mut self, start: &State) -> Result<(), StepError> {
        let contact = self.body_contact()?;
        let [x, v] = contact.snapshots();
        let queue = self.submitter.queue();
        queue.write_buffer(x, 0, bytemuck::cast_slice(&vec4s(&start.x)));
        queue.write_buffer(v, 0, bytemuck::cast_slice(&vec4s(&start.v)));
        let encoder = self.submitter.encode_pass("body contact response", |pass| {
            contact.encode_response(pass)
        });
        let submitter = self.stage_submitter()?;
        submitter.submit_and_read(encoder, &[])?;
        submitter.healthy()
    }

    /// Implicit Euler's buffers and calls, the submitter and the contact between bodies.
    fn implicit(
        &mut self,
    ) -> Result<(&mut ImplicitEuler, &mut Submitter, Option<&BodyContact>), StepError> {
        self.state_fresh = false;
        self.submitter.healthy()?;
        match &mut self.stepper {
            Stepper::Implicit(im) => Ok((im, &mut self.submitter, self.body_contact.as_ref())),
            Stepper::PerSpring(_) | Stepper::Fused(_) => Err(StepError::Invalid(
                "not an implicit-euler solver".to_owned(),
            )),
        }
    }

    /// Implicit Euler's system at the current state, and its product with `p`: the assembly
    /// (with the pairs of bodies in contact there, for a model whose bodies touch) and one
    /// product alone.
    pub fn debug_implicit_system(&mut self, p: &[DVec3]) -> Result<ImplicitSystem, StepError> {
        let n = self.model_len();
        let (im, submitter, contact) = self.implicit()?;
        let b = im.buffers();
        submitter
            .queue()
            .write_buffer(&b.dv, 0, bytemuck::cast_slice(&vec4s(p)));
        let encoder = submitter.encode_pass("implicit system", |pass| {
            im.encode_assemble(pass, contact);
            im.encode_apply_dv(pass);
        });
        let bytes = submitter.submit_and_read(
            encoder,
            &[(&b.b, n * VEC4), (&b.diag, 2 * n * VEC4), (&b.q, n * VEC4)],
        )?;
        let (b, rest) = bytes.split_at((n * VEC4) as usize);
        let (diag, q) = rest.split_at((2 * n * VEC4) as usize);
        Ok((to_vec3(b), bytemuck::pod_collect_to_vec(diag), to_vec3(q)))
    }

    /// One CG solve of implicit Euler's system at the current state with the given
    /// constraints, right-hand side, prescribed Δv and warm start (the twin of
    /// `softbody_cpu::integrators::implicit_euler::cg::CgProblem::solve`): returns Δv and the
    /// scalars it ended with.
    pub fn debug_implicit_solve(
        &mut self,
        constraints: &[Constraint],
        rhs: &[DVec3],
        z: &[DVec3],
        dv: &[DVec3],
    ) -> Result<(Vec<DVec3>, CgScalars), StepError> {
        let n = self.model_len();
        let packed: Vec<[f32; 4]> = constraints.iter().map(|&c| constraint_vec4(c)).collect();
        let (im, submitter, contact) = self.implicit()?;
        let b = im.buffers();
        let queue = submitter.queue();
        queue.write_buffer(&b.constraints, 0, bytemuck::cast_slice(&packed));
        queue.write_buffer(&b.rhs, 0, bytemuck::cast_slice(&vec4s(rhs)));
        queue.write_buffer(&b.z, 0, bytemuck::cast_slice(&vec4s(z)));
        queue.write_buffer(&b.dv, 0, bytemuck::cast_slice(&vec4s(dv)));
        let encoder = submitter.encode_pass("cg solve", |pass| {
            im.encode_assemble(pass, contact);
            im.encode_round(pass, false);
            im.encode_batch(pass, true);
        });
        let progress = im.solve(submitter, encoder)?;
        let dv = im.buffers().dv.clone();
        let encoder = submitter.encoder("read dv");
        let bytes = submitter.submit_and_read(encoder, &[(&dv, n * VEC4)])?;
        Ok((to_dvec3(&bytes), progress.scalars))
    }

    /// The dispatches `iterations` CG iterations of implicit Euler encode (encoded after a
    /// solve's round, so that they run on a started solve).
    pub fn debug_cg_iteration_dispatches(&mut self, iterations: u32) -> Result<u64, StepError> {
        let (im, submitter, contact) = self.implicit()?;
        let encoder = submitter.encode_pass("cg round", |pass| {
            im.encode_assemble(pass, contact);
            im.encode_round(pass, true);
        });
        submitter.submit_and_read(encoder, &[])?;
        let round = self.builder.traffic().totals().0;
        let (im, submitter, _) = self.implicit()?;
        let encoder = submitter.encode_pass("cg iterations", |pass| {
            im.encode_iterations(pass, iterations)
        });
        submitter.submit_and_read(encoder, &[])?;
        submitter.healthy()?;
        Ok(self.builder.traffic().totals().0 - round)
    }

    /// Destroys the device, as a driver reset would lose it: for the failure tests. Every
    /// solver on the same context fails from then on.
    pub fn debug_destroy_device(&self) {
        self.gpu().device.destroy();
    }
}

/// Evaluates every surface of `packed` at every point (w: a contact reach) on the GPU with
/// `shaders/terrain_probe.wgsl`: entry `i·K + k` (K surfaces) holds `terrain_query(k, p)` and
/// `terrain_query_within(k, p, reach)` of point i, each as (N, φ).
pub fn terrain_probe(
    gpu: &Arc<Gpu>,
    packed: &TerrainBuffers,
    points: &[Vec4],
) -> Result<Vec<[Vec4; 2]>, GpuError> {
    let builder = Builder::new(gpu.clone(), gpu.limits.clone(), Chunking::ONE, packed)?;
    let surfaces = packed.surfaces_for_binding().len();
    let input: Vec<[f32; 4]> = points.iter().map(|p| p.to_array()).collect();
    let points_buffer = builder.storage_init("probe_points", bytemuck::cast_slice(&input), 16);
    let out_bytes = (points.len() * surfaces * 2) as u64 * VEC4;
    let out = builder.storage("probe_out", out_bytes / VEC4, VEC4);
    let call = builder.call(
        Stage::TerrainProbe,
        "terrain_probe",
        &Resources::default()
            .buffer("probe_points", &points_buffer)
            .buffer("probe_out", &out),
    )?;
    let grid = Grid::new(
        points.len() as u64,
        gpu.limits.max_compute_workgroups_per_dimension,
    )
    .ok_or_else(|| GpuError::Unsupported("too many probe points".to_owned()))?;
    let mut submitter = Submitter::new(gpu.clone(), out_bytes);
    let encoder = submitter.encode_pass("terrain probe", |pass| call.run(pass, grid));
    let bytes = submitter
        .submit_and_read(encoder, &[(&out, out_bytes)])
        .map_err(|e| GpuError::Device {
            adapter: gpu.name(),
            message: e.to_string(),
        })?;
    let values: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
    Ok(values
        .chunks_exact(2)
        .map(|pair| [Vec4::from(pair[0]), Vec4::from(pair[1])])
        .collect())
}
