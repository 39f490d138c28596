// implicit_euler.wgsl ↔ crates/cpu/src/integrators/implicit_euler/mod.rs: linearised backward
// Euler with contacts as velocity constraints, around the solve of system.wgsl and cg.wgsl:
//
//   A Δv = h (f + h ∂f/∂x v) (+ friction impulses),   v' = v + Δv,   x' = x + h v'.
//
// Read the CPU twin's module doc for the contact model; the kernels here are its per-particle
// pieces, one thread per particle, each particle's contact in one `Candidate` record:
//
// - `implicit_candidates` (after assembly): the particle's nearest surface by the predicted
//   φ + h v·N among those with φ < reach = ε + h(2|v| + h|g|) (the first on ties), or none.
//   A candidate with φ + h v·N < ε (plus `resting_slack` if it was touching at the end of the
//   last step) is activated: target normal velocity v_n' = −φ/h, on a fresh
//   impact (not touching at the end of the last step) max(−φ/h, k_r·max(−v_n, 0)); normal
//   impulse estimate λ_n = max(m(v_n' − v_n) − b·N, 0); friction direction −v_t/|v_t|; it sticks
//   if the surface has Coulomb friction μ > 0 and (it stuck at the end of the last step or
//   m|v_t| ≤ μλ_n), else slips. The surface's friction law is copied into the record.
// - `implicit_constrain`: constraints, prescribed Δv (z) and rhs = b + friction impulse:
//   pinned → fixed, z = −v; sticking → fixed, z = v_n' N − v; slipping → normal(N),
//   z = (v_n' − v·N) N and the impulse μλ_n·dir (Coulomb) or −k_f λ_n v_t clamped to m|v_t|
//   (viscous); otherwise free, z = 0.
// - `implicit_active_set` (after a solve, with q = A Δv): λ = A Δv − rhs, λ_n = λ·N, and per
//   candidate: an inactive one (not released) that would end the step inside (φ + h v'·N < 0)
//   is activated (not sticking before; it keeps its settled mark); an active one that pulls
//   (λ_n < 0) is released for the rest of the step; a sticking one takes λ_n and slips along
//   λ_t once |λ_t| > μλ_n(1 + STICK_SLACK) unless settled; a slipping one whose slip reverses
//   (Coulomb, μ > 0, not settled) sticks and is settled; else, with μ > 0, it takes λ_n when
//   that moved by more than 1e-3 relative. Any change sets the `changed` word (atomicOr); the
//   host reads it and solves again, at most ACTIVE_SET_ROUNDS (8) times per step.
// - `implicit_remember` (before the step's solves): the warm start's history moves on a step.
// - `implicit_finish`: v ← v + Δv, x ← x + h v. The records stay: the next step's candidates
//   read from them whether the particle was touching (active) and sticking at the end of this
//   one.
//
// The records (twin: `softbody_gpu::layout::CandidateGpu`) persist between steps; the host
// zeroes them at the start (mode NONE). Terrain (terrain.wgsl, @group(1)) is bound for
// `implicit_candidates` only.

#import common
#import terrain

struct Candidate {
    // Outward unit normal N of the surface at the start of the step.
    normal: vec3<f32>,
    // Signed distance φ at the start of the step.
    phi: f32,
    // Unit direction of the kinetic friction impulse.
    friction_dir: vec3<f32>,
    // Target normal velocity at the end of the step.
    vn_target: f32,
    // Normal impulse the friction uses (estimated, then from the last solve).
    lambda_n: f32,
    // The surface's μ (Coulomb) or k_f (viscous).
    friction: f32,
    // The surface's k_r.
    restitution: f32,
    // CANDIDATE_MODE_MASK bits: the mode; then the CANDIDATE_* flags.
    state: u32,
}

const MODE_NONE: u32 = 0u;
const MODE_INACTIVE: u32 = 1u;
const MODE_STICK: u32 = 2u;
const MODE_SLIP: u32 = 3u;
const CANDIDATE_MODE_MASK: u32 = 3u;
// Released as pulling this step: stays free.
const CANDIDATE_RELEASED: u32 = 4u;
// Switched from slipping to sticking this step: may not switch again.
const CANDIDATE_SETTLED: u32 = 8u;
// Touching a surface at the end of the last step (a new touch is a fresh impact).
const CANDIDATE_TOUCHING: u32 = 16u;
// The surface's friction law is viscous (else Coulomb).
const CANDIDATE_VISCOUS: u32 = 32u;

