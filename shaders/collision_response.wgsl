// collision_response.wgsl ↔ crates/cpu/src/collision_response.rs: the response after each
// completed step of the explicit integrators.
//
// For each particle and surface k (in order) with φ < ε: if N·v < 0 the normal velocity is
// reflected and scaled by the restitution, v ← v − (1 + k_r)(v·N)N (= v_t − k_r v_n); if φ < 0
// the particle is moved back onto the surface, x ← x − φN. Each surface sees the position the
// previous one left. Pinned particles (1/m = 0) are left alone. One thread per particle.

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> mass: array<vec2<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn collision_response(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles || mass[i].y == 0.0 {
        return;
    }
    var xi = x[i].xyz;
    var vi = v[i].xyz;
    for (var k = 0u; k < params.n_surfaces; k++) {
        // Exact wherever φ < ε, which is all that matters here.
        let q = terrain_query_within(k, xi, params.contact_distance);
        if !(q.w < params.contact_distance) {
            continue;
        }
        let n = q.xyz;
        let vn = dot(vi, n);
        if vn < 0.0 {
            vi -= (1.0 + surfaces[k].restitution) * vn * n;
        }
        if q.w < 0.0 {
            xi -= q.w * n;
        }
    }
    x[i] = vec4<f32>(xi, 0.0);
    v[i] = vec4<f32>(vi, 0.0);
}
