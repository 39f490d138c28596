// energy.wgsl ↔ crates/cpu/src/energy.rs: the energies of a state,
//
//   kinetic ½Σ m|v|²,   gravitational −Σ m g·x,   elastic ½Σ k_s(|x_a − x_b| − r)².
//
// Each workgroup sums its 256 terms in shared memory by a fixed tree (`workgroup_sum`,
// reduce.wgsl) and writes one partial sum: `energy_particles` (m|v|², m g·x) per particle group into
// `particle_partials`, `energy_springs` (k_s(|d| − r)²) per spring group into `spring_partials`.
// The host adds the partials in order, in f64, and applies the ½ and − factors: the same result
// for the same state on one adapter, and no float atomics. `energy_springs` is dispatched once
// per spring chunk (common.wgsl, `SpringChunk`): chunks are whole workgroups long, so partial
// `chunk.first_group + g` sums the same 256 springs however the springs are chunked, and only
// workgroups that hold springs write one (a 2-D grid's idle tail would overwrite the next
// chunk's).

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> springs: array<Spring>;
@group(0) @binding(5) var<storage, read_write> particle_partials: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read_write> spring_partials: array<f32>;
@group(0) @binding(7) var<uniform> chunk: SpringChunk;

@compute @workgroup_size(WORKGROUP_SIZE)
fn energy_particles(id: Invocation) {
    let i = thread_of(id);
    // No early return: every thread takes part in the barriers.
    var term = vec2<f32>(0.0);
    if i < params.n_particles {
        let m = mass[i].x;
        let vi = v[i].xyz;
        term = vec2<f32>(m * dot(vi, vi), m * dot(params.gravity, x[i].xyz));
    }
    let sum = workgroup_sum(id.local, term);
    if id.local == 0u {
        particle_partials[workgroup_of(id)] = sum;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn energy_springs(id: Invocation) {
    let j = thread_of(id);
    var term = 0.0;
    if j < chunk.count {
        let spring = springs[j];
        let stretch = distance(x[spring.a].xyz, x[spring.b].xyz) - spring.rest;
        term = spring.stiffness * stretch * stretch;
    }
    let sum = workgroup_sum(id.local, vec2<f32>(term, 0.0));
    let group = workgroup_of(id);
    if id.local == 0u && group * WORKGROUP_SIZE < chunk.count {
        spring_partials[chunk.first_group + group] = sum.x;
    }
}
