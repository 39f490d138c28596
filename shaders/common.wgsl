// common.wgsl: what every kernel of the GPU solver shares (crates/gpu/src/shaders.rs prepends it
// to each stage; WGSL has no includes).
//
// - `Params`: the run's constants, one uniform at @group(0) @binding(0) of every kernel. Its Rust
//   twin is `softbody_gpu::layout::Params`; a test checks size and offsets with naga.
// - `Spring`: one spring (a, b, r, k_s, k_d), 20-byte stride; twin `layout::SpringGpu`;
//   `spring_force`, its force (spring_forces.wgsl, system.wgsl).
// - `Invocation`, `thread_of`: the builtins every kernel takes and the global index of its thread
//   in a 1-D or 2-D grid of 256-thread workgroups (`thread_index`).
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

// The builtins every kernel takes, as one entry-point argument: `fn kernel(id: Invocation)`.
struct Invocation {
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) workgroups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
}

// The invocation's global thread index (see thread_index). A kernel over particles starts
// `let i = thread_of(id); if i >= params.n_particles { return; }` (over springs, n_springs).
fn thread_of(id: Invocation) -> u32 {
    return thread_index(id.workgroup, id.workgroups, id.local);
}

// The invocation's workgroup index in its grid, the slot of its workgroup's partial sum.
fn workgroup_of(id: Invocation) -> u32 {
    return id.workgroup.y * id.workgroups.x + id.workgroup.x;
}

// The force on a of spring (a, b, r, k_s, k_d) (crates/cpu/src/spring_forces.rs): with
// d = x_a − x_b and l = d/|d|, f_a = −[k_s(|d| − r) + k_d((v_a − v_b)·l)] l, and 0 for a spring
// crushed to zero length (it has no direction).
fn spring_force(spring: Spring, xa: vec3<f32>, xb: vec3<f32>, va: vec3<f32>, vb: vec3<f32>) -> vec3<f32> {
    let d = xa - xb;
    let len = length(d);
    if len == 0.0 {
        return vec3<f32>(0.0);
    }
    let l = d / len;
    return -(spring.stiffness * (len - spring.rest) + spring.damping * dot(va - vb, l)) * l;
}

// Whether all three components are finite. WGSL lets a compiler assume that floats are never
// NaN or infinite, so `v != v` may be folded away; the exponent bits cannot be.
fn all_finite(v: vec3<f32>) -> bool {
    let e = bitcast<vec3<u32>>(v) & vec3<u32>(0x7f800000u);
    return all(e != vec3<u32>(0x7f800000u));
}

// glam's `clamp_length_max`, operation for operation: v scaled to length `max` if longer.
fn clamp_length_max(v: vec3<f32>, max_length: f32) -> vec3<f32> {
    let length_sq = dot(v, v);
    if length_sq > max_length * max_length {
        return max_length * (v / sqrt(length_sq));
    }
    return v;
}

// The velocity constraint of a particle in the implicit solve, in the w of its
// `constraints` vec4 (xyz: the normal of a NORMAL constraint): implicit_euler.wgsl writes them,
// cg.wgsl filters by them.
const CONSTRAINT_FREE: f32 = 0.0;
const CONSTRAINT_NORMAL: f32 = 1.0;
const CONSTRAINT_FIXED: f32 = 2.0;
