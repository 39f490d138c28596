// explicit.wgsl ↔ crates/cpu/src/integrators/{explicit_euler,symplectic_euler,midpoint,rk4}.rs
// and crates/cpu/src/pipeline/: the explicit integrators' kernels, one per stage of each
// method, written once for both of the GPU's paths (crates/gpu/src/integrators/). On
// y = (x, v), y' = (v, a(x, v)), with the update equations of updates.wgsl:
//
//   explicit (forward) Euler:  x' = x + h v,   v' = v + h a;
//   symplectic Euler:          v' = v + h a,   x' = x + h v';
//   midpoint (RK2):            y_m = y + (h/2) y'(y),   then   y ← y + h y'(y_m);
//   RK4:                       k1 = y'(y), k2 = y'(y + h/2 k1), k3 = y'(y + h/2 k2),
//                              k4 = y'(y + h k3),   y ← y + h/6 (k1 + 2k2 + 2k3 + k4),
//
// RK4's weighted sum accumulated as the stages go (the CPU's memory-lean scheme: one stage state
// and the running sums sum_x, sum_v). A method's first kernel reads the step's start y as (x, v)
// on both paths; the paths differ in where the rest is, so the kernels reach it through six
// functions each path defines: `acceleration(i)` (a at the state the dispatch evaluates),
// `stage_velocity(i)` (that state's velocity, where it is a stage state), `step_start(i)` (y,
// which the step's last kernel updates), `stage_base(i)` (y, read by a kernel that writes the
// next stage), `set_stage(i, y)` and `end_step(i, y)`.
//
// # The per-spring path (no define: `Stage::Explicit`)
//
// `accelerations` (forces.wgsl) has written a = a(x, v) of the state, the solver's (x, v) or the
// stage state (stage_x, stage_v), and each kernel updates element-wise, one thread per
// particle, so the result does not depend on the dispatch (each thread reads its stage velocity
// before overwriting it). A step is:
//
//   Euler:     accelerations(x, v) → explicit_euler | symplectic_euler
//   midpoint:  accelerations(x, v) → midpoint_stage (x_m = x + h/2 v, v_m = v + h/2 a)
//              → accelerations(x_m, v_m) → midpoint_update (x ← x + h v_m, v ← v + h a)
//   RK4:       accelerations(x, v)  → rk4_first:  sum = (v, a);       stage = y + h/2 (v, a)
//              accelerations(stage) → rk4_second: sum += 2 (v_s, a);  stage = y + h/2 (v_s, a)
//              accelerations(stage) → rk4_third:  sum += 2 (v_s, a);  stage = y + h (v_s, a)
//              accelerations(stage) → rk4_last:   sum += (v_s, a);    y += h/6 sum
//
// # The fused path (`fused`: `Stage::FusedStep`; with `stencil` too, `Stage::FusedStencil`)
//
// One dispatch per integrator stage, one thread per particle, in place of the per-spring path's
// spring forces per spring → gather → update → collision response → check_finite.
//
// Thread i, for the state (x, v) this dispatch evaluates the forces at:
//
// 1. gathers its springs' forces from its neighbours, `gather(i)`, computing each spring's
//    force itself from the two ends' states:
//      f_s = spring_force(s, x_a, x_b, v_a, v_b)  (common.wgsl; the per-spring kernel's call),
//      Σ = Σ over i's run, ascending s, of +f_s (i = a) or −f_s (i = b).
//    Both ends evaluate a spring in its own (a, b) orientation, so they see bit-opposite
//    forces, and each sum has the per-spring path's order: the same bits as spring_forces.wgsl
//    + forces.wgsl, run to run, with no float atomics. The module takes one of two gathers
//    (the define `stencil` chooses): through the CSR adjacency and the spring records
//    (gather.wgsl + fused_gather.wgsl, `Stage::FusedStep`), or, where every body is a lattice,
//    by its lattice's stencil (stencil.wgsl, `Stage::FusedStencil`) with the same terms in the
//    same order;
// 2. a = (m g − drag·m·v + Σ + contact(f)) / m (acceleration.wgsl; a = 0 when pinned);
// 3. the stage's update (below, the per-spring path's kernels), into `x_next`, `v_next`;
// 4. after a step's last stage: the collision response with terrain (response.wgsl, pinned
//    particles left alone) and the finiteness record of step `step_index` (finite.wgsl).
//
// No thread reads what another writes in the same dispatch: neighbours are read from (x, v),
// results go to (x_next, v_next), a different pair of buffers; a thread reads its own x_next,
// v_next (a step's start y, updated in place by the last stage), `start` and the sums only at
// its own index. The host binds the pairs per dispatch (crates/gpu/src/integrators/fused.rs):
//
// | entry point | (x, v) | reads | writes |
// |---|---|---|---|
// | symplectic_euler: v' = v + h a, x' = x + h v' | y | | y' (the other pair: ping-pong) |
// | explicit_euler: x' = x + h v, v' = v + h a | y | | y' (ping-pong) |
// | midpoint_stage: y_m = y + h/2 (v, a) | y | | y_m |
// | midpoint_update: y ← y + h (v_m, a(y_m)) | y_m | y | y (in place) |
// | rk4_first: sum = (v, a); y_1 = y + h/2 (v, a) | y | | y_1, sum |
// | rk4_second: sum += 2 (v_1, a); y_2 = y + h/2 (v_1, a) | y_1 | y (base) | y_2, sum |
// | rk4_third: sum += 2 (v_2, a); y_3 = y + h (v_2, a) | y_2 | y (base) | y_3 (into y_1's pair), sum |
// | rk4_last: y ← y + h/6 (sum + (v_3, a)) | y_3 | y, sum | y (in place) |
//
// Models whose bodies touch take the per-spring path (their pair forces need the broad phase),
// as do adapters with too few storage buffers per stage for these kernels.

