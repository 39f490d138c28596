// acceleration.wgsl: a particle's acceleration from the forces the other particles exert on it,
// imported by forces.wgsl and the fused step (explicit.wgsl), so that both paths
// add the same terms in the same order (crates/cpu/src/forces.rs, `acceleration_with`):
//
//   f = m g − drag·m·v + between,   a = (f + contact_force(f)) / m,
//
// where `between` is the gathered spring forces (and, with contact between bodies, the pairs'
// penalty forces). Pinned particles (1/m = 0) get a = 0: the callers test for them first, so a
// pinned particle gathers nothing.

#import common
#import contact

// The acceleration of a free particle of mass m = mw.x (mw.y = 1/m) at (xi, vi).
fn free_acceleration(mw: vec2<f32>, xi: vec3<f32>, vi: vec3<f32>, between: vec3<f32>) -> vec3<f32> {
    let m = mw.x;
    let f = m * params.gravity - params.drag * m * vi + between;
    let fc = contact_force(params.contact_distance, params.dt, m, xi, vi, f);
    return (f + fc) * mw.y;
}