// The CPU allows |λ_t| to exceed μλ_n by 1e-9 relative before a sticking contact slips; in f32
// the solve's λ is good to about the CG tolerance, so the slack is 1e-5.
const STICK_SLACK: f32 = 1e-5;
// A slipping contact's friction follows its solve's λ_n while it moves by more than this,
// relative: its f32 solve's tolerance (the CPU's twin refreshes to 1e-6).
const FRICTION_REFRESH: f32 = 1e-5;

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> rhs: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> b: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> dv: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> q: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> candidates: array<Candidate>;
@group(0) @binding(9) var<storage, read_write> constraints: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> z: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> changed: atomic<u32>;
// The warm start's history (cg.wgsl's projection): the Δv of the last step, and of the two
// before it.
@group(0) @binding(12) var<storage, read_write> last: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read_write> earlier_1: array<vec4<f32>>;
@group(0) @binding(14) var<storage, read_write> earlier_2: array<vec4<f32>>;

// softbody_scene::implicit::RESTING_ULPS, and f32's machine epsilon.
const RESTING_ULPS: f32 = 64.0;
const F32_EPSILON: f32 = 1.1920929e-7;

// softbody_scene::implicit::resting_slack in f32: how far above ε a particle that touched at the
// end of the last step may be predicted and still be activated, the rounding of x and h v (a
// particle at rest on a surface is predicted at ε = 0 up to that rounding).
fn resting_slack(xi: vec3<f32>, vi: vec3<f32>, h: f32) -> f32 {
    let a = abs(xi);
    return RESTING_ULPS * F32_EPSILON * (max(a.x, max(a.y, a.z)) + h * length(vi));
}

fn mode_of(c: Candidate) -> u32 {
    return c.state & CANDIDATE_MODE_MASK;
}

fn with_mode(c: Candidate, mode: u32) -> Candidate {
    var out = c;
    out.state = (c.state & ~CANDIDATE_MODE_MASK) | mode;
    return out;
}

fn coulomb(c: Candidate) -> bool {
    return (c.state & CANDIDATE_VISCOUS) == 0u && c.friction > 0.0;
}

