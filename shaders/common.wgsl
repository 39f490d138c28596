// common.wgsl: what every kernel of the GPU solver shares (crates/gpu/src/shaders.rs prepends it
// to each stage; WGSL has no includes).
//
// - `Params`: the run's constants, one uniform at @group(0) @binding(0) of every kernel. Its Rust
//   twin is `softbody_gpu::layout::Params`; a test checks size and offsets with naga.
// - `Spring`: one spring (a, b, r, k_s, k_d), 20-byte stride; twin `layout::SpringGpu`.
// - `thread_index`: the global index of a thread in a 1-D or 2-D grid of 256-thread workgroups.
//   Grids are 2-D only when more than 65,535 workgroups are needed (the per-dimension limit):
//   index = (workgroup_id.y · num_workgroups.x + workgroup_id.x) · 256 + local_invocation_index,
//   so every kernel returns early past the end of its range.
//
// Vectors are vec4<f32> in storage (16-byte stride, w = 0): vec3 arrays would have the same
// stride, and w = 0 keeps every element-wise update exact on the unused lane.

struct Params {
    // g, m/s².
    gravity: vec3<f32>,
    // Linear drag coefficient, 1/s: force −drag·m·v.
    drag: f32,
    n_particles: u32,
    n_springs: u32,
    // Terrain surfaces in `surfaces` (the buffer holds at least one, maybe a placeholder).
    n_surfaces: u32,
    // Step size h, s.
    dt: f32,
    // Contact reach ε, m: a surface acts on a particle where φ < ε.
    contact_distance: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct Spring {
    a: u32,
    b: u32,
    // Rest length r, m.
    rest: f32,
    // k_s, N/m.
    stiffness: f32,
    // k_d, N·s/m.
    damping: f32,
}

@group(0) @binding(0) var<uniform> params: Params;

const WORKGROUP_SIZE: u32 = 256u;
// "No particle / no step yet" in the status words (atomicMin targets).
const NONE: u32 = 0xffffffffu;

fn thread_index(workgroup: vec3<u32>, workgroups: vec3<u32>, local: u32) -> u32 {
    return (workgroup.y * workgroups.x + workgroup.x) * WORKGROUP_SIZE + local;
}

// Whether all three components are finite. WGSL lets a compiler assume that floats are never
// NaN or infinite, so `v != v` may be folded away; the exponent bits cannot be.
fn all_finite(v: vec3<f32>) -> bool {
    let e = bitcast<vec3<u32>>(v) & vec3<u32>(0x7f800000u);
    return all(e != vec3<u32>(0x7f800000u));
}
