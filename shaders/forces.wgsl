// forces.wgsl ↔ crates/cpu/src/forces.rs: a(x, v) = f(x, v)/m with
//
//   f = m g − drag·m·v + Σ_springs ±f_s (gathered) + contact and friction (contact.wgsl),
//
// one thread per particle. Particle i's spring forces are summed over its CSR run
// `entries[offsets[i]..offsets[i+1]]` in ascending spring order, entry e = 2s + side adding
// per_spring[s] for side 0 (i is a) and subtracting it for side 1 (i is b): the CPU's order, and
// no float atomics. Pinned particles (1/m = 0) get a = 0.
//
// `adjacency` holds the offsets (n + 1 words) followed by the entries (2·springs words), and
// `mass` holds (m, 1/m) per particle: one buffer each instead of two keeps this kernel at 8
// storage buffers with the terrain's two, WebGPU's guaranteed minimum per shader stage.

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> per_spring: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> adjacency: array<u32>;
@group(0) @binding(5) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read_write> a: array<vec4<f32>>;

// Gravity, drag and spring force on particle i of mass m and velocity vi.
fn applied_force(i: u32, m: f32, vi: vec3<f32>) -> vec3<f32> {
    var springs = vec3<f32>(0.0);
    let entries = params.n_particles + 1u;
    let end = adjacency[i + 1u];
    for (var k = adjacency[i]; k < end; k++) {
        let e = adjacency[entries + k];
        let f = per_spring[e >> 1u].xyz;
        if (e & 1u) == 0u {
            springs += f;
        } else {
            springs -= f;
        }
    }
    return m * params.gravity - params.drag * m * vi + springs;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn accelerations(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) workgroups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = thread_index(workgroup, workgroups, local);
    if i >= params.n_particles {
        return;
    }
    let mw = mass[i];
    if mw.y == 0.0 {
        a[i] = vec4<f32>(0.0);
        return;
    }
    let xi = x[i].xyz;
    let vi = v[i].xyz;
    let f = applied_force(i, mw.x, vi);
    let fc = contact_force(params.contact_distance, params.dt, mw.x, xi, vi, f);
    a[i] = vec4<f32>((f + fc) * mw.y, 0.0);
}
