//! Implicit Euler on the GPU, the twin of `softbody_cpu::integrators::implicit_euler`: the
//! linearised backward-Euler system ([`system`], `shaders/system.wgsl`), solved by filtered PCG
//! ([`cg`], `shaders/cg.wgsl`), with contacts as velocity constraints and an active set
//! (`shaders/implicit_euler.wgsl`).
//!
//! # A step
//!
//! | submission | dispatches | read back |
//! |---|---|---|
//! | first | start grid (bodies) → assemble (springs, pairs, particles) → candidates (terrain) → `implicit_remember` → round → batch | scalars, changed |
//! | while CG runs | batch | scalars, changed |
//! | next round (active set changed) | round → batch | scalars, changed |
//! | last | finish → end grid and response (bodies) → `check_finite` | nothing (the status at the end of `advance`) |
//!
//! where `implicit_remember` moves the warm start's history on (the last three steps' Δv), a
//! round is `implicit_constrain` → the CG's start (the warm start projected on that history,
//! then the residual), and a batch is a run of CG
//! iterations (the first batch of a solve as many as the last solve took plus 2, later ones
//! [`ITERATIONS_PER_BATCH`]) followed, with terrain, by the active-set update (A Δv →
//! `implicit_active_set`), dispatched from the "finished" argument slots so that it runs once,
//! in the batch where the solve ended. So a solve costs one submission and read-back of 68 bytes
//! (the [`CgScalars`] and the active set's `changed` word) when it takes no more iterations
//! than the last one (plus 2), one more per 16 iterations beyond, and a step at least one.
//!
//! The CG stopping rule is the CPU's (relative preconditioned residual, round-off growth, cap),
//! with the scene's tolerance at no less than [`CG_TOLERANCE_F32`] (the default 1e-8 is below
//! what f32 resolves) and a
//! floor at what the f32 state resolves of the right-hand side (each spring's h k_s ε with ε
//! half a ulp of its ends' coordinates; `shaders/cg.wgsl`, docs/physics.md): without it a
//! stiff body's solves resolve the forces of its positions' rounding, 25–33 iterations a step
//! for a 10³ cube in free fall.
//!
//! Where bodies touch ([`crate::body_contact`]), as on the CPU: the pairs in contact at the
//! step's start push apart inside the solve, as springs of the system (the grid of the start
//! state is built before the assembly and searched by every product, [`system`]), and after
//! the update comes the response between bodies of the explicit integrators.

pub mod cg;
pub mod system;

use softbody_scene::implicit::{ACTIVE_SET_ROUNDS, CG_MAX_ITERATIONS};
use softbody_scene::{History, Statistics, StepError, Timings};

use self::cg::Cg;
use self::system::{System, Vector};
use crate::body_contact::BodyContact;
use crate::buffers::Setup;
use crate::check_finite::CheckFinite;
use crate::grid::Grid;
use crate::integrators::Around;
use crate::kernel::{Call, Resources};
use crate::layout::{
    CG_DISPATCH_WORDS, CG_PARTIAL_HALVES, CandidateGpu, CgScalars, SpringBlockGpu, dispatch_slot,
};
use crate::shaders::Stage;
use crate::submit::Submitter;
use crate::{GpuError, VEC4};

/// The floor of CG's relative tolerance on the GPU (preconditioned residual norm, as the
/// scene's `cg_tolerance`, 1e-8 by default): f32 resolves about 6e-8 relative per operation, and the
/// recursively updated residual of an f32 CG drifts from the true one by about that times the
/// condition number, so 1e-5 is as far as a solve can usefully go; it is reached in a few dozen
/// iterations on the test scenes (see the adapter tests for the measured residuals).
pub const CG_TOLERANCE_F32: f32 = 1e-5;

/// CG iterations per batch (one submission and read-back of the scalars each) after a solve's
/// first, which is sized from the last solve's count (plus 2, between 4 and 4 × this).
pub const ITERATIONS_PER_BATCH: u32 = 16;