// Makes a candidate a contact (the CPU's `activate`): v, m of its particle and its b (the
// right-hand side without friction).
fn activate(c: Candidate, vi: vec3<f32>, m: f32, bi: vec3<f32>, was_sticking: bool) -> Candidate {
    var out = c;
    let h = params.dt;
    let n = c.normal;
    let vn = dot(vi, n);
    out.vn_target = -c.phi / h;
    if (c.state & CANDIDATE_TOUCHING) == 0u {
        out.vn_target = max(out.vn_target, c.restitution * max(-vn, 0.0));
    }
    out.lambda_n = max(m * (out.vn_target - vn) - dot(bi, n), 0.0);
    let vt = vi - vn * n;
    let speed = length(vt);
    out.friction_dir = select(vec3<f32>(0.0), -vt / speed, speed > 0.0);
    let stick = coulomb(c) && (was_sticking || m * speed <= c.friction * out.lambda_n);
    return with_mode(out, select(MODE_SLIP, MODE_STICK, stick));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn implicit_candidates(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let last = mode_of(candidates[i]);
    var c: Candidate;
    c.state = MODE_NONE;
    if mass[i].y == 0.0 {
        candidates[i] = c;
        return;
    }
    let h = params.dt;
    let eps = params.contact_distance;
    let xi = x[i].xyz;
    let vi = v[i].xyz;
    // Far enough that nothing this step can bring it within ε, even with twice its speed.
    let reach = eps + h * (2.0 * length(vi) + h * length(params.gravity));
    var best = NONE;
    var best_predicted = 0.0;
    var best_q = vec4<f32>(0.0);
    for (var k = 0u; k < params.n_surfaces; k++) {
        let qk = terrain_query_within(k, xi, reach);
        // Written so that a NaN φ never makes contact (as on the CPU).
        if !(qk.w < reach) {
            continue;
        }
        let predicted = qk.w + h * dot(vi, qk.xyz);
        if best == NONE || predicted < best_predicted {
            best = k;
            best_predicted = predicted;
            best_q = qk;
        }
    }
    if best == NONE {
        candidates[i] = c;
        return;
    }
    let surface = surfaces[best];
    c.normal = best_q.xyz;
    c.phi = best_q.w;
    c.friction = surface.friction;
    c.restitution = surface.restitution;
    c.state = MODE_INACTIVE;
    if surface.friction_model == FRICTION_VISCOUS {
        c.state |= CANDIDATE_VISCOUS;
    }
    var slack = 0.0;
    if last == MODE_STICK || last == MODE_SLIP {
        c.state |= CANDIDATE_TOUCHING;
        slack = resting_slack(xi, vi, h);
    }
    if best_predicted < eps + slack {
        c = activate(c, vi, mass[i].x, b[i].xyz, last == MODE_STICK);
    }
    candidates[i] = c;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn implicit_constrain(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i].xyz;
    var constraint = vec4<f32>(0.0, 0.0, 0.0, CONSTRAINT_FREE);
    var zi = vec3<f32>(0.0);
    var impulse = vec3<f32>(0.0);
    let mw = mass[i];
    let c = candidates[i];
    let n = c.normal;
    if mw.y == 0.0 {
        constraint.w = CONSTRAINT_FIXED;
        zi = -vi;
    } else if mode_of(c) == MODE_STICK {
        constraint.w = CONSTRAINT_FIXED;
        zi = c.vn_target * n - vi;
    } else if mode_of(c) == MODE_SLIP {
        constraint = vec4<f32>(n, CONSTRAINT_NORMAL);
        zi = (c.vn_target - dot(vi, n)) * n;
        if (c.state & CANDIDATE_VISCOUS) == 0u {
            impulse = c.friction * c.lambda_n * c.friction_dir;
        } else {
            let vt = vi - dot(vi, n) * n;
            impulse = clamp_length_max(-c.friction * c.lambda_n * vt, mw.x * length(vt));
        }
    }
    constraints[i] = constraint;
    z[i] = vec4<f32>(zi, 0.0);
    rhs[i] = vec4<f32>(b[i].xyz + impulse, 0.0);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn implicit_active_set(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    var c = candidates[i];
    let mode = mode_of(c);
    if mode == MODE_NONE {
        return;
    }
    let h = params.dt;
    let n = c.normal;
    let lambda = q[i].xyz - rhs[i].xyz;
    let lambda_n = dot(lambda, n);
    let vi = v[i].xyz;
    let v_new = vi + dv[i].xyz;
    let settled = (c.state & CANDIDATE_SETTLED) != 0u;
    var change = false;
    if mode == MODE_INACTIVE {
        if (c.state & CANDIDATE_RELEASED) == 0u && c.phi + h * dot(v_new, n) < 0.0 {
            // Free, so rhs is b here. `activate` keeps the flags (settled among them).
            c = activate(c, vi, mass[i].x, rhs[i].xyz, false);
            change = true;
        }
    } else if lambda_n < 0.0 {
        c = with_mode(c, MODE_INACTIVE);
        c.state |= CANDIDATE_RELEASED;
        change = true;
    } else if mode == MODE_STICK {
        c.lambda_n = lambda_n;
        let lambda_t = lambda - lambda_n * n;
        let t = length(lambda_t);
        if !settled && t > c.friction * lambda_n * (1.0 + STICK_SLACK) {
            c = with_mode(c, MODE_SLIP);
            c.friction_dir = lambda_t / t;
            change = true;
        }
    } else {
        let slip = v_new - dot(v_new, n) * n;
        if coulomb(c) && !settled && dot(slip, c.friction_dir) > 0.0 {
            // Friction overshot: the slip reversed, so the contact sticks.
            c = with_mode(c, MODE_STICK);
            c.state |= CANDIDATE_SETTLED;
            change = true;
        } else if c.friction > 0.0
            && abs(lambda_n - c.lambda_n) > FRICTION_REFRESH * max(abs(lambda_n), c.lambda_n) {
            c.lambda_n = lambda_n;
            change = true;
        }
    }
    candidates[i] = c;
    if change {
        atomicOr(&changed, 1u);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn implicit_finish(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i].xyz + dv[i].xyz;
    v[i] = vec4<f32>(vi, 0.0);
    x[i] = x[i] + vec4<f32>(params.dt * vi, 0.0);
}

// The warm start's history moves on by a step before the step's solves: earlier_2 ← earlier_1
// ← last ← Δv (the last step's). Then Δv, earlier_1 and earlier_2 are the CPU's warm start and
// `earlier` at every solve of the step (`last` carries the last step's Δv past them, where the
// CPU keeps it aside and rotates `earlier` after the solves).
@compute @workgroup_size(WORKGROUP_SIZE)
fn implicit_remember(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    earlier_2[i] = earlier_1[i];
    earlier_1[i] = last[i];
    last[i] = dv[i];
}
