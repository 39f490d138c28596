//! The model both solvers step: particles, springs and their CSR adjacency, bodies, terrain.
//!
//! A [`Model`] is immutable once built; the changing part is the [`State`] (positions and
//! velocities). Springs are stored as a structure of arrays, and each particle's springs as one
//! contiguous run of the adjacency (compressed sparse rows), so that per-particle force sums are
//! gathers in a fixed order: the same bits whatever the thread count, and the scheme the GPU
//! uses too, since WGSL has no float atomics.
//!
//! # Lean cuboids
//!
//! A lattice body's springs are a stencil ([`Lattice`]): the same offsets and parameters at
//! every particle (a mesh body's masked to its kept cells). The model keeps only the stencil
//! for them, so that a large cube stepped by a
//! stencil kernel holds no per-spring array at all (a 300³ cube has 423 M springs: 13.5 GB as
//! a list, 3.4 GB more as an adjacency). [`Model::springs`] and [`Model::adjacency`] build
//! the full list and its adjacency on first use and keep them, for the consumers that read
//! springs by index (the gather and sweep routes, implicit Euler, the GPU, the exports);
//! [`Model::for_each_spring`] visits every spring in the same order without building anything.

use glam::DVec3;

use crate::format::SurfaceKind;
use crate::scene::{BodyContact, BodyShape, Scene, Simulation, SpringCounts, Terrain};
use crate::topology::{self, SpringKind};

/// Most particles a scene may hold (indices are u32).
pub const MAX_PARTICLES: u64 = u32::MAX as u64 - 1;
/// Most springs a scene may hold (the adjacency stores `2·spring + side` in a u32).
pub const MAX_SPRINGS: u64 = (u32::MAX >> 1) as u64;

/// Upper estimate of what a solver holds per particle: state, mass, adjacency offsets and the
/// largest integrator scratch (implicit Euler's vectors and its multigrid hierarchy, about
/// 600 B per particle; RK4 keeps four stage derivatives and a trial state).
pub const BYTES_PER_PARTICLE: u64 = 1024;
/// Upper estimate per spring: topology, parameters, two adjacency entries, per-spring force and
/// the implicit solver's Jacobian data.
pub const BYTES_PER_SPRING: u64 = 144;

/// Estimated bytes a solver needs for a scene of this size (saturating), springs listed.
pub fn estimated_bytes(particles: u64, springs: u64) -> u64 {
    particles
        .saturating_mul(BYTES_PER_PARTICLE)
        .saturating_add(springs.saturating_mul(BYTES_PER_SPRING))
}

/// What the CPU solver holds per particle for a model of cuboids only (springs kept as
/// stencils, no list: see [`Model`]) under `integrator`, in the limit of large bodies. The
/// explicit integrators: 44 B of the model (masses 16, the contact arrays 28) and 48 B per
/// state they keep (the state and the passes' second state; midpoint one stage state more,
/// RK4 two). Implicit Euler lists no springs on lattices either, but keeps its right-hand
/// sides, CG's vectors, the diagonal blocks and their inverses, 1/ℓ per spring and the
/// multigrid's levels (the first coarse level's 27 blocks per node, and its sources naming
/// each spring twice): 1,340–1,388 B per particle on cubes from 22³ to 200³ (BENCHMARKS.md,
/// "Memory"), and since 2026-11-29 24 B more (the positions the multigrid's kept values were
/// computed at) and 72 B more (the earlier steps' Δv that the warm start combines, and a
/// copy of the last): 1,412 B on the 40³ cube, so 1.5 kB. `crates/cpu/tests/lean.rs` holds
/// the solver to it.
///
/// The figure is the CPU solver's. A GPU solver's needs are not estimated: its host keeps the
/// model and stages the uploads, and a software adapter's buffers are in this machine's memory
/// too.
pub fn lean_bytes_per_particle(integrator: crate::Integrator) -> u64 {
    use crate::Integrator::*;
    let states = match integrator {
        ExplicitEuler | SymplecticEuler => 2,
        Midpoint => 3,
        Rk4 => 4,
        ImplicitEuler => return 1_500,
    };
    44 + 48 * states
}

/// Estimated bytes a solver needs for `scene` (saturating): [`lean_bytes_per_particle`] for
/// one cuboid without self-contact (a quarter more for the explicit stencil's slabs, a few
/// planes per thread; implicit Euler's dense factor of its coarsest level, at most 2.9 MB
/// whatever the size, is left out), else [`estimated_bytes`].
pub fn estimated_scene_bytes(scene: &Scene) -> u64 {
    let particles = scene.particle_count();
    match scene.bodies.as_slice() {
        [body] if matches!(body.shape, BodyShape::Cuboid(_)) && !body.self_contact => {
            let bytes = lean_bytes_per_particle(scene.simulation.integrator);
            particles.saturating_mul(bytes + bytes / 4)
        }
        _ => estimated_bytes(particles, scene.spring_counts().total()),
    }
}

