// product.wgsl: the per-particle half of implicit Euler's product A p,
//
//   out_i = m(1 + h·drag) p_i + Σ± z_s,   z_s = B_s (p_a − p_b)
//
// (gather.wgsl's loop over `gathered(s)`), shared by system.wgsl, whose `gathered(s)` reads the
// z_s its per-spring pass `apply_springs` wrote, and fused_product.wgsl, whose `gathered(s)`
// computes z_s itself (`block_product`, common.wgsl). The same entry points in both modules, so
// the two routes differ only in where z_s comes from.
//
// The CG's iterations (cg.wgsl) multiply its direction c, and take the filtered product: their
// `…_curvature` entry points write out = S A p and each workgroup's partial sum of pᵀ(S A p)
// (cg_common.wgsl), on the particle grid, so the sum's terms and tree are those a kernel of
// their own formed from the stored product before (the same bits), one dispatch fewer.

#import common
#import cg_common
#import gather

@group(0) @binding(9) var<storage, read> p: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> out: array<vec4<f32>>;
// diag[2i].w = m(1 + h·drag) (system.wgsl's `assemble_particles` writes it).
@group(0) @binding(12) var<storage, read_write> diag: array<vec4<f32>>;

// (A p)_i; where bodies touch (`pairs`), `pair_products` (body_contact.wgsl) has left the pairs'
// terms in out, added last.
fn product(i: u32, pairs: bool) -> vec3<f32> {
    let springs = diag[2u * i].w * p[i].xyz + gather(i);
    if pairs {
        return springs + out[i].xyz;
    }
    return springs;
}

// out = A p.
fn apply(id: Invocation, pairs: bool) {
    let i = thread_of(id);
    if i < params.n_particles {
        out[i] = vec4<f32>(product(i, pairs), 0.0);
    }
}

// out = S A p, and the workgroup's partial of pᵀ out into cᵀq's half of the partials. Every
// thread of the workgroup gets here (`write_curvature_partial` has barriers).
fn apply_curvature(id: Invocation, pairs: bool) {
    let i = thread_of(id);
    var term = vec2<f32>(0.0);
    if i < params.n_particles {
        let qi = free_part(i, product(i, pairs));
        out[i] = vec4<f32>(qi, 0.0);
        term = vec2<f32>(dot(p[i].xyz, qi), 0.0);
    }
    write_curvature_partial(id, term);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_particles(id: Invocation) {
    apply(id, false);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_particles_with_pairs(id: Invocation) {
    apply(id, true);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_particles_curvature(id: Invocation) {
    apply_curvature(id, false);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_particles_with_pairs_curvature(id: Invocation) {
    apply_curvature(id, true);
}
