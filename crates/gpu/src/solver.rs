//! [`GpuSolver`]: the stages wired together — the model and state on the device, the
//! integrator, the collision response, the instability check, the energies — and the host side
//! of a run: submissions, the status, the read-backs.
//!
//! # A step
//!
//! Every step is a fixed sequence of dispatches in one compute pass (wgpu orders consecutive
//! dispatches: each is its own usage scope, so each sees what the previous wrote). Fused
//! ([`crate::integrators::fused`], the explicit integrators unless bodies touch): one dispatch
//! per integrator stage, the last of which also responds to the terrain and checks
//! finiteness; where every body is a lattice, on the stencil route, decided before the upload
//! ([`crate::buffers::Route`]), with no spring list on the host or the device. Otherwise
//! the integrator's ([`crate::integrators`]), then `collision_response` (when there is
//! terrain) and `check_finite`. Where bodies touch ([`crate::body_contact`]), the step starts with the grid
//! of its start state, whose pairs' penalty forces every stage adds, and the collision response
//! is followed by the grid of the end state and the response between bodies, and (with
//! terrain) by the terrain's record of the next step's start, which that response changed.
//!
//! # Submissions
//!
//! [`Solver::advance`] does not wait for the GPU. It encodes steps into command buffers of up
//! to [`STEPS_PER_SUBMISSION`] steps, sized so that one takes about [`SUBMISSION_SECONDS`] of
//! device time (the first submission is a single step, timed, and every read-back of the
//! statuses times them again), so a very large scene never holds the GPU near a driver's
//! watchdog and a small one amortises its submissions. Each submission ends by copying its
//! 12-byte status into a slot of a ring; the host encodes and submits the next while the GPU
//! runs this one, and reads the ring back only when it is full or when it needs a result
//! ([`Solver::sync`], the state, the energies, the history). Implicit Euler cannot know its CG
//! iterations and active-set rounds in advance: it synchronises at least once per step on a
//! 68-byte read-back; where bodies touch, it builds the start's grid before its assembly (its
//! pairs are springs of its system) and ends with the response between bodies before
//! `check_finite`.
//!
//! # Instability
//!
//! `check_finite` ([`crate::check_finite`]) records the first bad step of a submission and its
//! lowest bad particle: an instability is reported with the exact step, time and particle the
//! CPU would report, by the first call that reads the statuses back. The steps after it still
//! run (the GPU cannot stop mid-submission, and later submissions may be in flight), so after a
//! [`StepError::Unstable`] the state is that of the last step submitted, not of the failing
//! step; [`Solver::steps_taken`] is the failing step.
//!
//! # Read-backs
//!
//! Only on demand: [`Solver::state`] copies x and v into one mappable buffer (cached until the
//! next `advance`), [`Solver::energies`] runs the reductions ([`crate::energy`]).
//!
//! # Timings
//!
//! The stages of [`Statistics::timings`] are what the host sees: "encode" (recording
//! commands), "device" (waiting for the submissions in flight and their statuses: the GPU's
//! work the host did not overlap), "assemble + cg (device)" (implicit Euler's solves, their read-backs
//! included), "energies" and "read-back". How long each kernel takes on the device needs
//! timestamp queries, which this solver does not use.

use std::sync::Arc;

use softbody_scene::{
    Controls, Energies, History, Instability, Integrator, Model, Solver, State, Statistics,
    StepError, Timings, solver::check_state_len,
};

use crate::body_contact::BodyContact;
use crate::buffers::{ModelBuffers, Setup, to_dvec3, vec4s};
use crate::builder::Builder;
use crate::check_finite::CheckFinite;
use crate::chunks::SpringChunks;
use crate::collision_response::CollisionResponse;
use crate::device::Gpu;
use crate::energy::Energy;
#[cfg(feature = "debug")]
use crate::grid::Grid;
use crate::integrators::{Around, Stepper};
use crate::layout::{NONE, Status};
use crate::plan::{GpuOptions, Plan};
use crate::submit::Submitter;
use crate::{GpuError, STEPS_PER_SUBMISSION, VEC4};

/// Device time one submission aims at: long enough to amortise a submission, short enough that
/// a very large scene never holds the GPU near a driver's watchdog (2 s on Windows).
pub const SUBMISSION_SECONDS: f64 = 0.05;

/// Submissions in flight at most: each copies its status into a slot of a ring, and the host
/// reads the ring back when it is full or when it needs the results.
const STATUS_RING: usize = 32;