/// Memory this process may still allocate, where the platform says, and what limits it: the
/// least of the machine's free memory (Linux: `MemAvailable`), what its cgroup's memory limit
/// leaves (v2 `memory.max` − `memory.current` of its cgroup and every ancestor, or v1
/// `memory.limit_in_bytes` − `memory.usage_in_bytes`), and what its address-space limit
/// (`RLIMIT_AS`, `ulimit -v`) leaves above its current size. A scene is refused against it
/// before anything is allocated, rather than aborting on a failed allocation (a container's
/// OOM kill, or a `ulimit -v` abort).
pub fn available_memory() -> Option<(u64, &'static str)> {
    let read = |path: &str| std::fs::read_to_string(path).ok();
    let machine = read("/proc/meminfo")
        .and_then(|t| kib_field(&t, "MemAvailable:"))
        .map(|b| (b, "available on this machine"));
    let cgroup = read("/proc/self/cgroup")
        .and_then(|t| cgroup_room(&t, &|p| read(p)))
        .map(|b| (b, "left by this process's cgroup memory limit"));
    let address_space = read("/proc/self/limits")
        .and_then(|t| address_space_limit(&t))
        .zip(read("/proc/self/status").and_then(|t| kib_field(&t, "VmSize:")))
        .map(|(limit, size)| {
            (
                limit.saturating_sub(size),
                "left by this process's address-space limit (ulimit -v)",
            )
        });
    [machine, cgroup, address_space]
        .into_iter()
        .flatten()
        .min_by_key(|&(bytes, _)| bytes)
}

/// Bytes of a `Name:   N kB` line of /proc/meminfo or /proc/self/status.
fn kib_field(text: &str, name: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(name))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// The soft limit of `Max address space` in /proc/self/limits, bytes (`None`: unlimited).
fn address_space_limit(limits: &str) -> Option<u64> {
    let line = limits
        .lines()
        .find(|l| l.starts_with("Max address space"))?;
    line["Max address space".len()..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// What the memory limits of the cgroups in /proc/self/cgroup (`cgroups`) leave, bytes: the
/// least over the process's cgroup and its ancestors of limit − usage, read through `read`
/// (v2: `0::/path`, files under /sys/fs/cgroup/path; v1: the `memory` controller's line, files
/// under /sys/fs/cgroup/memory/path). `None` where no limit is set.
fn cgroup_room(cgroups: &str, read: &dyn Fn(&str) -> Option<String>) -> Option<u64> {
    let number = |text: Option<String>| text?.trim().parse::<u64>().ok();
    let mut room: Option<u64> = None;
    for line in cgroups.lines() {
        let mut fields = line.splitn(3, ':');
        let (_, controllers, path) = (fields.next()?, fields.next()?, fields.next()?);
        let (root, limit_file, usage_file) = if controllers.is_empty() {
            ("/sys/fs/cgroup", "memory.max", "memory.current")
        } else if controllers.split(',').any(|c| c == "memory") {
            (
                "/sys/fs/cgroup/memory",
                "memory.limit_in_bytes",
                "memory.usage_in_bytes",
            )
        } else {
            continue;
        };
        // The cgroup and each ancestor up to the root ("" below): a limit may be set on any.
        let mut dirs = Vec::new();
        let mut dir = path.trim_end_matches('/');
        loop {
            dirs.push(dir);
            match dir.rfind('/') {
                Some(cut) => dir = &dir[..cut],
                None => break,
            }
        }
        for dir in dirs {
            let at = |file: &str| format!("{root}{dir}/{file}");
            // "max" (v2) does not parse: no limit; v1 says "none" with a huge number.
            if let (Some(limit), Some(usage)) =
                (number(read(&at(limit_file))), number(read(&at(usage_file))))
                && limit < u64::MAX / 2
            {
                let left = limit.saturating_sub(usage);
                room = Some(room.map_or(left, |r| r.min(left)));
            }
        }
    }
    room
}

/// Springs as a structure of arrays; spring s joins `a[s]` and `b[s]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Springs {
    /// First particle.
    pub a: Vec<u32>,
    /// Second particle.
    pub b: Vec<u32>,
    /// Rest length r, metres.
    pub rest: Vec<f64>,
    /// Stiffness k_s, N/m.
    pub stiffness: Vec<f64>,
    /// Damping k_d, N·s/m.
    pub damping: Vec<f64>,
}

impl Springs {
    /// Number of springs.
    pub fn len(&self) -> usize {
        self.a.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }
    /// The end points [a, b] of every spring, in order.
    pub fn pairs(&self) -> Vec<[u32; 2]> {
        self.a.iter().zip(&self.b).map(|(&a, &b)| [a, b]).collect()
    }
    fn with_capacity(n: usize) -> Springs {
        Springs {
            a: Vec::with_capacity(n),
            b: Vec::with_capacity(n),
            rest: Vec::with_capacity(n),
            stiffness: Vec::with_capacity(n),
            damping: Vec::with_capacity(n),
        }
    }
    fn push(&mut self, a: u32, b: u32, rest: f64, stiffness: f64, damping: f64) {
        self.a.push(a);
        self.b.push(b);
        self.rest.push(rest);
        self.stiffness.push(stiffness);
        self.damping.push(damping);
    }
}

/// Each particle's springs in compressed sparse rows: particle i's entries are
/// `entries[offsets[i]..offsets[i + 1]]`, each `2·s + side` with side 0 when i is `a[s]` (the
/// spring force acts with a + sign) and 1 when i is `b[s]` (− sign), in ascending spring order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Adjacency {
    /// n + 1 offsets into `entries`.
    pub offsets: Vec<u32>,
    /// 2·springs entries.
    pub entries: Vec<u32>,
}

impl Adjacency {
    /// Builds the adjacency of `n` particles by a counting sort over the springs.
    pub fn build(n: usize, springs: &Springs) -> Adjacency {
        let mut adjacency = Adjacency::default();
        adjacency.rebuild(n, springs.a.iter().copied().zip(springs.b.iter().copied()));
        adjacency
    }

