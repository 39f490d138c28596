// body_contact.wgsl ↔ crates/cpu/src/body_contact.rs: contact between particles of bodies, for
// the pairs (lo, hi) in contact (neighbours.wgsl: admitted, d = |x_lo − x_hi| < R = r_lo + r_hi).
//
// `pair_forces`, in every stage of the explicit integrators, before `accelerations_with_pairs`
// (forces.wgsl), which adds what it leaves in `a`: for the pairs in contact at the step's start
// (the grid of the start snapshot), the critically damped penalty force at the stage state
//
//   F = max(0, k (R − d) − c (u·n)) n,  n = (x_lo − x_hi)/d,  u = v_lo − v_hi,
//   k = κ m_red / h²,  c = 2 √(k m_red),  m_red = 1/(w_lo + w_hi),
//
// +F on lo and −F on hi, summed per particle in the order of the grid's search.
//
// `body_contact_response`, after the step and its terrain collision response, for the pairs in
// contact at the end (the grid of the end snapshot): with w = 1/m,
//
//   if u·n < 0:  J_n = (u_n' − u·n)/(w_lo + w_hi), u_n' = −k_r u·n on a fresh impact, else 0;
//                friction J_t against u_t = u − (u·n)n, pressed by J = J_n + h·|F|:
//                  Coulomb: |u_t|/(w_lo + w_hi) if that is ≤ μ J (static), else μ J (kinetic)
//                  viscous: min(k_f J |u_t|, |u_t|/(w_lo + w_hi))
//   if d < (1 − slop) R: pushed apart to that distance, each by its share w/(w_lo + w_hi)
//   v_lo += w_lo P, v_hi −= w_hi P (P = J_n n + J_t), and likewise the push Δ.
//
// A fresh impact: the pair started the step apart (d_start ≥ R) and approaches faster than a fall
// from rest through ε at the step's relative normal acceleration a_n = −(u − u_start)·n/h,
// (u·n)² > 2 a_n ε. Every pair is computed from the end snapshot and the start snapshot and each
// particle writes only its own x and v (one Jacobi sweep); pinned particles (w = 0) take nothing.

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> a: array<vec4<f32>>;

// (k, c) of the penalty for a pair of reduced mass m_red.
fn penalty_coefficients(m_red: f32) -> vec2<f32> {
    let k = contact.penalty * m_red / (params.dt * params.dt);
    return vec2<f32>(k, 2.0 * sqrt(k * m_red));
}

// The penalty force on lo at the stage state (x, v), 0 unless they overlap there.
fn penalty(lo: u32, hi: u32) -> vec3<f32> {
    let reach = particles[lo].radius + particles[hi].radius;
    let w = particles[lo].inv_mass + particles[hi].inv_mass;
    let offset = x[lo].xyz - x[hi].xyz;
    let d2 = dot(offset, offset);
    if d2 >= reach * reach || d2 == 0.0 || w == 0.0 {
        return vec3<f32>(0.0);
    }
    let d = sqrt(d2);
    let n = offset / d;
    let kc = penalty_coefficients(1.0 / w);
    let un = dot(v[lo].xyz - v[hi].xyz, n);
    return max(kc.x * (reach - d) - kc.y * un, 0.0) * n;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_forces(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    var f = vec3<f32>(0.0);
    if particles[i].radius > 0.0 {
        var it = neighbours_of(snapshot_x[i].xyz);
        loop {
            let j = next_partner(i, &it, 0u);
            if j == NONE {
                break;
            }
            if i < j {
                f += penalty(i, j);
            } else {
                f -= penalty(j, i);
            }
        }
    }
    a[i] = vec4<f32>(f, 0.0);
}

// The impulse P and push Δ of one pair, per unit of inverse mass.
struct Response {
    impulse: vec3<f32>,
    push: vec3<f32>,
}

fn pair_response(lo: u32, hi: u32) -> Response {
    let end = params.n_particles;
    let h = params.dt;
    let w = particles[lo].inv_mass + particles[hi].inv_mass;
    let reach = particles[lo].radius + particles[hi].radius;
    let offset = snapshot_x[end + lo].xyz - snapshot_x[end + hi].xyz;
    let d = length(offset);
    if w == 0.0 || d == 0.0 {
        // Pinned both, or on top of each other with no direction to push along.
        return Response(vec3<f32>(0.0), vec3<f32>(0.0));
    }
    let n = offset / d;
    let push = max((1.0 - contact.slop) * reach - d, 0.0) / w * n;
    let u = snapshot_v[end + lo].xyz - snapshot_v[end + hi].xyz;
    let un = dot(u, n);
    if un >= 0.0 {
        return Response(vec3<f32>(0.0), push);
    }
    let kc = penalty_coefficients(1.0 / w);
    let pressed = h * max(kc.x * max(reach - d, 0.0) - kc.y * un, 0.0);
    let u0 = snapshot_v[lo].xyz - snapshot_v[hi].xyz;
    let a_n = max(-dot(u - u0, n) / h, 0.0);
    let apart = distance(snapshot_x[lo].xyz, snapshot_x[hi].xyz) >= reach;
    let fresh = apart && un * un > 2.0 * a_n * params.contact_distance;
    let target_un = select(0.0, -contact.restitution * un, fresh);
    let jn = (target_un - un) / w;
    let ut = u - un * n;
    let slip = length(ut);
    let press = jn + pressed;
    var jt = vec3<f32>(0.0);
    if slip > 0.0 {
        let stop = slip / w;
        var magnitude: f32;
        if contact.friction_model == FRICTION_VISCOUS {
            magnitude = min(contact.friction * press * slip, stop);
        } else if stop <= contact.friction * press {
            magnitude = stop;
        } else {
            magnitude = contact.friction * press;
        }
        jt = -magnitude / slip * ut;
    }
    return Response(jn * n + jt, push);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn body_contact_response(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let me = particles[i];
    if me.radius <= 0.0 || me.inv_mass == 0.0 {
        return;
    }
    let end = params.n_particles;
    var xi = snapshot_x[end + i].xyz;
    var vi = snapshot_v[end + i].xyz;
    var touched = false;
    var it = neighbours_of(xi);
    loop {
        let j = next_partner(i, &it, end);
        if j == NONE {
            break;
        }
        touched = true;
        if i < j {
            let r = pair_response(i, j);
            vi += me.inv_mass * r.impulse;
            xi += me.inv_mass * r.push;
        } else {
            let r = pair_response(j, i);
            vi -= me.inv_mass * r.impulse;
            xi -= me.inv_mass * r.push;
        }
    }
    // The others keep the end state, which x and v hold.
    if touched {
        x[i] = vec4<f32>(xi, 0.0);
        v[i] = vec4<f32>(vi, 0.0);
    }
}