/// The GPU backend: the model in device buffers, stepped by compute shaders in f32.
pub struct GpuSolver {
    model: Model,
    pub(crate) submitter: Submitter,
    /// Kept for what is built later (the debug read-backs) and the memory tally.
    pub(crate) builder: Builder,
    pub(crate) buffers: ModelBuffers,
    pub(crate) chunks: SpringChunks,
    /// The particle grid.
    #[cfg(feature = "debug")]
    pub(crate) particles: Grid,
    pub(crate) stepper: Stepper,
    /// Contact between bodies, for models whose bodies touch.
    pub(crate) body_contact: Option<BodyContact>,
    pub(crate) collision_response: Option<CollisionResponse>,
    check: CheckFinite,
    energy: Energy,
    /// Host copy of the state, valid while `state_fresh`.
    state: State,
    pub(crate) state_fresh: bool,
    /// Whether the collision response's band masks must be computed from the state before the
    /// next step (no response has left them: the first step, and after `set_state`).
    band_stale: bool,
    /// Steps submitted.
    steps: u64,
    /// The statuses of the submissions in flight, one slot each.
    status_ring: wgpu::Buffer,
    /// (steps before it, steps in it) of each submission in flight, in order.
    in_flight: Vec<(u64, u64)>,
    /// When the oldest submission in flight was made.
    in_flight_since: Option<std::time::Instant>,
    /// Steps per submission, chosen from the device time per step ([`SUBMISSION_SECONDS`]);
    /// `None` until the first submission has been timed.
    batch: Option<u64>,
    timings: Timings,
}

// Solvers move between threads (a batch of runs, a Python binding releasing the GIL).
const _: fn() = || {
    fn send<T: Send>() {}
    send::<GpuSolver>();
};

impl GpuSolver {
    /// Opens a device of its own and uploads `model` and `state`: [`GpuSolver::on`] with
    /// [`Gpu::open`].
    pub fn new(model: Model, state: State) -> Result<GpuSolver, GpuError> {
        GpuSolver::on(&Gpu::open()?, model, state)
    }

    /// Uploads `model` and `state` to `gpu`, a context other solvers may share (a batch of
    /// scenes on one device).
    ///
    /// Fails with [`GpuError::Limit`] when the scene exceeds the adapter's limits,
    /// [`GpuError::Unsupported`] for values beyond f32's range and for implicit Euler on an
    /// adapter without indirect dispatch
    /// (`DownlevelFlags::INDIRECT_EXECUTION`), and [`GpuError::Device`] when the buffers and
    /// pipelines cannot be created.
    pub fn on(gpu: &Arc<Gpu>, model: Model, state: State) -> Result<GpuSolver, GpuError> {
        GpuSolver::with_options(gpu, model, state, GpuOptions::default())
    }