#import common
#ifdef fused
#import finite
#ifdef stencil
#import stencil
#else
#import fused_gather
#endif
#import acceleration
#import response
#endif
#import updates

#ifdef fused
@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
// status (3) and step_index (5) are declared by finite.wgsl; adjacency (4) and springs (7) by
// gather.wgsl and fused_gather.wgsl, or lattice_bodies (15) and lattice_points (16) by
// stencil.wgsl.
@group(0) @binding(6) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(8) var<storage, read_write> x_next: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> v_next: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> start: array<Start>;
@group(0) @binding(11) var<storage, read> base_x: array<vec4<f32>>;
@group(0) @binding(12) var<storage, read> base_v: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read_write> sum_x: array<vec4<f32>>;
@group(0) @binding(14) var<storage, read_write> sum_v: array<vec4<f32>>;

// The gathering thread's particle and its state, read once rather than once per spring.
var<private> own: u32;
var<private> own_x: vec3<f32>;
var<private> own_v: vec3<f32>;

// a(x, v) of particle i, as forces.wgsl's `accelerations` writes it.
fn acceleration(i: u32) -> vec4<f32> {
    let mw = mass[i];
    if mw.y == 0.0 {
        return vec4<f32>(0.0);
    }
    own = i;
    own_x = x[i].xyz;
    own_v = v[i].xyz;
    return vec4<f32>(free_acceleration(mw, own_x, own_v, gather(i)), 0.0);
}

// A stage state is bound as (x, v).
fn stage_velocity(i: u32) -> vec4<f32> {
    return v[i];
}

// The last kernel of a step updates y in place, so y is its (x_next, v_next).
fn step_start(i: u32) -> Y {
    return Y(x_next[i], v_next[i]);
}

// RK4's middle stages write the next stage into (x_next, v_next) and read y beside it.
fn stage_base(i: u32) -> Y {
    return Y(base_x[i], base_v[i]);
}

fn set_stage(i: u32, y: Y) {
    x_next[i] = y.x;
    v_next[i] = y.v;
}

// The end of a step: particle i's new state y after the collision response, into
// (x_next, v_next), and its finiteness record.
fn end_step(i: u32, y: Y) {
    var xi = y.x.xyz;
    var vi = y.v.xyz;
    if params.n_surfaces > 0u && mass[i].y != 0.0 {
        let r = respond(start[i], xi, vi);
        xi = r.x;
        vi = r.v;
        start[i] = r.start;
    }
    x_next[i] = vec4<f32>(xi, 0.0);
    v_next[i] = vec4<f32>(vi, 0.0);
    check_particle(i, xi, vi);
}
#else
@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> a: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> stage_x: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> stage_v: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> sum_x: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> sum_v: array<vec4<f32>>;

fn acceleration(i: u32) -> vec4<f32> {
    return a[i];
}

// The stage state is (stage_x, stage_v), whose accelerations `a` holds after the stage's
// forces; a kernel reads it before overwriting it with the next stage.
fn stage_velocity(i: u32) -> vec4<f32> {
    return stage_v[i];
}

// y stays in the solver's (x, v), which only a step's last kernel writes.
fn step_start(i: u32) -> Y {
    return Y(x[i], v[i]);
}

fn stage_base(i: u32) -> Y {
    return step_start(i);
}

fn set_stage(i: u32, y: Y) {
    stage_x[i] = y.x;
    stage_v[i] = y.v;
}

fn end_step(i: u32, y: Y) {
    x[i] = y.x;
    v[i] = y.v;
}
#endif

@compute @workgroup_size(WORKGROUP_SIZE)
fn explicit_euler(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i];
    end_step(i, advance(Y(x[i], vi), vi, acceleration(i), params.dt));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn symplectic_euler(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    end_step(i, symplectic(Y(x[i], v[i]), acceleration(i), params.dt));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn midpoint_stage(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i];
    set_stage(i, advance(Y(x[i], vi), vi, acceleration(i), 0.5 * params.dt));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn midpoint_update(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    end_step(i, advance(step_start(i), stage_velocity(i), acceleration(i), params.dt));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn rk4_first(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i];
    let ai = acceleration(i);
    sum_x[i] = vi;
    sum_v[i] = ai;
    set_stage(i, advance(Y(x[i], vi), vi, ai, 0.5 * params.dt));
}

// k2 and k3: add 2·(v_s, a) to the sums and move to the stage y + next·(v_s, a).
fn rk4_middle(i: u32, next: f32) {
    let vs = stage_velocity(i);
    let ai = acceleration(i);
    let sum = rk4_accumulate(Y(sum_x[i], sum_v[i]), vs, ai);
    sum_x[i] = sum.x;
    sum_v[i] = sum.v;
    set_stage(i, advance(stage_base(i), vs, ai, next));
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn rk4_second(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    rk4_middle(i, 0.5 * params.dt);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn rk4_third(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    rk4_middle(i, params.dt);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn rk4_last(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let sum = Y(sum_x[i], sum_v[i]);
    end_step(i, rk4_finish(step_start(i), sum, stage_velocity(i), acceleration(i), params.dt));
}