/// The first batch of a solve has the last solve's iterations plus this many (and at least 4):
/// consecutive solves take similar counts, so most solves need one submission, and few empty
/// dispatches (which software adapters do not get for free) are encoded.
const BATCH_MARGIN: u32 = 2;

/// Byte offsets of a pair of argument slots in the CG's dispatch buffer.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Slots {
    /// Per-spring kernels.
    pub springs: u64,
    /// Per-particle kernels.
    pub particles: u64,
}

/// Full grids while a solve runs, empty once it is done.
pub(crate) const SLOTS_RUNNING: Slots = Slots {
    springs: dispatch_slot::SPRINGS,
    particles: dispatch_slot::PARTICLES,
};

/// Empty while a solve runs, full once it is done.
pub(crate) const SLOTS_FINISHED: Slots = Slots {
    springs: dispatch_slot::FINISHED_SPRINGS,
    particles: dispatch_slot::FINISHED_PARTICLES,
};

/// Implicit Euler's own buffers.
pub(crate) struct Buffers {
    pub b: wgpu::Buffer,
    pub rhs: wgpu::Buffer,
    pub z: wgpu::Buffer,
    pub dv: wgpu::Buffer,
    pub q: wgpu::Buffer,
    pub r: wgpu::Buffer,
    pub c: wgpu::Buffer,
    /// The inverse diagonal blocks, two `vec4` per particle.
    pub diag: wgpu::Buffer,
    pub constraints: wgpu::Buffer,
    /// Spring blocks, one buffer per spring chunk.
    pub blocks: Vec<wgpu::Buffer>,
    pub candidates: wgpu::Buffer,
    /// Per-workgroup partial sums of the CG's dot products, in two halves (`cg.wgsl`).
    pub partials: wgpu::Buffer,
    pub scalars: wgpu::Buffer,
    pub dispatch: wgpu::Buffer,
    pub changed: wgpu::Buffer,
    /// The warm start's history (`implicit_remember`): the last step's Δv while this step's
    /// solves replace it, and the two steps' before it.
    pub last: wgpu::Buffer,
    pub earlier_1: wgpu::Buffer,
    pub earlier_2: wgpu::Buffer,
}

impl Buffers {
    /// Sized for the setup's model, CG stopping at `tolerance`.
    fn new(s: Setup<'_>, tolerance: f32) -> Buffers {
        let builder = s.builder;
        let vectors = |label| builder.storage(label, s.n, VEC4);
        let settings = CgScalars {
            tolerance,
            max_iterations: CG_MAX_ITERATIONS,
            n_partials: s.particles.groups() as u32,
            particle_grid: [s.particles.x, s.particles.y],
            spring_grid: [s.chunks.largest_grid().x, s.chunks.largest_grid().y],
            ..CgScalars::default()
        };
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        Buffers {
            b: vectors("b"),
            rhs: vectors("rhs"),
            z: vectors("z"),
            dv: vectors("dv"),
            q: vectors("q"),
            r: vectors("r"),
            c: vectors("c"),
            diag: builder.storage("diag", 2 * s.n, VEC4),
            constraints: vectors("constraints"),
            blocks: s
                .chunks
                .ranges
                .iter()
                .map(|&(_, count)| {
                    builder.storage(
                        "blocks",
                        count,
                        std::mem::size_of::<SpringBlockGpu>() as u64,
                    )
                })
                .collect(),
            // Zeroed: no particle was touching before the first step.
            candidates: builder.storage(
                "candidates",
                s.n,
                std::mem::size_of::<CandidateGpu>() as u64,
            ),
            partials: builder.storage("cg partials", CG_PARTIAL_HALVES * s.particles.groups(), 8),
            scalars: builder.init("cg scalars", bytemuck::bytes_of(&settings), storage),
            dispatch: builder.init(
                "cg dispatch",
                &[0u8; CG_DISPATCH_WORDS * 4],
                storage | wgpu::BufferUsages::INDIRECT,
            ),
            changed: builder.storage("changed", 1, 4),
            // Zeroed: the first steps' bases leave the missing solutions out.
            last: vectors("last"),
            earlier_1: vectors("earlier_1"),
            earlier_2: vectors("earlier_2"),
        }
    }

