//! `shaders/body_contact.wgsl` ↔ `softbody_cpu::body_contact`: contact between particles of
//! bodies, for every integrator (docs/physics.md, "Contact between bodies").
//!
//! A pair (i, j) touches when admitted (different bodies, or one body with self-contact beyond
//! its rest neighbourhood) and d = |x_i − x_j| < R = r_i + r_j. Per step:
//!
//! 1. at the start, the grid of the start state (`broad_phase`, which keeps a snapshot of it);
//! 2. the critically damped penalty F = max(0, k (R − d) − c (u·n)) n, k = κ m_red/h²,
//!    c = 2√(k m_red), of each pair in contact at the start: in every stage of the explicit
//!    integrators, `pair_forces` evaluates it at the stage state into `a`, which
//!    `accelerations_with_pairs` adds to the spring forces (`forces`); implicit Euler takes it
//!    into its linear system as a spring along n, linearised at the start (`pair_system` and
//!    `pair_products` before the system's per-particle kernels,
//!    `integrators::implicit_euler::system`);
//! 3. after the step and its terrain collision response, the grid of the end state and
//!    `body_contact_response`: per particle, the Jacobi sum of ±w·(P, Δ) over its pairs in
//!    contact at the end, P the normal (restitution on a fresh impact) and friction impulse and
//!    Δ the push beyond the slop, each computed from the end and start snapshots.
//!
//! The partners of a particle are not stored: each stage searches the start grid again (the
//! 27 cells around the particle, the same distance test on the same snapshot, so the same
//! partners every stage). That needs no capacity fixed in advance — the pairs of a scene are
//! unknown until it runs, and the device cannot grow a buffer mid-submission — and costs a
//! search per stage where a stored list would cost two searches (count, then fill) and a prefix
//! sum per step.
//!
//! Every pair is evaluated in the orientation (min, max) by both of its particles' threads, so
//! the two get bit-equal and opposite forces, impulses and pushes, and each thread sums its own
//! in the search's order (a function of the positions alone): no float atomics, the same bits
//! run to run. Implicit Euler's products search the start grid again each time (its pairs'
//! blocks are a function of the start snapshot, which nothing writes until the step's end), so
//! its matrix is the same, and symmetric, in every product of a step.

use softbody_scene::Model;
use softbody_scene::model::{SELF_CONTACT_EXCLUSION, SLOP, penalty};

use crate::broad_phase::{BroadPhase, Snapshot, count_words};
use crate::buffers::{ModelBuffers, Setup};
use crate::grid::Grid;
use crate::kernel::{Call, Resources};
use crate::layout::{ContactParams, ContactParticleGpu, friction_code};
use crate::shaders::Stage;
use crate::{GpuError, VEC4};

/// The grid's cell over 2·r_max: enough that f32 rounding of x/s cannot put two particles
/// closer than r_i + r_j two cells apart.
const CELL_MARGIN: f64 = 1e-3;

/// Buckets of the grid for `n` particles: a power of two ≥ 2n (the CPU's table size).
pub(crate) fn buckets(n: u64) -> u64 {
    (2 * n).max(1).next_power_of_two()
}

