// explicit_euler.wgsl ↔ crates/cpu/src/integrators/explicit_euler.rs: the update of explicit
// (forward) Euler, after `accelerations` has written a = a(x, v):
//
//   x' = x + h v,   v' = v + h a.
//
// One thread per particle; element-wise, so the result does not depend on the dispatch.

#import common
#import updates

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> a: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn explicit_euler(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let vi = v[i];
    let y = advance(Y(x[i], vi), vi, a[i], params.dt);
    x[i] = y.x;
    v[i] = y.v;
}