    /// `r` with these buffers added by their shader names (the gathers' blocks as chunks;
    /// `out` of the products is q).
    pub fn resources<'a>(&'a self, r: Resources<'a>) -> Resources<'a> {
        r.buffer("b", &self.b)
            .buffer("rhs", &self.rhs)
            .buffer("z", &self.z)
            .buffer("dv", &self.dv)
            .buffer("q", &self.q)
            .buffer("out", &self.q)
            .buffer("r", &self.r)
            .buffer("c", &self.c)
            .buffer("diag", &self.diag)
            .buffer("constraints", &self.constraints)
            .chunks("blocks", "block", &self.blocks)
            .buffer("candidates", &self.candidates)
            .buffer("partials", &self.partials)
            .buffer("scalars", &self.scalars)
            .buffer("dispatch", &self.dispatch)
            .buffer("changed", &self.changed)
            .buffer("last", &self.last)
            .buffer("earlier_1", &self.earlier_1)
            .buffer("earlier_2", &self.earlier_2)
    }
}

/// What one read-back after a batch says.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Progress {
    pub scalars: CgScalars,
    pub changed: bool,
}

/// The contact kernels of `implicit_euler.wgsl` that only run with terrain.
struct Contacts {
    candidates: Call,
    active_set: Call,
}

/// Implicit Euler's buffers, calls and counters.
pub(crate) struct ImplicitEuler {
    buffers: Buffers,
    system: System,
    cg: Cg,
    constrain: Call,
    remember: Call,
    contacts: Option<Contacts>,
    finish: Call,
    particles: Grid,
    /// Particles: a model without any takes no steps.
    n: u64,
    /// Iterations of the last solve.
    last_iterations: u32,
    /// Counters over the run.
    pub statistics: Statistics,
}

impl ImplicitEuler {
    /// Its buffers and calls; `around`: the contact between bodies (for models whose bodies
    /// touch), whether the scene has terrain to touch and its CG tolerance; `two_pass`: the
    /// product in two passes even where the fused one fits ([`System::new`]).
    pub fn new(
        s: Setup<'_>,
        around: Around<'_>,
        two_pass: bool,
    ) -> Result<ImplicitEuler, GpuError> {
        let (contact, terrain) = (around.contact, around.terrain);
        let tolerance = CG_TOLERANCE_F32.max(around.cg_tolerance as f32);
        let buffers = Buffers::new(s, tolerance);
        let resources = buffers.resources(s.buffers.resources());
        let call = |entry| s.builder.call(Stage::ImplicitEuler, entry, &resources);
        let contacts = match terrain {
            true => Some(Contacts {
                candidates: call("implicit_candidates")?,
                active_set: call("implicit_active_set")?,
            }),
            false => None,
        };
        Ok(ImplicitEuler {
            system: System::new(s, contact, &buffers, two_pass)?,
            cg: Cg::new(s, &buffers)?,
            constrain: call("implicit_constrain")?,
            remember: call("implicit_remember")?,
            finish: call("implicit_finish")?,
            contacts,
            particles: s.particles,
            n: s.n,
            last_iterations: ITERATIONS_PER_BATCH,
            statistics: Statistics::default(),
            buffers,
        })
    }

    /// What the next step starts from besides the state, read back: the warm start Δv and the
    /// two steps' before it (`dv-earlier`, the latest first, as the CPU's), the contact records
    /// (who touches and sticks) and the last solve's iteration count (which sizes the next
    /// solve's first batch).
    pub fn history(&self, submitter: &mut Submitter) -> Result<History, StepError> {
        let b = &self.buffers;
        let n = self.n;
        let vector = (n * VEC4) as usize;
        let candidates = n * std::mem::size_of::<CandidateGpu>() as u64;
        let encoder = submitter.encoder("read history");
        let bytes = submitter.submit_and_read(
            encoder,
            &[
                (&b.dv, n * VEC4),
                (&b.last, n * VEC4),
                (&b.earlier_1, n * VEC4),
                (&b.candidates, candidates),
            ],
        )?;
        let (dv, rest) = bytes.split_at(vector);
        let (earlier, candidates) = rest.split_at(2 * vector);
        let mut history = History::default();
        history.push("dv", dv.to_vec());
        history.push("dv-earlier", earlier.to_vec());
        history.push("candidates", candidates.to_vec());
        history.push(
            "last iterations",
            self.last_iterations.to_le_bytes().to_vec(),
        );
        Ok(history)
    }

