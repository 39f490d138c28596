// forces.wgsl ↔ crates/cpu/src/forces.rs: a(x, v) = f(x, v)/m with
//
//   f = m g − drag·m·v + Σ_springs ±f_s (gathered) + contact and friction (contact.wgsl),
//
// plus, with contact between bodies, the pairs' penalty forces (body_contact.wgsl),
//
// one thread per particle. Particle i's spring forces are gathered over its CSR run in ascending
// spring order (gather.wgsl): the CPU's order, and no float atomics. Pinned particles (1/m = 0)
// get a = 0. The formula is acceleration.wgsl's, shared with the fused step.
//
// `adjacency` holds the offsets (n + 1 words) followed by the entries (2·springs words), and
// `mass` holds (m, 1/m) per particle: one buffer each instead of two keeps this kernel at 8
// storage buffers with the terrain's two, WebGPU's guaranteed minimum per shader stage.

#import common
#import gather
#import acceleration
#import per_spring_chunks

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> per_spring: array<vec4<f32>>;
// adjacency (binding 4) is declared by gather.wgsl.
@group(0) @binding(5) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read_write> a: array<vec4<f32>>;

// The acceleration of particle i, with the forces between particles `pairs`.
fn accelerate(i: u32, pairs: vec3<f32>) {
    let mw = mass[i];
    if mw.y == 0.0 {
        a[i] = vec4<f32>(0.0);
        return;
    }
    a[i] = vec4<f32>(free_acceleration(mw, x[i].xyz, v[i].xyz, gather(i) + pairs), 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn accelerations(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        accelerate(i, vec3<f32>(0.0));
    }
}

// For models whose bodies touch: `pair_forces` (body_contact.wgsl) has left each particle's
// penalty forces in `a`, which are added to its springs' (the CPU's springs + pairs).
@compute @workgroup_size(WORKGROUP_SIZE)
fn accelerations_with_pairs(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        accelerate(i, a[i].xyz);
    }
}
