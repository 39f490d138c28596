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
    let half_h = 0.5 * params.dt;
    let vi = v[i];
    let ai = a[i];
    sum_x[i] = vi;
    sum_v[i] = ai;
    stage_x[i] = x[i] + half_h * vi;
    stage_v[i] = vi + half_h * ai;
}

// k2 and k3: add 2·(v_s, a) to the sums and move the stage to y + next·(v_s, a).
fn rk4_middle(i: u32, next: f32) {
    let vs = stage_v[i];
    let ai = a[i];
    sum_x[i] = sum_x[i] + 2.0 * vs;
    sum_v[i] = sum_v[i] + 2.0 * ai;
    stage_x[i] = x[i] + next * vs;
    stage_v[i] = v[i] + next * ai;
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
    let sixth_h = params.dt / 6.0;
    let sx = sum_x[i] + stage_v[i];
    let sv = sum_v[i] + a[i];
    x[i] = x[i] + sixth_h * sx;
    v[i] = v[i] + sixth_h * sv;
}