    /// [`GpuSolver::on`] with test settings (see [`GpuOptions`]).
    #[doc(hidden)]
    pub fn with_options(
        gpu: &Arc<Gpu>,
        model: Model,
        mut state: State,
        options: GpuOptions,
    ) -> Result<GpuSolver, GpuError> {
        let plan = Plan::new(gpu, &model, &state, &options)?;
        let device = &gpu.device;
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
        let built = Parts::build(gpu, &plan, &model, &state);
        // Scopes pop in reverse order.
        let errors = [
            pollster::block_on(internal.pop()),
            pollster::block_on(memory.pop()),
            pollster::block_on(validation.pop()),
        ];
        if let Some(e) = errors.into_iter().flatten().next() {
            return Err(GpuError::Device {
                adapter: plan.adapter,
                message: format!("cannot set up the solver: {e}"),
            });
        }
        let parts = built?;
        // The host copy is what the device holds: the state rounded to f32.
        for p in state.x.iter_mut().chain(state.v.iter_mut()) {
            *p = p.as_vec3().as_dvec3();
        }
        // Holds x and v, the energy partials, the status; implicit Euler's progress and stage
        // tests grow it on demand.
        let status_bytes = std::mem::size_of::<Status>() as u64;
        let readback = (2 * plan.n * VEC4)
            .max(plan.particles.groups() * 8 + plan.spring_groups * 4)
            .max(STATUS_RING as u64 * status_bytes);
        let status_ring = parts.builder.buffer(&wgpu::BufferDescriptor {
            label: Some("status ring"),
            size: STATUS_RING as u64 * status_bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Ok(GpuSolver {
            submitter: Submitter::new(gpu.clone(), readback),
            model,
            builder: parts.builder,
            buffers: parts.buffers,
            chunks: parts.chunks,
            #[cfg(feature = "debug")]
            particles: plan.particles,
            stepper: parts.stepper,
            body_contact: parts.body_contact,
            collision_response: parts.collision_response,
            check: parts.check,
            energy: parts.energy,
            state,
            state_fresh: true,
            band_stale: true,
            steps: 0,
            status_ring,
            in_flight: Vec::new(),
            in_flight_since: None,
            batch: None,
            timings: Timings::default(),
        })
    }

    /// The adapter, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) via Vulkan".
    pub fn adapter(&self) -> String {
        self.builder.gpu().name()
    }

    /// The context the solver runs on.
    pub fn gpu(&self) -> &Arc<Gpu> {
        self.builder.gpu()
    }

    /// (first spring, springs) of each chunk the per-spring arrays are split into: one unless
    /// they exceed a storage binding ([`crate::chunks`]). On the stencil route, which keeps no
    /// per-spring array, one empty chunk (as for a model without springs).
    pub fn spring_chunks(&self) -> &[(u64, u64)] {
        &self.chunks.ranges
    }

    /// Submits `batch` steps without waiting for them; their status goes into the next slot of
    /// the ring.
    fn submit_batch(&mut self, batch: u64) -> Result<(), StepError> {
        let started = std::time::Instant::now();
        // Ordered before the submission's commands.
        self.submitter.queue().write_buffer(
            &self.buffers.status,
            0,
            bytemuck::bytes_of(&Status::RESET),
        );
        let encoder = match &mut self.stepper {
            Stepper::Fused(fused) => {
                let band = self.collision_response.as_ref();
                let band_stale = std::mem::take(&mut self.band_stale);
                let mut encoder = self.submitter.encode_pass("steps", |pass| {
                    if let (Some(c), true) = (band, band_stale) {
                        c.encode_band(pass);
                    }
                    for k in 0..batch {
                        fused.encode(pass, k);
                    }
                });
                fused.end_batch(&mut encoder, batch);
                self.timings.add("encode", started.elapsed().as_secs_f64());
                encoder
            }
            Stepper::PerSpring(stepper) => {
                let (collision, check) = (&self.collision_response, &self.check);
                let contact = &self.body_contact;
                let band_stale = std::mem::take(&mut self.band_stale);
                let encoder = self.submitter.encode_pass("steps", |pass| {
                    if let (Some(c), true) = (collision, band_stale) {
                        c.encode_band(pass);
                    }
                    for k in 0..batch {
                        if let Some(contact) = contact {
                            contact.encode_start(pass);
                        }
                        stepper.encode(pass);
                        if let Some(c) = collision {
                            c.encode(pass);
                        }
                        if let Some(contact) = contact {
                            contact.encode_response(pass);
                            if let Some(c) = collision {
                                c.encode_band(pass);
                            }
                        }
                        check.encode(pass, k);
                    }
                });
                self.timings.add("encode", started.elapsed().as_secs_f64());
                encoder
            }
            Stepper::Implicit(im) => {
                // Each step synchronises on its CG read-backs; the status is read at the end.
                for k in 0..batch {
                    let contact = self.body_contact.as_ref();
                    im.step(
                        &mut self.submitter,
                        &self.check,
                        contact,
                        k,
                        &mut self.timings,
                    )?;
                }
                self.submitter.encoder("status")
            }
        };
        let mut encoder = encoder;
        let size = std::mem::size_of::<Status>() as u64;
        let slot = self.in_flight.len() as u64;
        encoder.copy_buffer_to_buffer(
            &self.buffers.status,
            0,
            &self.status_ring,
            slot * size,
            size,
        );
        self.submitter.submit(encoder);
        self.in_flight.push((self.steps, batch));
        self.in_flight_since
            .get_or_insert_with(std::time::Instant::now);
        self.steps += batch;
        Ok(())
    }

    /// Waits for the submissions in flight and reads their statuses: the first instability
    /// among them, if any (the steps submitted then count up to it). Sizes the next
    /// submissions from the device time per step it saw.
    fn settle(&mut self) -> Result<(), StepError> {
        if self.in_flight.is_empty() {
            return Ok(());
        }
        let size = std::mem::size_of::<Status>();
        let started = std::time::Instant::now();
        let encoder = self.submitter.encoder("statuses");
        let bytes = self.submitter.submit_and_read(
            encoder,
            &[(&self.status_ring, (self.in_flight.len() * size) as u64)],
        )?;
        self.timings.add("device", started.elapsed().as_secs_f64());
        let in_flight = std::mem::take(&mut self.in_flight);
        if let Some(since) = self.in_flight_since.take() {
            let steps: u64 = in_flight.iter().map(|&(_, batch)| batch).sum();
            let per_step = since.elapsed().as_secs_f64() / steps as f64;
            let batch = (SUBMISSION_SECONDS / per_step.max(1e-9)) as u64;
            self.batch = Some(batch.clamp(1, STEPS_PER_SUBMISSION));
        }
        for (k, &(before, _)) in in_flight.iter().enumerate() {
            let status: Status = bytemuck::pod_read_unaligned(&bytes[k * size..(k + 1) * size]);
            if status.bad_step != NONE {
                let step = before + u64::from(status.bad_step);
                self.steps = step;
                let particle = status.bad_particle;
                return Err(StepError::Unstable(Instability {
                    step,
                    time: step as f64 * self.model.simulation.dt,
                    particle,
                    what: if status.bad_position == particle {
                        "has a non-finite position"
                    } else {
                        "has a non-finite velocity"
                    }
                    .to_owned(),
                }));
            }
        }
        Ok(())
    }
}

/// What the solver is built of: the device side of a [`Plan`].
struct Parts {
    builder: Builder,
    buffers: ModelBuffers,
    chunks: SpringChunks,
    stepper: Stepper,
    body_contact: Option<BodyContact>,
    collision_response: Option<CollisionResponse>,
    check: CheckFinite,
    energy: Energy,
}

impl Parts {
    /// The buffers and kernels of `plan` for `model` from `state`, on `gpu`.
    fn build(gpu: &Arc<Gpu>, plan: &Plan, model: &Model, state: &State) -> Result<Parts, GpuError> {
        let alignment = plan.limits.min_uniform_buffer_offset_alignment;
        let chunks = SpringChunks::new(
            &gpu.device,
            plan.chunking,
            plan.m,
            plan.spring_grids.clone(),
            alignment,
        );
        let builder = Builder::new(
            gpu.clone(),
            plan.limits.clone(),
            plan.chunking,
            &plan.terrain,
        )?;
        let buffers = ModelBuffers::new(
            &builder,
            model,
            state,
            plan.route,
            &chunks,
            plan.surfaces(),
            plan.particles.groups(),
            plan.spring_groups,
            alignment,
        );
        let s = Setup {
            builder: &builder,
            buffers: &buffers,
            chunks: &chunks,
            particles: plan.particles,
            n: plan.n,
        };
        let body_contact = model
            .contact
            .enabled()
            .then(|| BodyContact::new(s, model, plan.width, plan.max_rows))
            .transpose()?;
        let implicit = plan.integrator == Integrator::ImplicitEuler;
        let collision_response = match (implicit, plan.surfaces()) {
            (false, 1..) => Some(CollisionResponse::new(s)?),
            _ => None,
        };
        let around = Around {
            contact: body_contact.as_ref(),
            start: collision_response.as_ref().map(|c| &c.start),
            terrain: plan.surfaces() > 0,
            cg_tolerance: model.simulation.cg_tolerance,
        };
        let stepper = Stepper::new(s, around, plan.integrator, plan.route, plan.two_pass)?;
        let check = CheckFinite::new(s)?;
        let energy = Energy::new(s, plan.spring_groups)?;
        Ok(Parts {
            stepper,
            body_contact,
            collision_response,
            check,
            energy,
            buffers,
            chunks,
            builder,
        })
    }
}

impl Solver for GpuSolver {
    fn backend(&self) -> &'static str {
        "gpu"
    }

    fn device(&self) -> String {
        self.adapter()
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn advance(&mut self, steps: u64) -> Result<(), StepError> {
        self.submitter.healthy()?;
        if steps == 0 {
            return Ok(());
        }
        self.state_fresh = false;
        let mut done = 0;
        while done < steps {
            if self.in_flight.len() == STATUS_RING {
                self.settle()?;
            }
            let remaining = steps - done;
            let cycle = match &self.stepper {
                Stepper::Fused(fused) => fused.steps_per_cycle(),
                _ => 1,
            };
            // The first submission is one step, timed alone; then as many as fit the time, in
            // whole cycles of the fused Euler methods' ping-pong (two steps, even where one
            // would fill the time) while the steps asked for allow: no copy back but after
            // the first and an odd last.
            let batch = match self.batch {
                None => 1,
                Some(batch) if remaining >= cycle => {
                    batch.max(cycle).min(remaining) / cycle * cycle
                }
                Some(_) => remaining,
            };
            self.submit_batch(batch)?;
            if self.batch.is_none() {
                self.settle()?;
            }
            done += batch;
        }
        Ok(())
    }

    fn sync(&mut self) -> Result<(), StepError> {
        self.settle()?;
        self.submitter.wait()
    }

    fn steps_taken(&self) -> u64 {
        self.steps
    }

    fn state(&mut self) -> Result<&State, StepError> {
        self.submitter.healthy()?;
        self.settle()?;
        if !self.state_fresh {
            let started = std::time::Instant::now();
            let n = self.model.len() as u64;
            let (x, v) = (&self.buffers.x, &self.buffers.v);
            let encoder = self.submitter.encoder("read state");
            let bytes = self
                .submitter
                .submit_and_read(encoder, &[(x, n * VEC4), (v, n * VEC4)])?;
            let half = (n * VEC4) as usize;
            self.state.x = to_dvec3(&bytes[..half]);
            self.state.v = to_dvec3(&bytes[half..]);
            self.state_fresh = true;
            self.timings
                .add("read-back", started.elapsed().as_secs_f64());
        }
        Ok(&self.state)
    }

    fn set_state(&mut self, state: &State) -> Result<(), StepError> {
        self.submitter.healthy()?;
        self.settle()?;
        check_state_len(&self.model, state)?;
        if !self.model.is_empty() {
            let queue = self.submitter.queue();
            queue.write_buffer(&self.buffers.x, 0, bytemuck::cast_slice(&vec4s(&state.x)));
            queue.write_buffer(&self.buffers.v, 0, bytemuck::cast_slice(&vec4s(&state.v)));
        }
        self.state_fresh = false;
        self.band_stale = true;
        Ok(())
    }

    fn set_controls(&mut self, controls: Option<Controls>) -> Result<(), StepError> {
        match controls {
            None => Ok(()),
            Some(_) => Err(StepError::Invalid(crate::NO_CONTROLS.into())),
        }
    }

    fn controls(&self) -> Option<&Controls> {
        None
    }

    fn history(&mut self) -> Result<History, StepError> {
        self.submitter.healthy()?;
        self.settle()?;
        match &self.stepper {
            Stepper::Implicit(im) if !self.model.is_empty() => im.history(&mut self.submitter),
            _ => Ok(History::default()),
        }
    }

    fn restore(&mut self, steps: u64, state: &State, history: &History) -> Result<(), StepError> {
        self.set_state(state)?;
        match &mut self.stepper {
            Stepper::Implicit(im) if !self.model.is_empty() => {
                im.restore(&self.submitter, history)?
            }
            _ if history.parts.is_empty() => {}
            _ => {
                return Err(StepError::Invalid(
                    "restore: the history is not this solver's integrator's".to_owned(),
                ));
            }
        }
        self.steps = steps;
        Ok(())
    }

    fn energies(&mut self) -> Result<Energies, StepError> {
        self.submitter.healthy()?;
        self.settle()?;
        let started = std::time::Instant::now();
        let energies = self.energy.energies(&mut self.submitter)?;
        self.timings
            .add("energies", started.elapsed().as_secs_f64());
        Ok(energies)
    }

    fn statistics(&self) -> Statistics {
        let implicit = match &self.stepper {
            Stepper::Implicit(im) => im.statistics.clone(),
            Stepper::PerSpring(_) | Stepper::Fused(_) => Statistics::default(),
        };
        let (dispatches, device_bytes) = self.builder.traffic().totals();
        Statistics {
            steps: self.steps,
            timings: self.timings.clone(),
            dispatches,
            device_bytes,
            // The designs of `integrators/`: each particle's springs computed by the particle as
            // it gathers them, one dispatch per stage (found on the lattices or through the
            // adjacency); or per-spring forces in chunks, gathered per particle through the
            // adjacency.
            kernel: match &self.stepper {
                Stepper::Implicit(implicit) => implicit.kernel(),
                Stepper::Fused(fused) => fused.kernel(),
                Stepper::PerSpring(_) => "per-spring + gather",
            },
            ..implicit
        }
    }

    /// Device buffers: the model, the state, the integrator's and the stages' scratch, the
    /// read-back buffer.
    fn memory_bytes(&self) -> u64 {
        self.builder.bytes() + self.submitter.readback_bytes()
    }
}
