// contact.wgsl ↔ crates/cpu/src/contact.rs: contact and friction forces of the explicit
// integrators. Prepended (after terrain.wgsl) to forces.wgsl.
//
// With f the gravity, drag and spring force on a particle, for each surface k where the signed
// distance φ < ε and the particle pushes into it (N·f < 0):
//
// - contact: −(N·f) N, which cancels the push;
// - friction, with f_n = −N·f > 0 and the slip velocity v_t = v − (v·N)N:
//   - Coulomb (friction_model 0): kinetic −μ f_n v_t/|v_t|; when that would stop the slip within
//     this step (m|v_t|/h ≤ μ f_n) the contact sticks instead: −f_t − m v_t/h, clamped to μ f_n
//     (static friction);
//   - viscous (friction_model 1): −k_f f_n v_t, clamped to m|v_t|/h so it never reverses the slip
//     in one step.
//
// Every surface sees the same f: contact forces of one surface do not feed the next.
// `terrain_query_within(k, x, ε)` (terrain.wgsl) returns (outward unit normal N, φ) of surface k,
// exact wherever φ < ε (beyond, it may stop searching early: only φ ≥ ε matters then).

#import common
#import terrain

// Friction force for a contact pressed with `press`, slip `vt` and tangential applied force `ft`.
fn friction(
    model: u32,
    mu: f32,
    press: f32,
    h: f32,
    m: f32,
    vt: vec3<f32>,
    ft: vec3<f32>,
) -> vec3<f32> {
    // Force per unit slip speed that stops the slip in one step.
    let stop = m / h;
    if model == FRICTION_COULOMB {
        let limit = mu * press;
        let speed = length(vt);
        if stop * speed > limit {
            return -limit * vt / speed;
        }
        return clamp_length_max(-ft - stop * vt, limit);
    }
    return clamp_length_max(-mu * press * vt, stop * length(vt));
}

// The contact and friction force on one particle (mass m, position x, velocity v, applied
// force f) for step size h and contact reach eps.
fn contact_force(eps: f32, h: f32, m: f32, x: vec3<f32>, v: vec3<f32>, f: vec3<f32>) -> vec3<f32> {
    var total = vec3<f32>(0.0);
    for (var k = 0u; k < params.n_surfaces; k++) {
        let q = terrain_query_within(k, x, eps);
        // Written so that a NaN φ never makes contact (as on the CPU).
        if !(q.w < eps) {
            continue;
        }
        let n = q.xyz;
        let fn_dot = dot(n, f);
        if fn_dot >= 0.0 {
            continue;
        }
        let press = -fn_dot;
        total += press * n;
        let vt = v - dot(v, n) * n;
        let surface = surfaces[k];
        let ft = f - fn_dot * n;
        total += friction(surface.friction_model, surface.friction, press, h, m, vt, ft);
    }
    return total;
}