    /// Takes up [`ImplicitEuler::history`]'s.
    pub fn restore(&mut self, submitter: &Submitter, history: &History) -> Result<(), StepError> {
        let n = self.n as usize;
        let vector = n * VEC4 as usize;
        let dv = history.part("dv", vector)?;
        let candidates = history.part("candidates", n * std::mem::size_of::<CandidateGpu>())?;
        let iterations = history.part("last iterations", 4)?;
        let queue = submitter.queue();
        queue.write_buffer(&self.buffers.dv, 0, dv);
        // A history without the earlier solutions (written before the warm start combined
        // them) leaves them zero: the next step starts from the last Δv alone. The next step's
        // `implicit_remember` moves `last` and `earlier_1` on and overwrites `earlier_2`.
        let mut earlier = vec![0u8; 2 * vector];
        if history.parts.iter().any(|(name, _)| name == "dv-earlier") {
            earlier.copy_from_slice(history.part("dv-earlier", 2 * vector)?);
        }
        let (previous, before) = earlier.split_at(vector);
        queue.write_buffer(&self.buffers.last, 0, previous);
        queue.write_buffer(&self.buffers.earlier_1, 0, before);
        queue.write_buffer(&self.buffers.candidates, 0, candidates);
        self.last_iterations = u32::from_le_bytes(iterations.try_into().expect("4 bytes"));
        Ok(())
    }

    /// Its buffers.
    #[cfg(feature = "debug")]
    pub fn buffers(&self) -> &Buffers {
        &self.buffers
    }

    /// Linearises at the current (x, v): b, the spring blocks and the preconditioner, with the
    /// pairs of bodies in contact there (`contact`: given exactly when the model has contact
    /// between bodies), whose grid it builds first; with terrain, the contact candidates.
    pub fn encode_assemble(&self, pass: &mut wgpu::ComputePass<'_>, contact: Option<&BodyContact>) {
        if let Some(contact) = contact {
            contact.encode_start(pass);
        }
        self.system.encode_assemble(pass);
        if let Some(contacts) = &self.contacts {
            contacts.candidates.run(pass, self.particles);
        }
    }

    /// A solve's start: constraints, z and rhs from the candidates (unless `constrain` is
    /// false: the twin tests write them), the warm start, the residual and the scalars.
    pub fn encode_round(&self, pass: &mut wgpu::ComputePass<'_>, constrain: bool) {
        if constrain {
            self.constrain.run(pass, self.particles);
        }
        self.cg.encode_start(pass, &self.system);
    }

    /// A batch of CG iterations (the first of a solve, or a later one), then, with terrain, the
    /// active-set update (empty until the solve is done).
    pub fn encode_batch(&self, pass: &mut wgpu::ComputePass<'_>, first: bool) {
        let iterations = if first {
            (self.last_iterations + BATCH_MARGIN).clamp(4, 4 * ITERATIONS_PER_BATCH)
        } else {
            ITERATIONS_PER_BATCH
        };
        self.cg.encode_iterations(pass, &self.system, iterations);
        if let Some(contacts) = &self.contacts {
            self.system
                .encode_apply(pass, Vector::Dv, Some(SLOTS_FINISHED));
            contacts.active_set.run_indirect(
                pass,
                &self.buffers.dispatch,
                SLOTS_FINISHED.particles,
            );
        }
    }