    /// Rebuilds in place (reusing the buffers) the adjacency of `n` particles joined by `ends`,
    /// the (a, b) of each link in link order, by a counting sort.
    pub fn rebuild(&mut self, n: usize, ends: impl Iterator<Item = (u32, u32)> + Clone) {
        let (offsets, entries) = (&mut self.offsets, &mut self.entries);
        offsets.clear();
        offsets.resize(n + 1, 0);
        let mut links = 0;
        for (a, b) in ends.clone() {
            offsets[a as usize + 1] += 1;
            offsets[b as usize + 1] += 1;
            links += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        entries.clear();
        entries.resize(2 * links, 0);
        // offsets[p] walks to p's end (the start of p + 1's run), then is shifted back below.
        for (s, (a, b)) in ends.enumerate() {
            for (p, side) in [(a, 0), (b, 1)] {
                let next = &mut offsets[p as usize];
                entries[*next as usize] = 2 * s as u32 + side;
                *next += 1;
            }
        }
        offsets.copy_within(0..n, 1);
        offsets[0] = 0;
    }

    /// The entries of particle i.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.entries[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }
}

/// A lattice body's springs as a stencil. A cuboid's particle (i, j, k), global index
/// `first + i + nx·(j + ny·k)`, is joined to the particle at (i, j, k) + o for every offset o
/// of `springs` where that lies in the grid, with that offset's parameters. A mesh body's
/// lattice is masked: only the kept points are particles, and only the springs its kept cells
/// hold exist ([`LatticeMask`]). These are the springs [`Model::springs`] lists for the body,
/// in its order ([`topology::for_each_lattice_spring`]): a solver may take them from either.
#[derive(Debug, Clone, PartialEq)]
pub struct Lattice {
    /// The body (an index into [`Model::bodies`]).
    pub body: u32,
    /// Its first particle.
    pub first: u32,
    /// Lattice points per axis (nx, ny, nz).
    pub dims: [u32; 3],
    /// The offsets with springs, in [`topology::OFFSETS`] order (families the body leaves out
    /// have none).
    pub springs: Vec<LatticeSpring>,
    /// Which points are particles and which springs exist, for a mesh body; `None` for a
    /// cuboid (every point, every spring whose partner lies in the grid).
    pub mask: Option<LatticeMask>,
}

/// The particles and springs of a masked lattice, per lattice point `i + nx·(j + ny·k)`.
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeMask {
    /// The particle (within the body) at each point, [`LatticeMask::NONE`] where there is none;
    /// ascending over the points that have one.
    pub particle_of: Vec<u32>,
    /// Bit o set where a spring of offset o ([`topology::OFFSETS`], one of `springs`) starts
    /// at the point.
    pub springs: Vec<u16>,
}

impl LatticeMask {
    /// `particle_of` of a point without a particle.
    pub const NONE: u32 = u32::MAX;
}

/// The springs of one lattice offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatticeSpring {
    /// Index into [`topology::OFFSETS`].
    pub offset: usize,
    /// r, metres: [`topology::offset_rest`].
    pub rest: f64,
    /// k_s, N/m.
    pub stiffness: f64,
    /// k_d, N·s/m.
    pub damping: f64,
}

impl Lattice {
    /// The lattice of a body of `dims` points at cell edges `spacing` whose families have the
    /// parameters `params` gives (`None`: left out).
    fn new(
        body: u32,
        first: u32,
        dims: [u32; 3],
        spacing: DVec3,
        params: impl Fn(SpringKind) -> Option<crate::scene::SpringParams>,
    ) -> Lattice {
        let springs = (topology::OFFSETS.iter().enumerate())
            .filter_map(|(offset, &(o, kind))| {
                params(kind).map(|p| LatticeSpring {
                    offset,
                    rest: topology::offset_rest(spacing, o),
                    stiffness: p.stiffness,
                    damping: p.damping,
                })
            })
            .collect();
        Lattice {
            body,
            first,
            dims,
            springs,
            mask: None,
        }
    }

    /// The lattice of a mesh body: `new`'s, masked to the points with a particle
    /// (`particle_of`) and the springs of the cells `present`.
    fn masked(mut self, particle_of: &[u32], present: &[bool]) -> Lattice {
        let mut springs = vec![0u16; particle_of.len()];
        let kept = self
            .springs
            .iter()
            .fold(0u16, |bits, s| bits | 1 << s.offset);
        topology::for_each_lattice_spring(self.dims, Some(present), 0..self.dims[2], |a, _, o| {
            springs[a as usize] |= (1 << o) & kept;
        });
        self.mask = Some(LatticeMask {
            particle_of: particle_of.to_vec(),
            springs,
        });
        self
    }

    /// The springs of offset `o` (an index into [`topology::OFFSETS`]), if the body has them.
    pub fn spring(&self, o: usize) -> Option<&LatticeSpring> {
        self.springs.iter().find(|s| s.offset == o)
    }

    /// Number of springs.
    pub fn spring_count(&self) -> u64 {
        match &self.mask {
            None => (self.springs.iter())
                .map(|s| topology::offset_spring_count(self.dims, topology::OFFSETS[s.offset].0))
                .sum(),
            Some(mask) => mask.springs.iter().map(|b| u64::from(b.count_ones())).sum(),
        }
    }

