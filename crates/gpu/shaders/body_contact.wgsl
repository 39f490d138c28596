// body_contact.wgsl ↔ crates/cpu/src/body_contact.rs: contact between particles of bodies, for
// the pairs (lo, hi) in contact (neighbours.wgsl: admitted, d = |x_lo − x_hi| < R = r_lo + r_hi).
//
// The penalty of a pair in contact at the step's start is the critically damped spring
//
//   F = max(0, k (R − d) − c (u·n)) n,  n = (x_lo − x_hi)/d,  u = v_lo − v_hi,
//   k = κ m_red / h²,  c = 2 √(k m_red),  m_red = 1/(w_lo + w_hi),
//
// +F on lo and −F on hi, with κ = `contact.penalty` (PENALTY in the explicit integrators' stages,
// PENALTY_IMPLICIT in implicit Euler's solve).
//
// `pair_forces`, in every stage of the explicit integrators, before `accelerations_with_pairs`
// (forces.wgsl), which adds what it leaves in `a`: for the pairs in contact at the step's start
// (the grid of the start snapshot), F at the stage state, summed per particle in the order of
// the grid's search.
//
// `pair_system` and `pair_products` ↔ the pair blocks of
// crates/cpu/src/integrators/implicit_euler/system.rs: implicit Euler's linear system (system.wgsl)
// takes each pair in contact at the start whose penalty pushes there (F > 0 at the start
// snapshot) as a spring along n: ∂f_lo/∂x_lo = −k nnᵀ (the transverse term k(R − d)/d (I − nnᵀ)
// dropped, as for a compressed spring, so the matrix stays positive definite) and
// ∂f_lo/∂v_lo = −c nnᵀ, so its block is β nnᵀ with β = h c + h² k, added to the (lo, lo) and
// (hi, hi) blocks of A and subtracted from (lo, hi) and (hi, lo), and its share of the
// right-hand side is ±h(F − h k (u·n)) n. Per particle, in the order of the start grid's search:
//
// - `pair_system`, before `assemble_particles_with_pairs`, which adds what it leaves: into `b`
//   Σ±(F − h k (u·n)) n (the right-hand side over h), into `diag` Σ β nnᵀ as (xx, yy, zz, 0) and
//   (xy, xz, yz, 0);
// - `pair_products`, before `apply_particles_with_pairs`, which adds what it leaves: into `out`
//   Σ± β n n·(p_lo − p_hi).
//
// Pairs are not stored (as for `pair_forces`): every product searches the start grid again and
// evaluates its pairs from the start snapshot, whose positions and velocities no kernel writes
// until the step's end, so every product of a step has the same pairs and bit-equal blocks,
// and lo's and hi's terms are bit-equal and opposite: A stays symmetric. Only the particles
// with a pushing pair search: `pair_system` leaves their number in the w of the start
// snapshot's velocity (a lane that is 0 in every state vector and that nothing else reads),
// and a particle without one has no pair terms — skipping its search gives the same zero bits,
// and saves a software adapter most of a product where few particles touch (the search costs
// lavapipe more than the rest of a CG iteration).
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

#import common
#import neighbours

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> a: array<vec4<f32>>;
// Implicit Euler's (system.wgsl's names): the vector of a product, its result, the right-hand
// side, the diagonal blocks.
@group(0) @binding(4) var<storage, read> p: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> out: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> b: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> diag: array<vec4<f32>>;

// (k, c) of the penalty for a pair of reduced mass m_red.
fn penalty_coefficients(m_red: f32) -> vec2<f32> {
    let k = contact.penalty * m_red / (params.dt * params.dt);
    return vec2<f32>(k, 2.0 * sqrt(k * m_red));
}

// The penalty between lo and hi at positions (x_lo, x_hi) and velocities (v_lo, v_hi): its
// magnitude F = k (R − d) − c (u·n) on lo along n (not clamped: it pushes where F > 0), k and c,
// and u·n; all zero unless they overlap (or where they coincide, or both are pinned).
struct Penalty {
    normal: vec3<f32>,
    force: f32,
    stiffness: f32,
    damping: f32,
    approach: f32,
}