    /// The design's name in `Statistics::kernel`: the product fused or in two passes.
    pub fn kernel(&self) -> &'static str {
        match self.system.fused() {
            true => "matrix-free, fused product",
            false => "matrix-free",
        }
    }

    /// A Δv into q, on the full grids (for the system twin test, with Δv uploaded as p).
    #[cfg(feature = "debug")]
    pub fn encode_apply_dv(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.system.encode_apply(pass, Vector::Dv, None);
    }

    /// `iterations` CG iterations alone (for the test of the dispatches an iteration takes).
    #[cfg(feature = "debug")]
    pub fn encode_iterations(&self, pass: &mut wgpu::ComputePass<'_>, iterations: u32) {
        self.cg.encode_iterations(pass, &self.system, iterations);
    }

    /// Submits `encoder` (after resetting the active set's `changed` word) and runs CG batches
    /// until the solve it begins is done; counts the solve and returns its last progress.
    pub fn solve(
        &mut self,
        submitter: &mut Submitter,
        encoder: wgpu::CommandEncoder,
    ) -> Result<Progress, StepError> {
        submitter
            .queue()
            .write_buffer(&self.buffers.changed, 0, bytemuck::bytes_of(&0u32));
        let mut progress = self.progress(submitter, encoder)?;
        while progress.scalars.done == 0 {
            let encoder = submitter.encode_pass("cg batch", |pass| self.encode_batch(pass, false));
            progress = self.progress(submitter, encoder)?;
        }
        let scalars = progress.scalars;
        let st = &mut self.statistics;
        st.cg_iterations += u64::from(scalars.iterations);
        st.cg_solves += 1;
        st.cg_max_residual = st.cg_max_residual.max(scalars.relative_residual());
        self.last_iterations = scalars.iterations;
        Ok(progress)
    }

    /// Submits `encoder` and reads the CG's scalars and the `changed` word back.
    fn progress(
        &self,
        submitter: &mut Submitter,
        encoder: wgpu::CommandEncoder,
    ) -> Result<Progress, StepError> {
        let size = std::mem::size_of::<CgScalars>();
        let bytes = submitter.submit_and_read(
            encoder,
            &[
                (&self.buffers.scalars, size as u64),
                (&self.buffers.changed, 4),
            ],
        )?;
        Ok(Progress {
            scalars: bytemuck::pod_read_unaligned(&bytes[..size]),
            changed: bytemuck::pod_read_unaligned::<u32>(&bytes[size..size + 4]) != 0,
        })
    }

    /// Step `k` (0-based) of a submission of `advance`: the solves until the active set
    /// settles (at most [`ACTIVE_SET_ROUNDS`]), then the update, the response between bodies
    /// (`contact`, given exactly when the model has contact between bodies) and `check`.
    pub fn step(
        &mut self,
        submitter: &mut Submitter,
        check: &CheckFinite,
        contact: Option<&BodyContact>,
        k: u64,
        timings: &mut Timings,
    ) -> Result<(), StepError> {
        if self.n == 0 {
            return Ok(());
        }
        let started = std::time::Instant::now();
        let encoder = submitter.encode_pass("implicit step", |pass| {
            self.encode_assemble(pass, contact);
            self.remember.run(pass, self.particles);
            self.encode_round(pass, true);
            self.encode_batch(pass, true);
        });
        let mut progress = self.solve(submitter, encoder)?;
        let mut rounds = 1;
        while self.contacts.is_some() && progress.changed && rounds < ACTIVE_SET_ROUNDS {
            let encoder = submitter.encode_pass("active-set round", |pass| {
                self.encode_round(pass, true);
                self.encode_batch(pass, true);
            });
            progress = self.solve(submitter, encoder)?;
            rounds += 1;
        }
        timings.add("assemble + cg (device)", started.elapsed().as_secs_f64());
        let encoder = submitter.encode_pass("implicit finish", |pass| {
            self.finish.run(pass, self.particles);
            if let Some(contact) = contact {
                contact.encode_response(pass);
            }
            check.encode(pass, k);
        });
        submitter.submit(encoder);
        Ok(())
    }
}