    /// Calls `f(a, b, spring)` for each spring starting in the z-planes `planes`, a and b global
    /// particle indices, in the order of [`Model::springs`].
    pub fn for_each_spring(
        &self,
        planes: std::ops::Range<u32>,
        mut f: impl FnMut(u32, u32, &LatticeSpring),
    ) {
        let mut by_offset = [None; topology::OFFSETS.len()];
        for s in &self.springs {
            by_offset[s.offset] = Some(s);
        }
        let Some(mask) = &self.mask else {
            topology::for_each_cuboid_spring_in(self.dims, planes, |a, b, o| {
                if let Some(s) = by_offset[o] {
                    f(self.first + a, self.first + b, s);
                }
            });
            return;
        };
        let [nx, ny, nz] = self.dims.map(|d| d as usize);
        let plane = nx * ny;
        let points = planes.start as usize * plane..(planes.end as usize).min(nz) * plane;
        for (p, &bits) in mask.springs[points.clone()].iter().enumerate() {
            let p = points.start + p;
            for (o, s) in by_offset.iter().enumerate() {
                if let Some(s) = s.filter(|_| bits >> o & 1 == 1) {
                    let [di, dj, dk] = topology::OFFSETS[o].0.map(|d| d as isize);
                    let q = p.wrapping_add_signed(di + nx as isize * (dj + ny as isize * dk));
                    let (a, b) = (mask.particle_of[p], mask.particle_of[q]);
                    f(self.first + a, self.first + b, s);
                }
            }
        }
    }
}

/// A value computed from the rest of its model on first use, then kept. It is no part of the
/// model's identity: its `Debug` text is the same computed or not (checkpoints fingerprint
/// the model's `Debug` text), and a clone carries it if computed.
#[derive(Clone, Default)]
struct Derived<T>(std::sync::OnceLock<T>);

impl<T> std::fmt::Debug for Derived<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Derived")
    }
}

/// Bytes a vector holds on the heap.
pub fn vec_bytes<T>(v: &Vec<T>) -> u64 {
    (v.capacity() * std::mem::size_of::<T>()) as u64
}

/// Where a body's particles sit in the global arrays.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BodyRange {
    /// The body's name.
    pub name: String,
    /// Index of its first particle.
    pub first: u32,
    /// Number of particles.
    pub count: u32,
}

/// Positions and velocities: what a step changes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct State {
    /// x_i, metres.
    pub x: Vec<DVec3>,
    /// v_i, m/s.
    pub v: Vec<DVec3>,
}

/// Everything about a scene that does not change during a run.
#[derive(Debug, Clone)]
pub struct Model {
    /// Time stepping and global forces.
    pub simulation: Simulation,
    /// m_i, kg.
    pub mass: Vec<f64>,
    /// 1/m_i, and 0 for pinned particles (so they never accelerate).
    pub inv_mass: Vec<f64>,
    /// The springs of the bodies without a lattice (`particles` bodies), in body
    /// order; all of them once [`Model::springs_mut`] has turned the lattices into a list.
    listed: Springs,
    /// The lattice bodies' springs (cuboids and mesh bodies), as stencils on their lattices
    /// (one per body, in body order).
    lattices: Vec<Lattice>,
    /// Every spring ([`Model::springs`]), built on first use when there are lattices.
    all_springs: Derived<Springs>,
    /// Each particle's springs ([`Model::adjacency`]), built on first use.
    adjacency: Derived<Adjacency>,
    /// Springs of each family.
    pub spring_counts: SpringCounts,
    /// Bodies in particle order.
    pub bodies: Vec<BodyRange>,
    /// The outer surface of the cuboid bodies as triangles of particle indices, wound
    /// counter-clockwise seen from outside ([`topology::cuboid_surface`]), and of the mesh
    /// bodies with `surface = "lattice"` (the outer faces of their kept cells,
    /// [`crate::voxel::Voxels::lattice_surface`]); `particles` bodies have no surface and add
    /// none, mesh bodies showing their mesh add it to `embedded` instead.
    pub surface: Vec<[u32; 3]>,
    /// The input meshes of the mesh bodies, carried by their lattices.
    pub embedded: Embedded,
    /// Terrain shapes.
    pub terrain: Vec<Terrain>,
    /// Who touches whom between and within bodies.
    pub contact: Contacts,
}

/// Surfaces whose vertices are not particles but weighted sums of particles: the input meshes
/// of mesh bodies, each vertex a trilinear combination of the eight corners of its cell, so
/// that the artist's mesh (its vertex order, its faces) comes back deformed in every frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Embedded {
    /// Per vertex: the particles (global indices) its position is a weighted sum of.
    pub corners: Vec<[u32; 8]>,
    /// Per vertex: the weights of `corners`, summing to 1.
    pub weights: Vec<[f64; 8]>,
    /// Triangles over vertex numbers (0-based, all meshes numbered together), in each input
    /// file's order and winding.
    pub triangles: Vec<[u32; 3]>,
    /// The meshes, in body order.
    pub meshes: Vec<EmbeddedMesh>,
}

/// One body's embedded mesh: its vertices and triangles within [`Embedded`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EmbeddedMesh {
    /// The body (an index into `Model::bodies`).
    pub body: u32,
    /// Its first vertex.
    pub first_vertex: u32,
    /// Its vertex count (the input file's).
    pub vertices: u32,
    /// Its first triangle.
    pub first_triangle: u32,
    /// Its triangle count (the input file's, faces of more than three corners split).
    pub triangles: u32,
}