/// The storage a model's contact between bodies needs, as (what, elements, bytes each), for the
/// limits check: the snapshot (x and v at the step's start and end), the contact data, the
/// grid, the rest neighbours of `particles` bodies with self-contact.
pub(crate) fn needs(model: &Model) -> [(&'static str, u64, u64); 5] {
    let n = model.len() as u64;
    [
        ("contact snapshot", 2 * n, VEC4),
        (
            "contact particles",
            n,
            std::mem::size_of::<ContactParticleGpu>() as u64,
        ),
        ("broad-phase counts", count_words(buckets(n)), 4),
        ("broad-phase particles", n, 4),
        ("rest neighbours", rest_neighbours(model).len() as u64, 4),
    ]
}

/// The contact data of each particle.
fn contact_particles(model: &Model) -> Vec<ContactParticleGpu> {
    let c = &model.contact;
    (0..model.len())
        .map(|i| {
            let body = c.body[i];
            let lattice = c.lattice[i];
            let flags = if c.self_contact[body as usize] {
                ContactParticleGpu::SELF_CONTACT
            } else {
                0
            } | if lattice.is_some() {
                ContactParticleGpu::LATTICE
            } else {
                0
            };
            ContactParticleGpu {
                lattice: lattice.unwrap_or_default(),
                body,
                radius: c.radius[i] as f32,
                inv_mass: model.inv_mass[i] as f32,
                flags,
                _pad: 0,
            }
        })
        .collect()
}

/// For a model with a `particles` body in self-contact, the adjacency's offsets followed by the
/// particle at the other end of each entry's spring (the admit rule's "joined by a spring");
/// empty otherwise.
fn rest_neighbours(model: &Model) -> Vec<u32> {
    let c = &model.contact;
    let needed =
        (0..model.len()).any(|i| c.lattice[i].is_none() && c.self_contact[c.body[i] as usize]);
    if !needed {
        return Vec::new();
    }
    let adjacency = model.adjacency();
    let springs = model.springs();
    let mut words = adjacency.offsets.clone();
    for i in 0..model.len() {
        words.extend(adjacency.of(i).iter().map(|&e| {
            let s = (e >> 1) as usize;
            springs.a[s] + springs.b[s] - i as u32
        }));
    }
    words
}

/// The buffers of the contact data and the state's snapshots.
struct ContactBuffers {
    /// [`ContactParams`].
    contact: wgpu::Buffer,
    particles: wgpu::Buffer,
    rest_neighbours: wgpu::Buffer,
    /// Positions and velocities at the step's start, then at its end.
    snapshot_x: wgpu::Buffer,
    snapshot_v: wgpu::Buffer,
}

impl ContactBuffers {
    fn resources<'a>(&'a self, resources: Resources<'a>) -> Resources<'a> {
        resources
            .buffer("contact", &self.contact)
            .buffer("particles", &self.particles)
            .buffer("rest_neighbours", &self.rest_neighbours)
            .buffer("snapshot_x", &self.snapshot_x)
            .buffer("snapshot_v", &self.snapshot_v)
    }
}

/// The contact's buffers, the grid and the response.
pub(crate) struct BodyContact {
    buffers: ContactBuffers,
    broad: BroadPhase,
    response: Call,
    particles: Grid,
}

impl BodyContact {
    /// The contact between the bodies of `model` (`model.contact.enabled()`); dispatch grids
    /// are rows of at most `width` workgroups, at most `max_rows` rows.
    pub fn new(
        s: Setup<'_>,
        model: &Model,
        width: u32,
        max_rows: u32,
    ) -> Result<BodyContact, GpuError> {
        let c = &model.contact;
        let r_max = c.radius.iter().copied().fold(0.0, f64::max);
        let buckets = buckets(s.n);
        let params = ContactParams {
            inv_cell: (1.0 / (2.0 * r_max * (1.0 + CELL_MARGIN))) as f32,
            buckets: buckets as u32,
            restitution: c.laws.restitution as f32,
            friction: c.laws.friction as f32,
            friction_model: friction_code(c.laws.friction_model),
            penalty: penalty(model.simulation.integrator) as f32,
            slop: SLOP as f32,
            exclusion: SELF_CONTACT_EXCLUSION,
        };
        let b = s.builder;
        let buffers = ContactBuffers {
            contact: b.init(
                "contact",
                bytemuck::bytes_of(&params),
                wgpu::BufferUsages::UNIFORM,
            ),
            particles: b.storage_init(
                "particles",
                bytemuck::cast_slice(&contact_particles(model)),
                std::mem::size_of::<ContactParticleGpu>(),
            ),
            rest_neighbours: b.storage_init(
                "rest_neighbours",
                bytemuck::cast_slice(&rest_neighbours(model)),
                4,
            ),
            snapshot_x: b.storage("snapshot_x", 2 * s.n, VEC4),
            snapshot_v: b.storage("snapshot_v", 2 * s.n, VEC4),
        };
        let grid = |threads| {
            Grid::with_width(threads, width, max_rows).ok_or_else(|| {
                // Only with a narrow test width: check_limits checked the adapter's.
                GpuError::Unsupported(format!(
                    "the broad phase needs more than {max_rows} rows of {width} workgroups"
                ))
            })
        };
        let broad = BroadPhase::new(s, &buffers.resources(s.buffers.resources()), buckets, grid)?;
        let resources = broad.resources(buffers.resources(s.buffers.resources()));
        let response = b.call(Stage::BodyContact, "body_contact_response", &resources)?;
        Ok(BodyContact {
            buffers,
            broad,
            response,
            particles: s.particles,
        })
    }

    /// The model's buffers with the contact's and the grid's, as the searches bind them.
    pub fn resources<'a>(&'a self, model: &'a ModelBuffers) -> Resources<'a> {
        self.broad
            .resources(self.buffers.resources(model.resources()))
    }

    /// The penalty forces of the stage state `(x, v)` (the solver's, or a stage's) into `a`.
    pub fn pair_forces(
        &self,
        s: Setup<'_>,
        x: &wgpu::Buffer,
        v: &wgpu::Buffer,
    ) -> Result<Call, GpuError> {
        let resources = self.resources(s.buffers).buffer("x", x).buffer("v", v);
        s.builder
            .call(Stage::BodyContact, "pair_forces", &resources)
    }

    /// The snapshot buffers: x and v, each the step's start (particles [0, n)) then its end.
    #[cfg(feature = "debug")]
    pub fn snapshots(&self) -> [&wgpu::Buffer; 2] {
        [&self.buffers.snapshot_x, &self.buffers.snapshot_v]
    }

    /// Encodes the snapshot of the solver's state as `snapshot` and its grid.
    #[cfg(feature = "debug")]
    pub fn encode_grid(&self, pass: &mut wgpu::ComputePass<'_>, snapshot: Snapshot) {
        self.broad.encode(pass, snapshot);
    }

    /// Encodes what the step's start needs: its snapshot and grid.
    pub fn encode_start(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.broad.encode(pass, Snapshot::Start);
    }

    /// Encodes the response at the step's end: the end's snapshot and grid, then the response.
    pub fn encode_response(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.broad.encode(pass, Snapshot::End);
        self.response.run(pass, self.particles);
    }
}
