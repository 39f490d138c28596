//! Rust twins of the structs the shaders share with the host. Each is `#[repr(C)]` +
//! [`bytemuck::Pod`] so that it uploads as bytes, and a test parses the WGSL with naga and checks
//! the struct's size and every member's offset against these definitions.

use bytemuck::{Pod, Zeroable};
use softbody_scene::implicit::Constraint;
use softbody_scene::{FrictionModel, Lattice, LatticeMask, Model, Springs, topology};

/// The run's constants: twin of `Params` in `shaders/shared/common.wgsl` (`@group(0) @binding(0)`
/// of every kernel). WGSL aligns `vec3<f32>` to 16 bytes and rounds a uniform struct to 16, hence
/// the layout and the padding.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Params {
    /// g, m/s².
    pub gravity: [f32; 3],
    /// Linear drag coefficient, 1/s.
    pub drag: f32,
    /// Particles.
    pub n_particles: u32,
    /// Springs.
    pub n_springs: u32,
    /// Terrain surfaces.
    pub n_surfaces: u32,
    /// Step size h, s.
    pub dt: f32,
    /// Contact reach ε, m.
    pub contact_distance: f32,
    /// Padding to WGSL's 48-byte size.
    pub _pad: [u32; 3],
}

impl Params {
    /// The parameters of a model with `n_surfaces` terrain surfaces.
    pub fn new(model: &Model, n_surfaces: u32) -> Params {
        let sim = &model.simulation;
        Params {
            gravity: sim.gravity.as_vec3().to_array(),
            drag: sim.drag as f32,
            n_particles: model.len() as u32,
            n_springs: model.spring_count() as u32,
            n_surfaces,
            dt: sim.dt as f32,
            contact_distance: sim.contact_distance as f32,
            _pad: [0; 3],
        }
    }
}

/// One spring: twin of `Spring` in `shaders/shared/common.wgsl` (20-byte stride).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct SpringGpu {
    /// First particle.
    pub a: u32,
    /// Second particle.
    pub b: u32,
    /// Rest length r, m.
    pub rest: f32,
    /// k_s, N/m.
    pub stiffness: f32,
    /// k_d, N·s/m.
    pub damping: f32,
}

impl SpringGpu {
    /// The springs of a model, in f32.
    pub fn pack(springs: &Springs) -> Vec<SpringGpu> {
        (0..springs.len())
            .map(|s| SpringGpu {
                a: springs.a[s],
                b: springs.b[s],
                rest: springs.rest[s] as f32,
                stiffness: springs.stiffness[s] as f32,
                damping: springs.damping[s] as f32,
            })
            .collect()
    }
}

/// The springs of one lattice offset of a body: twin of `LatticeOffset` in
/// `shaders/shared/lattice.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct LatticeOffsetGpu {
    /// (di, dj, dk): the spring starting at point p ends at p + d.
    pub d: [i32; 3],
    /// Rest length r, m.
    pub rest: f32,
    /// k_s, N/m.
    pub stiffness: f32,
    /// k_d, N·s/m.
    pub damping: f32,
    /// Its index in [`topology::OFFSETS`].
    pub bit: u32,
    /// Its step in point index, di + nx (dj + ny dk), wrapped to 32 bits: the spring starting
    /// at point p ends at point p + linear (mod 2³², as the shader adds).
    pub linear: i32,
}

/// One lattice body: twin of `LatticeBody` in `shaders/shared/lattice.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct LatticeBodyGpu {
    /// Its first particle.
    pub first: u32,
    /// Its particles.
    pub count: u32,
    /// Points per axis.
    pub nx: u32,
    /// Points per axis.
    pub ny: u32,
    /// Points per axis.
    pub nz: u32,
    /// Offsets with springs.
    pub n_offsets: u32,
    /// A mesh body's first word in the points buffer; `u32::MAX` for a cuboid.
    pub points: u32,
    /// Padding to the offsets' 16-byte alignment.
    pub _pad: u32,
    /// The offsets with springs, in [`topology::OFFSETS`] order.
    pub offsets: [LatticeOffsetGpu; 16],
    /// Indices into `offsets` by descending linear offset.
    pub backward: [u32; 16],
}