impl Embedded {
    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.corners.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.corners.is_empty()
    }

    /// Whether body `b` shows an embedded mesh.
    pub fn has_body(&self, b: u32) -> bool {
        self.meshes.iter().any(|m| m.body == b)
    }

    /// Each vertex's value from the particles' `values` (positions, or velocities: the weights
    /// are constant, so the vertex velocity is the same sum of particle velocities). The
    /// corners are summed in corner order: the same bits every time.
    pub fn apply(&self, values: &[DVec3]) -> Vec<DVec3> {
        let mut out = Vec::with_capacity(self.len());
        self.apply_into(values, &mut out);
        out
    }

    /// [`Embedded::apply`], appending to `out`.
    pub fn apply_into(&self, values: &[DVec3], out: &mut Vec<DVec3>) {
        out.extend(self.corners.iter().zip(&self.weights).map(|(c, w)| {
            let mut sum = DVec3::ZERO;
            for k in 0..8 {
                sum += w[k] * values[c[k] as usize];
            }
            sum
        }));
    }

    /// The largest particle index named, if any.
    pub fn max_particle(&self) -> Option<u32> {
        self.corners.iter().flatten().copied().max()
    }
}

/// Contact between particles of bodies: each particle's radius and place, and the rule that
/// decides which pairs may touch (docs/physics.md, "Contact between bodies").
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Contacts {
    /// r_i, metres; 0 touches no particle.
    pub radius: Vec<f64>,
    /// The body of each particle (an index into `Model::bodies`).
    pub body: Vec<u32>,
    /// Lattice coordinates of each particle of a cuboid or a mesh body; `None` for a
    /// `particles` body.
    pub lattice: Vec<Option<[i32; 3]>>,
    /// Whether each body's particles touch each other.
    pub self_contact: Vec<bool>,
    /// The laws of the contact.
    pub laws: BodyContact,
}

/// Self-contact ignores pairs of a cuboid this close on the lattice (Chebyshev distance, in
/// cells): the particles a spring joins (up to two cells apart) and their neighbours at rest.
pub const SELF_CONTACT_EXCLUSION: i32 = 2;

/// κ of the penalty force between bodies in contact, in units of m_red/h², in the explicit
/// integrators' stages (ω h = √κ ≈ 0.32): both backends' (docs/physics.md, "Contact between
/// bodies").
pub const PENALTY: f64 = 0.1;

/// κ inside implicit Euler's solve, where the pair is a linearised spring like any other:
/// backward Euler damps any stiffness, and a stiff penalty keeps the overlap under load small
/// at large steps (κ = 100 lets a pile at h = 1/60 s sink to 0.79 R; 10⁴ makes the
/// linearisation at the step start too coarse and the pile never settles).
pub const PENALTY_IMPLICIT: f64 = 1000.0;

/// κ of the penalty in `integrator`'s steps ([`PENALTY_IMPLICIT`] for implicit Euler, else
/// [`PENALTY`]); the response between bodies presses its friction with the same penalty.
pub fn penalty(integrator: crate::Integrator) -> f64 {
    if integrator == crate::Integrator::ImplicitEuler {
        PENALTY_IMPLICIT
    } else {
        PENALTY
    }
}

/// The overlap, as a fraction of R, that the response between bodies leaves to the penalty
/// force. A push is a move without a force, which the springs around it answer with elastic
/// energy, so pushes must stay rare, and short: at 5%, implicit Euler's pile in the bowl at
/// h = 1/60 s gains up to 1.5 J in a step, at 10% 0.08 J (of 206 J), and 1.25 J when a push
/// triggered at 10% goes on to 5%.
pub const SLOP: f64 = 0.1;

impl Contacts {
    /// Whether any pair can ever touch: a particle with a radius in a body with
    /// `self_contact`, or in two different bodies.
    pub fn enabled(&self) -> bool {
        let mut with_radius = self
            .radius
            .iter()
            .zip(&self.body)
            .filter(|(r, _)| **r > 0.0)
            .map(|(_, b)| *b);
        let Some(first) = with_radius.next() else {
            return false;
        };
        self.self_contact.iter().any(|&s| s) || with_radius.any(|b| b != first)
    }
}

/// The largest step h of symplectic Euler on a mode of M⁻¹K eigenvalue λ and damping rate c:
/// the root of h²λ + 2hc = 4 (2/c without stiffness); `None` for a mode with neither.
pub fn largest_stable_step(lambda: f64, c: f64) -> Option<f64> {
    if lambda == 0.0 {
        return (c > 0.0).then(|| 2.0 / c);
    }
    Some((-c + (c * c + 4.0 * lambda).sqrt()) / lambda)
}

