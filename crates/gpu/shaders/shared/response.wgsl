// response.wgsl: the collision response of one particle after a step (the law is in
// collision_response.wgsl's header, twin crates/cpu/src/collision_response.rs), shared by
// collision_response.wgsl and the fused step (explicit.wgsl).

#import common
#import terrain

/// A particle at the start of a step: its velocity and the mask of the bands it lies in.
struct Start {
    v: vec3<f32>,
    band: u32,
}

/// A particle after the response: its position and velocity, and the start of its next step.
struct Responded {
    x: vec3<f32>,
    v: vec3<f32>,
    start: Start,
}

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

/// The response of a free particle at (x0, v0) whose step started as `begin`.
fn respond(begin: Start, x0: vec3<f32>, v0: vec3<f32>) -> Responded {
    var xi = x0;
    var vi = v0;
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
    return Responded(xi, vi, Start(vi, select(end, band_mask(xi), moved)));
}
