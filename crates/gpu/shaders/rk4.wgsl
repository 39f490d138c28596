// rk4.wgsl ↔ crates/cpu/src/integrators/rk4.rs: classic fourth-order Runge–Kutta on
// y = (x, v), y' = (v, a(x, v)):
//
//   k1 = y'(y), k2 = y'(y + h/2 k1), k3 = y'(y + h/2 k2), k4 = y'(y + h k3),
//   y ← y + h/6 (k1 + 2k2 + 2k3 + k4).
//
// The weighted sum is accumulated as the stages go (the CPU's memory-lean scheme): the scratch is
// one stage state (stage_x, stage_v), the acceleration a and the running sums (sum_x, sum_v). A
// step is:
//
//   accelerations(x, v)        → rk4_first:  sum = (v, a);          stage = y + h/2 (v, a)
//   accelerations(stage)       → rk4_second: sum += 2 (v_s, a);     stage = y + h/2 (v_s, a)
//   accelerations(stage)       → rk4_third:  sum += 2 (v_s, a);     stage = y + h (v_s, a)
//   accelerations(stage)       → rk4_last:   sum += (v_s, a);       y += h/6 sum
//
// One thread per particle; element-wise (each thread reads its stage velocity before
// overwriting it).

#import common
#import updates

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> a: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> stage_x: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> stage_v: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> sum_x: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> sum_v: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn rk4_first(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i];
    let ai = a[i];
    sum_x[i] = vi;
    sum_v[i] = ai;
    let stage = advance(Y(x[i], vi), vi, ai, 0.5 * params.dt);
    stage_x[i] = stage.x;
    stage_v[i] = stage.v;
}

// k2 and k3: add 2·(v_s, a) to the sums and move the stage to y + next·(v_s, a).
fn rk4_middle(i: u32, next: f32) {
    let vs = stage_v[i];
    let ai = a[i];
    let sum = rk4_accumulate(Y(sum_x[i], sum_v[i]), vs, ai);
    sum_x[i] = sum.x;
    sum_v[i] = sum.v;
    let stage = advance(Y(x[i], v[i]), vs, ai, next);
    stage_x[i] = stage.x;
    stage_v[i] = stage.v;
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
    let y = rk4_finish(Y(x[i], v[i]), Y(sum_x[i], sum_v[i]), stage_v[i], a[i], params.dt);
    x[i] = y.x;
    v[i] = y.v;
}