impl Model {
    /// Builds the model and its initial state from a validated scene. Pinned particles start at
    /// rest whatever velocity the scene gives them: they never move.
    pub fn build(scene: &Scene) -> (Model, State) {
        let n = scene.particle_count() as usize;
        let mut state = State {
            x: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
        };
        let mut mass = Vec::with_capacity(n);
        let mut springs = Springs::default();
        let mut lattices = Vec::new();
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut pinned = vec![false; n];
        let mut surface = Vec::new();
        let mut embedded = Embedded::default();
        let mut contact = Contacts {
            laws: scene.simulation.body_contact,
            ..Contacts::default()
        };
        for (b, body) in scene.bodies.iter().enumerate() {
            let first = state.x.len() as u32;
            match &body.shape {
                BodyShape::Cuboid(c) => {
                    let [nx, ny, _] = c.resolution.map(|r| r as i32);
                    let cells = (0..body.particle_count() as i32)
                        .map(|p| Some([p % nx, p / nx % ny, p / (nx * ny)]));
                    contact.lattice.extend(cells);
                    let x = topology::cuboid_positions(c);
                    let m = c.mass / x.len() as f64;
                    state.v.extend(std::iter::repeat_n(c.velocity, x.len()));
                    mass.extend(std::iter::repeat_n(m, x.len()));
                    let params = |kind| match kind {
                        SpringKind::Structural => c.structural,
                        SpringKind::Shear => c.shear,
                        SpringKind::Bending => c.bending,
                    };
                    let lattice = Lattice::new(
                        b as u32,
                        first,
                        c.resolution,
                        topology::cuboid_spacing(c),
                        params,
                    );
                    lattices.push(lattice);
                    state.x.extend(x);
                    surface.extend(
                        topology::cuboid_surface(c.resolution)
                            .into_iter()
                            .map(|t| t.map(|p| first + p)),
                    );
                }
                BodyShape::Mesh(m) => {
                    let v = &m.voxels;
                    let rot = crate::scene::rotation_from_degrees(m.rotation);
                    let x: Vec<DVec3> = v
                        .points()
                        .iter()
                        .map(|&p| m.center + rot * v.local(p))
                        .collect();
                    contact
                        .lattice
                        .extend(v.points().iter().map(|p| Some(p.map(|c| c as i32))));
                    let mass_each = m.total_mass() / x.len() as f64;
                    state.v.extend(std::iter::repeat_n(m.velocity, x.len()));
                    mass.extend(std::iter::repeat_n(mass_each, x.len()));
                    let params = |kind| match kind {
                        SpringKind::Structural => m.structural,
                        SpringKind::Shear => m.shear,
                        SpringKind::Bending => m.bending,
                    };
                    let points = v.lattice_points();
                    let lattice =
                        Lattice::new(b as u32, first, points, DVec3::splat(v.cell()), params);
                    lattices.push(lattice.masked(v.particle_of(), v.present()));
                    state.x.extend(x);
                    match m.surface {
                        SurfaceKind::Lattice => surface.extend(
                            v.lattice_surface()
                                .into_iter()
                                .map(|t| t.map(|p| first + p)),
                        ),
                        SurfaceKind::Mesh => {
                            let mesh = v.mesh();
                            let first_vertex = embedded.len() as u32;
                            embedded.meshes.push(EmbeddedMesh {
                                body: b as u32,
                                first_vertex,
                                vertices: mesh.vertices.len() as u32,
                                first_triangle: embedded.triangles.len() as u32,
                                triangles: mesh.triangles.len() as u32,
                            });
                            for (corners, weights) in v.embedding() {
                                embedded.corners.push(corners.map(|p| first + p));
                                embedded.weights.push(weights);
                            }
                            embedded
                                .triangles
                                .extend(mesh.triangles.iter().map(|t| t.map(|i| first_vertex + i)));
                        }
                    }
                }
                BodyShape::Particles(p) => {
                    contact
                        .lattice
                        .extend(std::iter::repeat_n(None, p.positions.len()));
                    state.x.extend(&p.positions);
                    state.v.extend(&p.velocities);
                    mass.extend(&p.masses);
                    for s in &p.springs {
                        let rest = s.rest.unwrap_or_else(|| {
                            p.positions[s.a as usize].distance(p.positions[s.b as usize])
                        });
                        springs.push(first + s.a, first + s.b, rest, s.stiffness, s.damping);
                    }
                }
            }
            let count = state.x.len() as u32 - first;
            let radius = body.contact_radius();
            contact
                .radius
                .extend(std::iter::repeat_n(radius, count as usize));
            contact
                .body
                .extend(std::iter::repeat_n(b as u32, count as usize));
            contact.self_contact.push(body.self_contact);
            for &p in &body.pinned {
                pinned[(first + p) as usize] = true;
            }
            bodies.push(BodyRange {
                name: body.name.clone(),
                first,
                count,
            });
        }
        let inv_mass = mass
            .iter()
            .zip(&pinned)
            .map(|(&m, &p)| if p { 0.0 } else { 1.0 / m })
            .collect();
        for (v, &p) in state.v.iter_mut().zip(&pinned) {
            if p {
                *v = DVec3::ZERO;
            }
        }
        let model = Model {
            simulation: scene.simulation,
            mass,
            inv_mass,
            listed: springs,
            lattices,
            all_springs: Derived::default(),
            adjacency: Derived::default(),
            spring_counts: scene.spring_counts(),
            bodies,
            surface,
            embedded,
            terrain: scene.terrain.clone(),
            contact,
        };
        (model, state)
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.mass.len()
    }

    /// Whether the model has no particles.
    pub fn is_empty(&self) -> bool {
        self.mass.is_empty()
    }

    /// Every spring, bodies in order: a lattice body's in [`topology::for_each_lattice_spring`]'s
    /// order, a `particles` body's as given. Built on first use where there are lattices, then kept
    /// (see the module doc: a caller that only needs to visit them once wants
    /// [`Model::for_each_spring`]).
    pub fn springs(&self) -> &Springs {
        if self.lattices.is_empty() {
            return &self.listed;
        }
        self.all_springs.0.get_or_init(|| {
            let mut all = Springs::with_capacity(self.spring_count());
            self.for_each_spring(|a, b, rest, stiffness, damping| {
                all.push(a, b, rest, stiffness, damping);
            });
            all
        })
    }

    /// Each particle's springs in [`Model::springs`]: built on first use, then kept.
    pub fn adjacency(&self) -> &Adjacency {
        (self.adjacency.0).get_or_init(|| Adjacency::build(self.len(), self.springs()))
    }

