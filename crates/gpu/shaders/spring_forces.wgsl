// spring_forces.wgsl ↔ crates/cpu/src/spring_forces.rs: one force per spring.
//
// For spring s = (a, b, r, k_s, k_d), with d = x_a − x_b and l = d/|d|:
//
//   f_a = −[k_s(|d| − r) + k_d((v_a − v_b)·l)] l,   f_b = −f_a,
//
// and f_a = 0 for a spring crushed to zero length (it has no direction; inventing one would be
// worse): `spring_force` in common.wgsl, shared with system.wgsl. One thread per spring writes f_a into `per_spring[s]`; `forces.wgsl` gathers them per
// particle in ascending spring order. No float atomics, no scattered sums: each particle's sum has
// one fixed order, so a run repeats bit for bit on one adapter.
//
// The inputs are whichever state the bind group holds: (x, v) or a stage state of midpoint/RK4.
// Dispatched once per spring chunk (common.wgsl, `SpringChunk`): `springs` and `per_spring` are
// the chunk's, indexed from 0.

#import common

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> springs: array<Spring>;
@group(0) @binding(4) var<storage, read_write> per_spring: array<vec4<f32>>;
@group(0) @binding(5) var<uniform> chunk: SpringChunk;

@compute @workgroup_size(WORKGROUP_SIZE)
fn spring_forces(id: Invocation) {
    let j = thread_of(id);
    if j >= chunk.count {
        return;
    }
    let spring = springs[j];
    let f = spring_force(spring, x[spring.a].xyz, x[spring.b].xyz, v[spring.a].xyz, v[spring.b].xyz);
    per_spring[j] = vec4<f32>(f, 0.0);
}
