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
// lies in: the start of the next step. One thread per particle.

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> mass: array<vec2<f32>>;
/// A particle at the start of a step: its velocity and the mask of the bands it lies in.
struct Start {
    v: vec3<f32>,
    band: u32,
}

@group(0) @binding(4) var<storage, read_write> start: array<Start>;

/// Bit min(k, 31) for each surface k whose contact band holds `p` (`band_mask` on the CPU).
fn band_mask(p: vec3<f32>) -> u32 {
    var mask = 0u;
    for (var k = 0u; k < params.n_surfaces; k++) {
        if terrain_query_within(k, p, params.contact_distance).w < params.contact_distance {
            mask |= 1u << min(k, 31u);
        }
    }
    return mask;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn collision_response(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles || mass[i].y == 0.0 {
        return;
    }
    let begin = start[i];
    var xi = x[i].xyz;
    var vi = v[i].xyz;
    // The bands the particle ends in, exact unless a later surface moves it (then recomputed).
    var end = 0u;
    var moved = false;
    for (var k = 0u; k < params.n_surfaces; k++) {
        // Exact wherever φ < ε, which is all that matters here.
        let q = terrain_query_within(k, xi, params.contact_distance);
        if !(q.w < params.contact_distance) {
            continue;
        }
        end |= 1u << min(k, 31u);
        let n = q.xyz;
        let vn = dot(vi, n);
        if vn < 0.0 {
            // Approach slower than a fall from rest through the band at the step's own
            // acceleration is band-scale jitter, not an impact.
            let a_n = max(-dot(vi - begin.v, n) / params.dt, 0.0);
            let outside = (begin.band & (1u << min(k, 31u))) == 0u;
            let fresh = outside && vn * vn > 2.0 * a_n * params.contact_distance;
            vi -= (1.0 + select(0.0, surfaces[k].restitution, fresh)) * vn * n;
        }
        if q.w < 0.0 {
            xi -= q.w * n;
            moved = true;
        }
    }
    x[i] = vec4<f32>(xi, 0.0);
    v[i] = vec4<f32>(vi, 0.0);
    start[i] = Start(vi, select(end, band_mask(xi), moved));
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
