//! Rust twins of the structs the shaders share with the host. Each is `#[repr(C)]` +
//! [`bytemuck::Pod`] so that it uploads as bytes, and a test parses the WGSL with naga and checks
//! the struct's size and every member's offset against these definitions.

use bytemuck::{Pod, Zeroable};
use softbody_scene::{Model, Springs};

/// The run's constants: twin of `Params` in `shaders/common.wgsl` (`@group(0) @binding(0)` of
/// every kernel). WGSL aligns `vec3<f32>` to 16 bytes and rounds a uniform struct to 16, hence
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
            n_springs: model.springs.len() as u32,
            n_surfaces,
            dt: sim.dt as f32,
            contact_distance: sim.contact_distance as f32,
            _pad: [0; 3],
        }
    }
}

/// One spring: twin of `Spring` in `shaders/common.wgsl` (20-byte stride).
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