    /// The springs, for changing their parameters: the lattices' stencils become a list
    /// (afterwards [`Model::lattices`] is empty and the solvers take the routes for listed
    /// springs). The end points may change too; the adjacency is rebuilt on its next use.
    pub fn springs_mut(&mut self) -> &mut Springs {
        if !self.lattices.is_empty() {
            self.springs();
            self.listed = std::mem::take(&mut self.all_springs)
                .0
                .into_inner()
                .unwrap_or_default();
            self.lattices.clear();
        }
        self.adjacency = Derived::default();
        &mut self.listed
    }

    /// The lattice bodies' springs (cuboids and mesh bodies) as stencils on their lattices, one
    /// per such body in body order:
    /// what lets a solver find a spring's partner at a constant offset.
    pub fn lattices(&self) -> &[Lattice] {
        &self.lattices
    }

    /// The springs of the bodies without a lattice (`particles` bodies), in body
    /// order: with [`Model::lattices`], every spring.
    pub fn listed_springs(&self) -> &Springs {
        &self.listed
    }

    /// Number of springs (without building [`Model::springs`]).
    pub fn spring_count(&self) -> usize {
        let lattices: u64 = self.lattices.iter().map(Lattice::spring_count).sum();
        self.listed.len() + lattices as usize
    }

    /// Calls `f(a, b, rest, stiffness, damping)` for every spring, in the order of
    /// [`Model::springs`], without building it.
    pub fn for_each_spring(&self, mut f: impl FnMut(u32, u32, f64, f64, f64)) {
        let mut lattices = self.lattices.iter().peekable();
        let mut listed = 0;
        for (index, body) in self.bodies.iter().enumerate() {
            if let Some(lattice) = lattices.next_if(|l| l.body as usize == index) {
                lattice.for_each_spring(0..lattice.dims[2], |a, b, s| {
                    f(a, b, s.rest, s.stiffness, s.damping);
                });
                continue;
            }
            let (l, end) = (&self.listed, body.first + body.count);
            while listed < l.len() && l.a[listed] < end {
                let k = listed;
                f(l.a[k], l.b[k], l.rest[k], l.stiffness[k], l.damping[k]);
                listed += 1;
            }
        }
    }

    /// Whether particles i and j may touch: different bodies, or one body with `self_contact`
    /// where they are not rest neighbours — on a cuboid's or mesh body's lattice more than
    /// [`SELF_CONTACT_EXCLUSION`] cells apart along some axis, in a `particles` body not joined
    /// by a spring.
    pub fn admits(&self, i: usize, j: usize) -> bool {
        let c = &self.contact;
        let body = c.body[i];
        if body != c.body[j] {
            return true;
        }
        if !c.self_contact[body as usize] {
            return false;
        }
        match (c.lattice[i], c.lattice[j]) {
            (Some(a), Some(b)) => (0..3).any(|k| (a[k] - b[k]).abs() > SELF_CONTACT_EXCLUSION),
            _ => {
                let springs = self.springs();
                !self.adjacency().of(i).iter().any(|&e| {
                    let s = (e >> 1) as usize;
                    springs.a[s] as usize + springs.b[s] as usize - i == j
                })
            }
        }
    }

    /// Bytes the model holds on the heap per particle and per spring: masses, the contact
    /// arrays, the listed springs, and [`Model::springs`] and [`Model::adjacency`] where they
    /// were built (the surface, embedded meshes and terrain excluded).
    pub fn memory_bytes(&self) -> u64 {
        let springs = |s: &Springs| {
            vec_bytes(&s.a)
                + vec_bytes(&s.b)
                + vec_bytes(&s.rest)
                + vec_bytes(&s.stiffness)
                + vec_bytes(&s.damping)
        };
        let c = &self.contact;
        vec_bytes(&self.mass)
            + vec_bytes(&self.inv_mass)
            + vec_bytes(&c.radius)
            + vec_bytes(&c.body)
            + vec_bytes(&c.lattice)
            + springs(&self.listed)
            + self.all_springs.0.get().map_or(0, springs)
            + (self.adjacency.0.get()).map_or(0, |a| vec_bytes(&a.offsets) + vec_bytes(&a.entries))
    }

    /// Estimate of the largest stable step of the explicit integrators: the symplectic-Euler
    /// bound h²λ + 2hc ≤ 4 of the stiffest mode, with λ ≥ ω² and c bounded by Gershgorin's
    /// theorem on M⁻¹K and M⁻¹D (λ_i = 2Σk_s/m_i, c_i = 2Σk_d/m_i over particle i's springs).
    /// Conservative: a regular cube's true bound is about 1.5 times larger. RK4 tolerates about
    /// 1.4 times this step, explicit Euler and midpoint are unstable on undamped springs at any
    /// step (their energy grows), and implicit Euler is stable at any step. `None` without
    /// springs.
    pub fn stable_dt(&self) -> Option<f64> {
        self.stable_dt_bounds()
            .and_then(|(lambda, c)| largest_stable_step(lambda, c))
    }

    /// Gershgorin's bounds on the λ and c of [`Model::stable_dt`]; `None` without springs.
    pub fn stable_dt_bounds(&self) -> Option<(f64, f64)> {
        if self.spring_count() == 0 {
            return None;
        }
        // Each particle's sums in ascending spring order, as a gather over its adjacency would
        // add them, without building it.
        let mut sums = vec![(0.0f64, 0.0f64); self.len()];
        self.for_each_spring(|a, b, _, k, d| {
            for p in [a, b] {
                let sum = &mut sums[p as usize];
                *sum = (sum.0 + k, sum.1 + d);
            }
        });
        let (mut lambda, mut c) = (0.0f64, 0.0f64);
        for (&(k, d), &m) in sums.iter().zip(&self.mass) {
            lambda = lambda.max(2.0 * k / m);
            c = c.max(2.0 * d / m);
        }
        Some((lambda, c))
    }