impl LatticeBodyGpu {
    /// The lattices of a model whose bodies are all lattices, in f32 (the spring records'
    /// rounding, [`SpringGpu::pack`]), and the words of its mesh bodies' masks: for each, the
    /// point of each particle, then per point its particle (`LatticeMask::NONE` where none) and
    /// its spring bits.
    pub fn pack(lattices: &[Lattice]) -> (Vec<LatticeBodyGpu>, Vec<u32>) {
        let mut points = Vec::with_capacity(LatticeBodyGpu::point_words(lattices) as usize);
        let bodies = lattices
            .iter()
            .map(|lattice| {
                let [nx, ny, nz] = lattice.dims;
                let mut body = LatticeBodyGpu {
                    first: lattice.first,
                    count: nx * ny * nz,
                    nx,
                    ny,
                    nz,
                    n_offsets: lattice.springs.len() as u32,
                    points: u32::MAX,
                    ..LatticeBodyGpu::default()
                };
                let linear = |d: [i32; 3]| {
                    i64::from(d[0])
                        + i64::from(nx) * (i64::from(d[1]) + i64::from(ny) * i64::from(d[2]))
                };
                for (slot, s) in body.offsets.iter_mut().zip(&lattice.springs) {
                    let d = topology::OFFSETS[s.offset].0;
                    *slot = LatticeOffsetGpu {
                        d,
                        rest: s.rest as f32,
                        stiffness: s.stiffness as f32,
                        damping: s.damping as f32,
                        bit: s.offset as u32,
                        // Wrapping, as the shader's u32 addition does.
                        linear: linear(d) as i32,
                    };
                }
                let mut backward: Vec<u32> = (0..body.n_offsets).collect();
                backward.sort_by_key(|&r| std::cmp::Reverse(linear(body.offsets[r as usize].d)));
                body.backward[..backward.len()].copy_from_slice(&backward);
                if let Some(mask) = &lattice.mask {
                    body.points = points.len() as u32;
                    let kept = mask.particle_of.iter().enumerate();
                    let of_particle: Vec<u32> = kept
                        .filter(|&(_, &q)| q != LatticeMask::NONE)
                        .map(|(point, _)| point as u32)
                        .collect();
                    body.count = of_particle.len() as u32;
                    points.extend(of_particle);
                    for (&particle, &bits) in mask.particle_of.iter().zip(&mask.springs) {
                        points.extend([particle, u32::from(bits)]);
                    }
                }
                body
            })
            .collect();
        (bodies, points)
    }

    /// The words of the mesh bodies' masks [`LatticeBodyGpu::pack`] makes, without making
    /// them: per mesh body one per particle and two per lattice point.
    pub fn point_words(lattices: &[Lattice]) -> u64 {
        (lattices.iter())
            .filter_map(|l| l.mask.as_ref())
            .map(|mask| {
                let kept = mask.particle_of.iter().filter(|&&q| q != LatticeMask::NONE);
                kept.count() as u64 + 2 * mask.particle_of.len() as u64
            })
            .sum()
    }
}

/// The springs of one per-spring dispatch: twin of `SpringChunk` in `shaders/shared/common.wgsl`, a
/// uniform bound per chunk (one slot per chunk of a constant table, at the uniform offset
/// alignment).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct SpringChunk {
    /// The chunk's first spring.
    pub base: u32,
    /// Springs in the chunk.
    pub count: u32,
    /// `base / WORKGROUP_SIZE`: the slot of the chunk's first energy partial sum.
    pub first_group: u32,
    /// Padding to WGSL's 16-byte uniform size.
    pub _pad: u32,
}

/// "No particle / no step": the initial value of the atomicMin targets.
pub const NONE: u32 = u32::MAX;

/// The instability record of the steps of one submission: twin of `Status` in
/// `shaders/check_finite.wgsl` (three atomic u32 there).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable)]
pub struct Status {
    /// First step (1-based, within the submission) with a non-finite value, or [`NONE`].
    pub bad_step: u32,
    /// Lowest particle with a non-finite x or v at that step, or [`NONE`].
    pub bad_particle: u32,
    /// Lowest particle with a non-finite x at that step, or [`NONE`].
    pub bad_position: u32,
}

impl Status {
    /// Nothing seen yet.
    pub const RESET: Status = Status {
        bad_step: NONE,
        bad_particle: NONE,
        bad_position: NONE,
    };
}

/// A step's number within its submission: twin of `StepIndex` in `shaders/check_finite.wgsl`,
/// a uniform bound at a dynamic offset (one slot per step of a submission).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable)]
pub struct StepIndex {
    /// 1, 2, … within the submission.
    pub step: u32,
    /// Padding to WGSL's 16-byte uniform size.
    pub _pad: [u32; 3],
}

