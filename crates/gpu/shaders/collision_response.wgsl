// collision_response.wgsl ↔ crates/cpu/src/collision_response.rs: the response after each
// completed step of the explicit integrators.
//
// For each particle and surface k (in order) with φ < ε: if N·v < 0 the normal velocity is
// reflected and scaled by the restitution, v ← v − (1 + k_r)(v·N)N (= v_t − k_r v_n), on a fresh
// impact only, else v ← v − (v·N)N; if φ < 0 the particle is moved back onto the surface,
// x ← x − φN. A fresh impact: the particle started the step outside surface k's band (bit
// min(k, 31) of its start mask clear) and approaches faster than a fall from rest through the
// band at the step's acceleration a_n = −N·(v − v_start)/h would bring it, (v·N)² > 2 a_n ε.
// Each surface sees the position the previous one left. Pinned particles (1/m = 0) are left
// alone. Then `start` becomes the final velocity and the mask of the bands the final position
// lies in: the start of the next step. One thread per particle. The response itself is
// response.wgsl's `respond`, shared with the fused step (explicit.wgsl).

#import common
#import response

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> start: array<Start>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn collision_response(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles || mass[i].y == 0.0 {
        return;
    }
    let r = respond(start[i], x[i].xyz, v[i].xyz);
    x[i] = vec4<f32>(r.x, 0.0);
    v[i] = vec4<f32>(r.v, 0.0);
    start[i] = r.start;
}

/// The start of the next step from the state as it is: before the first step and after the
/// state is set.
@compute @workgroup_size(WORKGROUP_SIZE)
fn contact_band(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    start[i] = Start(v[i].xyz, band_mask(x[i].xyz));
}
