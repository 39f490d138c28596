// energy.wgsl ↔ crates/cpu/src/energy.rs: the energies of a state,
//
//   kinetic ½Σ m|v|²,   gravitational −Σ m g·x,   elastic ½Σ k_s(|x_a − x_b| − r)².
//
// Each workgroup sums its 256 terms in shared memory by a fixed tree (`workgroup_sum`,
// reduce.wgsl) and writes one partial sum: `energy_particles` (m|v|², m g·x) per particle group into
// `particle_partials`, and the springs' k_s(|d| − r)² into `spring_partials` by one of two
// kernels. The host adds the partials in order, in f64, and applies the ½ and − factors: the
// same result for the same state on one adapter, and no float atomics.
//
// `energy_springs` (the spring list on the device: every route but the stencil) sums per spring
// group. It is dispatched once per spring chunk (common.wgsl, `SpringChunk`): chunks are whole
// workgroups long, so partial `chunk.first_group + g` sums the same 256 springs however the
// springs are chunked, and only workgroups that hold springs write one (a 2-D grid's idle tail
// would overwrite the next chunk's).
//
// `energy_lattices` (the stencil route, where every body is a lattice and no spring list exists
// on the device; twin: `energy_lattices` in energy.rs) sums per particle group: thread i adds
// the terms of the springs starting at its lattice point, in topology::OFFSETS order, as
// lattice.wgsl finds them, so each spring is counted once, at its first end. Its grid is the
// particles', every workgroup writing its partial (a 2-D grid's idle tail writes zeros into
// slots of its own).

#import common
#import reduce
#import lattice

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read> springs: array<Spring>;
@group(0) @binding(5) var<storage, read_write> particle_partials: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read_write> spring_partials: array<f32>;
@group(0) @binding(7) var<uniform> chunk: SpringChunk;

// Twice the elastic energy of `spring` with ends at xa and xb: k_s(|xa − xb| − r)².
fn spring_energy(spring: Spring, xa: vec3<f32>, xb: vec3<f32>) -> f32 {
    let stretch = distance(xa, xb) - spring.rest;
    return spring.stiffness * stretch * stretch;
}

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
        term = spring_energy(spring, x[spring.a].xyz, x[spring.b].xyz);
    }
    let sum = workgroup_sum(id.local, vec2<f32>(term, 0.0));
    let group = workgroup_of(id);
    if id.local == 0u && group * WORKGROUP_SIZE < chunk.count {
        spring_partials[chunk.first_group + group] = sum.x;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn energy_lattices(id: Invocation) {
    let i = thread_of(id);
    var term = 0.0;
    if i < params.n_particles {
        let s = stencil_of(i);
        let body = &lattice_bodies[s.body];
        let xi = x[i].xyz;
        for (var r = 0u; r < (*body).n_offsets; r++) {
            let offset = (*body).offsets[r];
            if in_grid(s, s.p + offset.d) && kept(s, offset, s.point) {
                let o = particle_at(s, step_point(s.point, offset, 1));
                term += spring_energy(lattice_spring(offset, i, o), xi, x[o].xyz);
            }
        }
    }
    let sum = workgroup_sum(id.local, vec2<f32>(term, 0.0));
    if id.local == 0u {
        spring_partials[workgroup_of(id)] = sum.x;
    }
}