/// One spring's block of implicit Euler's system, B_s = β uuᵀ + γ I: twin of `SpringBlock` in
/// `shaders/system.wgsl` (written by the GPU; the host only reads it in tests).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct SpringBlockGpu {
    /// Unit direction u.
    pub u: [f32; 3],
    /// β = h k_d + h² k_s (1 − α).
    pub beta: f32,
    /// γ = h² k_s α.
    pub gamma: f32,
    /// h k_s ε_s: the spring's impulse over a step where its length is known to ε_s, half a
    /// ulp of its ends' largest coordinate in f32 (for CG's stopping rule,
    /// `shaders/system.wgsl`).
    pub resolution: f32,
    /// Padding to WGSL's 32-byte size (the struct aligns to its vec3's 16).
    pub _pad: [u32; 2],
}

/// The scalars of one CG solve: twin of `CgScalars` in `shaders/cg.wgsl`. The host writes the
/// settings (tolerance, cap, partial count, grids) once, and reads the record after each batch
/// of iterations.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct CgScalars {
    /// rᵀP⁻¹r of the current residual.
    pub delta: f32,
    /// max((Sb)ᵀP⁻¹(Sb), r₀ᵀP⁻¹r₀).
    pub scale: f32,
    /// tol²·scale.
    pub target_delta: f32,
    /// The smallest δ so far.
    pub smallest: f32,
    /// The last step length.
    pub alpha: f32,
    /// The last direction factor.
    pub beta: f32,
    /// Iterations taken.
    pub iterations: u32,
    /// 1 once the solve has stopped.
    pub done: u32,
    /// The relative tolerance (preconditioned norm).
    pub tolerance: f32,
    /// The iteration cap.
    pub max_iterations: u32,
    /// Per-workgroup partial sums of a particle reduction.
    pub n_partials: u32,
    /// δ at the iteration's start, kept by `cg_advance` for `cg_direction`'s β: there the
    /// first workgroup replaces `delta` while the others divide by the old value.
    pub previous_delta: f32,
    /// Workgroups of the particle grid along x and y.
    pub particle_grid: [u32; 2],
    /// Workgroups of the spring grid along x and y.
    pub spring_grid: [u32; 2],
    /// The warm start's coefficients on its basis (`cg_project_solve`).
    pub warm_start: [f32; 3],
    /// Padding to the record's 8-byte alignment.
    pub _pad: u32,
}

impl CgScalars {
    /// sqrt(δ/scale), 0 when the scale is 0: the CPU's `CgOutcome::relative_residual`.
    pub fn relative_residual(&self) -> f64 {
        let (delta, scale) = (f64::from(self.delta), f64::from(self.scale));
        if scale > 0.0 {
            (delta.max(0.0) / scale).sqrt()
        } else {
            0.0
        }
    }
}

/// Words of the indirect dispatch arguments CG rewrites (`DISPATCH_WORDS` in `shaders/cg.wgsl`):
/// four slots of (x, y, z).
pub const CG_DISPATCH_WORDS: usize = 12;

/// Halves of the CG's per-workgroup partial sums (`cg_common.wgsl`, `PARTIAL_HALVES`): cᵀq's,
/// δ's and the warm start projection's eight.
pub const CG_PARTIAL_HALVES: u64 = 10;

/// Byte offsets of the slots in the indirect dispatch buffer (`DISPATCH_*` in
/// `shaders/cg.wgsl`, in words there).
pub mod dispatch_slot {
    /// Particle kernels while the solve runs.
    pub const PARTICLES: u64 = 0;
    /// Spring kernels while the solve runs.
    pub const SPRINGS: u64 = 12;
    /// Particle kernels once the solve is done.
    pub const FINISHED_PARTICLES: u64 = 24;
    /// Spring kernels once the solve is done.
    pub const FINISHED_SPRINGS: u64 = 36;
}

/// One particle's contact record of implicit Euler: twin of `Candidate` in
/// `shaders/implicit_euler.wgsl` (written by the GPU; the host zeroes it).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct CandidateGpu {
    /// Outward unit normal N.
    pub normal: [f32; 3],
    /// Signed distance φ.
    pub phi: f32,
    /// Unit direction of the kinetic friction impulse.
    pub friction_dir: [f32; 3],
    /// Target normal velocity.
    pub vn_target: f32,
    /// Normal impulse the friction uses.
    pub lambda_n: f32,
    /// The surface's μ or k_f.
    pub friction: f32,
    /// The surface's k_r.
    pub restitution: f32,
    /// Mode (low two bits: 0 none, 1 inactive, 2 stick, 3 slip) and flags.
    pub state: u32,
}

/// The constraint as `constraints[i]` holds it: (n, kind) with kind 0 free, 1 normal, 2 fixed
/// (`CONSTRAINT_*` in `shaders/shared/common.wgsl`).
pub fn constraint_vec4(c: Constraint) -> [f32; 4] {
    match c {
        Constraint::Free => [0.0; 4],
        Constraint::Normal(n) => {
            let n = n.as_vec3();
            [n.x, n.y, n.z, 1.0]
        }
        Constraint::Fixed => [0.0, 0.0, 0.0, 2.0],
    }
}

