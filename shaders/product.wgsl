// product.wgsl: the per-particle half of implicit Euler's product A p,
//
//   out_i = m(1 + h·drag) p_i + Σ± z_s,   z_s = B_s (p_a − p_b)
//
// (gather.wgsl's loop over `gathered(s)`), shared by system.wgsl, whose `gathered(s)` reads the
// z_s its per-spring pass `apply_springs` wrote, and fused_product.wgsl, whose `gathered(s)`
// computes z_s itself (`block_product`, common.wgsl). The same entry points in both modules, so
// the two routes differ only in where z_s comes from.

@group(0) @binding(9) var<storage, read> p: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> out: array<vec4<f32>>;
// diag[2i].w = m(1 + h·drag) (system.wgsl's `assemble_particles` writes it).
@group(0) @binding(12) var<storage, read_write> diag: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_particles(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        out[i] = vec4<f32>(diag[2u * i].w * p[i].xyz + gather(i), 0.0);
    }
}

// For models whose bodies touch: `pair_products` (body_contact.wgsl) has left the pairs' terms
// in out.
@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_particles_with_pairs(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        out[i] = vec4<f32>((diag[2u * i].w * p[i].xyz + gather(i)) + out[i].xyz, 0.0);
    }
}