fn penalty_law(lo: u32, hi: u32, x_lo: vec3<f32>, x_hi: vec3<f32>, v_lo: vec3<f32>, v_hi: vec3<f32>) -> Penalty {
    let reach = particles[lo].radius + particles[hi].radius;
    let w = particles[lo].inv_mass + particles[hi].inv_mass;
    let offset = x_lo - x_hi;
    let d2 = dot(offset, offset);
    if d2 >= reach * reach || d2 == 0.0 || w == 0.0 {
        return Penalty(vec3<f32>(0.0), 0.0, 0.0, 0.0, 0.0);
    }
    let d = sqrt(d2);
    let n = offset / d;
    let kc = penalty_coefficients(1.0 / w);
    let un = dot(v_lo - v_hi, n);
    return Penalty(n, kc.x * (reach - d) - kc.y * un, kc.x, kc.y, un);
}

// The penalty force on lo at the stage state (x, v), 0 unless they overlap there.
fn penalty(lo: u32, hi: u32) -> vec3<f32> {
    let law = penalty_law(lo, hi, x[lo].xyz, x[hi].xyz, v[lo].xyz, v[hi].xyz);
    return max(law.force, 0.0) * law.normal;
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

// A pair's spring in implicit Euler's system, from the start snapshot: n, β = h c + h² k and
// the right-hand side's share over h on lo, (F − h k (u·n)) n; β = 0 and no share where the
// penalty does not push at the start.
struct PairSpring {
    normal: vec3<f32>,
    beta: f32,
    rhs: vec3<f32>,
}

fn pair_spring(lo: u32, hi: u32) -> PairSpring {
    let law = penalty_law(lo, hi, snapshot_x[lo].xyz, snapshot_x[hi].xyz, snapshot_v[lo].xyz, snapshot_v[hi].xyz);
    if !(law.force > 0.0) {
        return PairSpring(vec3<f32>(0.0), 0.0, vec3<f32>(0.0));
    }
    let h = params.dt;
    let rhs = (law.force - h * law.stiffness * law.approach) * law.normal;
    return PairSpring(law.normal, h * law.damping + h * h * law.stiffness, rhs);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_system(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    var g = vec3<f32>(0.0);
    var dd = vec3<f32>(0.0);
    var off = vec3<f32>(0.0);
    var pushing = 0u;
    if particles[i].radius > 0.0 {
        var it = neighbours_of(snapshot_x[i].xyz);
        loop {
            let j = next_partner(i, &it, 0u);
            if j == NONE {
                break;
            }
            let s = pair_spring(min(i, j), max(i, j));
            if i < j {
                g += s.rhs;
            } else {
                g -= s.rhs;
            }
            let n = s.normal;
            dd += s.beta * n * n;
            off += s.beta * vec3<f32>(n.x * n.y, n.x * n.z, n.y * n.z);
            pushing += u32(s.beta > 0.0);
        }
    }
    snapshot_v[i].w = f32(pushing);
    b[i] = vec4<f32>(g, 0.0);
    diag[2u * i] = vec4<f32>(dd, 0.0);
    diag[2u * i + 1u] = vec4<f32>(off, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn pair_products(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    var z = vec3<f32>(0.0);
    if snapshot_v[i].w > 0.0 {
        var it = neighbours_of(snapshot_x[i].xyz);
        loop {
            let j = next_partner(i, &it, 0u);
            if j == NONE {
                break;
            }
            let lo = min(i, j);
            let hi = max(i, j);
            let s = pair_spring(lo, hi);
            let t = s.beta * dot(s.normal, p[lo].xyz - p[hi].xyz) * s.normal;
            if i == lo {
                z += t;
            } else {
                z -= t;
            }
        }
    }
    out[i] = vec4<f32>(z, 0.0);
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