/// The constants of contact between bodies: twin of `ContactParams` in
/// `shaders/shared/neighbours.wgsl`, one uniform.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct ContactParams {
    /// 1/s, s the grid's cell size, 1/m.
    pub inv_cell: f32,
    /// Buckets of the hash table, a power of two.
    pub buckets: u32,
    /// k_r between bodies.
    pub restitution: f32,
    /// μ or k_f between bodies.
    pub friction: f32,
    /// [`friction_code`] of the laws between bodies.
    pub friction_model: u32,
    /// κ: the penalty stiffness in units of m_red/h².
    pub penalty: f32,
    /// The overlap, as a fraction of R, that the response leaves to the penalty force.
    pub slop: f32,
    /// Self-contact ignores pairs of a cuboid this close on its lattice (Chebyshev, in cells).
    pub exclusion: i32,
}

/// A friction model as every shader reads it (terrain and bodies alike): `FRICTION_COULOMB`
/// and `FRICTION_VISCOUS` in `shaders/shared/common.wgsl`.
pub fn friction_code(model: FrictionModel) -> u32 {
    match model {
        FrictionModel::Coulomb => FRICTION_COULOMB,
        FrictionModel::Viscous => FRICTION_VISCOUS,
    }
}

/// [`friction_code`] of Coulomb friction.
pub const FRICTION_COULOMB: u32 = 0;
/// [`friction_code`] of viscous friction.
pub const FRICTION_VISCOUS: u32 = 1;

/// A particle's contact data: twin of `ContactParticle` in `shaders/shared/neighbours.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct ContactParticleGpu {
    /// Lattice coordinates in its cuboid (with [`ContactParticleGpu::LATTICE`]).
    pub lattice: [i32; 3],
    /// Its body.
    pub body: u32,
    /// r, m.
    pub radius: f32,
    /// 1/m, 0 if pinned.
    pub inv_mass: f32,
    /// [`ContactParticleGpu::SELF_CONTACT`] | [`ContactParticleGpu::LATTICE`].
    pub flags: u32,
    /// Padding to WGSL's 32-byte size (the struct aligns to its vec3's 16).
    pub _pad: u32,
}

impl ContactParticleGpu {
    /// Its body touches itself.
    pub const SELF_CONTACT: u32 = 1;
    /// It belongs to a cuboid and has lattice coordinates.
    pub const LATTICE: u32 = 2;
}

/// One level of the broad phase's prefix sum: twin of `ScanLevel` in `shaders/broad_phase.wgsl`,
/// a uniform bound at a dynamic offset (one slot per level).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct ScanLevel {
    /// The level's first element in the counts.
    pub offset: u32,
    /// Its elements.
    pub count: u32,
    /// Where its blocks' totals go.
    pub sums: u32,
    /// Padding to WGSL's 16-byte uniform size.
    pub _pad: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::LatticeSpring;

    /// A mesh body's mask packs into one word per particle and two per point, as
    /// `point_words` counts without packing (the limits check sizes the buffer by it); a
    /// cuboid has none.
    #[test]
    fn point_words_count_what_pack_makes() {
        let spring = LatticeSpring {
            offset: 0,
            rest: 0.1,
            stiffness: 100.0,
            damping: 1.0,
        };
        let cuboid = Lattice {
            body: 0,
            first: 0,
            dims: [3, 2, 2],
            springs: vec![spring],
            mask: None,
        };
        // A 3 × 2 × 1 lattice with points 1 and 4 empty: particles 0..4 at points 0, 2, 3, 5.
        let none = LatticeMask::NONE;
        let mesh = Lattice {
            body: 1,
            first: 12,
            dims: [3, 2, 1],
            springs: vec![spring],
            mask: Some(LatticeMask {
                particle_of: vec![0, none, 1, 2, none, 3],
                springs: vec![0, 0, 0, 1, 0, 0],
            }),
        };
        let lattices = [cuboid, mesh];
        let (bodies, points) = LatticeBodyGpu::pack(&lattices);
        assert_eq!(LatticeBodyGpu::point_words(&lattices), 4 + 2 * 6);
        assert_eq!(points.len(), 4 + 2 * 6);
        assert_eq!(&points[..4], &[0, 2, 3, 5]);
        assert_eq!((bodies[0].points, bodies[1].points), (u32::MAX, 0));
        assert_eq!(LatticeBodyGpu::point_words(&lattices[..1]), 0);
    }
}
