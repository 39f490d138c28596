// midpoint.wgsl ↔ crates/cpu/src/integrators/midpoint.rs: the midpoint method (RK2) on
// y = (x, v), y' = (v, a(x, v)):
//
//   y_m = y + (h/2) y'(y),   then   y ← y + h y'(y_m).
//
// A step is: accelerations at (x, v) → `midpoint_stage` (x_m = x + h/2 v, v_m = v + h/2 a) →
// accelerations at (x_m, v_m) → `midpoint_update` (x ← x + h v_m, v ← v + h a). One thread per
// particle; element-wise.

#import common
#import updates

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> a: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> stage_x: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> stage_v: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn midpoint_stage(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i];
    let stage = advance(Y(x[i], vi), vi, a[i], 0.5 * params.dt);
    stage_x[i] = stage.x;
    stage_v[i] = stage.v;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn midpoint_update(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let y = advance(Y(x[i], v[i]), stage_v[i], a[i], params.dt);
    x[i] = y.x;
    v[i] = y.v;
}