    /// The bodies and springs of this model, with every spring's stiffness and damping
    /// (k_s, k_d) replaced by `coefficients(k_s, k_d)`; no terrain, surfaces, embedded meshes
    /// or contact between bodies. A spring kernel run on it computes other linear operators
    /// of the springs: with (0, k_s), the damper forces at velocities w are −K w, the product
    /// of the stiffness matrix linearised at the positions (the stable-step estimate's power
    /// iteration, `softbody_cpu::stable_step`).
    pub fn with_spring_coefficients(&self, coefficients: impl Fn(f64, f64) -> (f64, f64)) -> Model {
        let mut listed = self.listed.clone();
        for (k, d) in listed.stiffness.iter_mut().zip(&mut listed.damping) {
            (*k, *d) = coefficients(*k, *d);
        }
        let mut lattices = self.lattices.clone();
        for s in lattices.iter_mut().flat_map(|l| &mut l.springs) {
            (s.stiffness, s.damping) = coefficients(s.stiffness, s.damping);
        }
        Model {
            simulation: self.simulation,
            mass: self.mass.clone(),
            inv_mass: self.inv_mass.clone(),
            listed,
            lattices,
            all_springs: Derived::default(),
            adjacency: Derived::default(),
            spring_counts: self.spring_counts,
            bodies: self.bodies.clone(),
            surface: Vec::new(),
            embedded: Embedded::default(),
            terrain: Vec::new(),
            contact: Contacts::default(),
        }
    }

    /// Whether particle i is pinned.
    pub fn is_pinned(&self, i: usize) -> bool {
        self.inv_mass[i] == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_limits_are_read_from_proc_and_the_cgroup_files() {
        let status = "Name:\tsoftbody\nVmPeak:\t  9000 kB\nVmSize:\t  8192 kB\n";
        assert_eq!(kib_field(status, "VmSize:"), Some(8192 * 1024));
        let limits = "Limit                     Soft Limit           Hard Limit           Units\n\
                      Max stack size            8388608              unlimited            bytes\n\
                      Max address space         1073741824           unlimited            bytes\n";
        assert_eq!(address_space_limit(limits), Some(1 << 30));
        let unlimited = limits.replace("1073741824", "unlimited ");
        assert_eq!(address_space_limit(&unlimited), None);

        // v2: a limit on the parent of the process's cgroup counts.
        let files = |path: &str| -> Option<String> {
            match path {
                "/sys/fs/cgroup/user/job/memory.max" => Some("max\n".into()),
                "/sys/fs/cgroup/user/job/memory.current" => Some("100\n".into()),
                "/sys/fs/cgroup/user/memory.max" => Some("5000\n".into()),
                "/sys/fs/cgroup/user/memory.current" => Some("1000\n".into()),
                "/sys/fs/cgroup/memory.max" => None,
                // v1, memory controller.
                "/sys/fs/cgroup/memory/box/memory.limit_in_bytes" => Some("3000\n".into()),
                "/sys/fs/cgroup/memory/box/memory.usage_in_bytes" => Some("500\n".into()),
                "/sys/fs/cgroup/memory/memory.limit_in_bytes" => {
                    Some("9223372036854771712\n".into())
                }
                "/sys/fs/cgroup/memory/memory.usage_in_bytes" => Some("9000\n".into()),
                _ => None,
            }
        };
        assert_eq!(cgroup_room("0::/user/job\n", &files), Some(4000));
        assert_eq!(
            cgroup_room("4:memory:/box\n3:cpu:/other\n", &files),
            Some(2500)
        );
        assert_eq!(cgroup_room("0::/\n", &files), None, "no limit anywhere");
        assert_eq!(cgroup_room("garbage", &files), None);
    }

    #[test]
    fn adjacency_lists_every_spring_twice_in_order() {
        let mut s = Springs::default();
        for (a, b) in [(0, 1), (1, 2), (0, 2), (2, 3)] {
            s.push(a, b, 1.0, 1.0, 0.0);
        }
        let adj = Adjacency::build(4, &s);
        assert_eq!(adj.offsets, vec![0, 2, 4, 7, 8]);
        assert_eq!(adj.of(0), &[0, 4]); // spring 0 side a, spring 2 side a
        assert_eq!(adj.of(1), &[1, 2]); // spring 0 side b, spring 1 side a
        assert_eq!(adj.of(2), &[3, 5, 6]);
        assert_eq!(adj.of(3), &[7]);
    }

    #[test]
    fn stable_dt_of_one_spring_is_the_leapfrog_bound() {
        // Two unit masses, one spring k: ω² = 2k/m, and symplectic Euler is stable for h ≤ 2/ω.
        let scene = crate::Scene::from_toml(
            "[simulation]\ndt = 0.001\nduration = 1.0\n[[body]]\nkind = \"particles\"\n\
             positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\nmasses = [1.0, 1.0]\n\
             springs = [{ a = 0, b = 1, stiffness = 50.0 }]\n",
            "t.toml".as_ref(),
        )
        .unwrap();
        let (model, _) = Model::build(&scene);
        assert!((model.stable_dt().unwrap() - 2.0 / 100f64.sqrt()).abs() < 1e-15);
    }
}
