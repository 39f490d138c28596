// symplectic_euler.wgsl ↔ crates/cpu/src/integrators/symplectic_euler.rs: the update of
// symplectic (semi-implicit) Euler, after `accelerations` has written a = a(x, v):
//
//   v' = v + h a,   x' = x + h v'.
//
// One thread per particle; element-wise.

#import common
#import updates

@group(0) @binding(1) var<storage, read_write> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> a: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn symplectic_euler(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let y = symplectic(Y(x[i], v[i]), a[i], params.dt);
    x[i] = y.x;
    v[i] = y.v;
}
