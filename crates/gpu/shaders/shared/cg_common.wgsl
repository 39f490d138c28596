// cg_common.wgsl: what the CG's kernels (cg.wgsl) share with the product of its iterations
// (product.wgsl's `apply_particles_curvature`, which also forms q = S A c and cᵀq's partial
// sums): the velocity constraints' filter S and the per-workgroup partial sums of the CG's dot
// products.
//
// `partials` has PARTIAL_HALVES "halves" of n_partials slots (the workgroups of the particle
// grid), one sum per workgroup each: cᵀq's (and at a solve's start wᵀP⁻¹w's) first, then δ's
// (rᵀP⁻¹r, and at the start (Sb)ᵀP⁻¹(Sb)), then the warm start projection's (cg.wgsl).
// cᵀq's half comes first so that the product, which does not bind the CG's scalars and so does
// not know n_partials, can write it.

#import common
#import reduce

@group(0) @binding(14) var<storage, read> constraints: array<vec4<f32>>;
@group(0) @binding(15) var<storage, read_write> partials: array<vec2<f32>>;

// The halves of `partials`: which · n_partials is where each starts.
const CURVATURE: u32 = 0u;
const DELTA: u32 = 1u;
// The halves in all: these two and the warm start projection's (cg.wgsl, from PROJECTION).
const PARTIAL_HALVES: u32 = 10u;

// S_i p: the free part of p.
fn free_part(i: u32, p: vec3<f32>) -> vec3<f32> {
    let s = constraints[i];
    if s.w == CONSTRAINT_FREE {
        return p;
    }
    if s.w == CONSTRAINT_NORMAL {
        return p - dot(p, s.xyz) * s.xyz;
    }
    return vec3<f32>(0.0);
}

// Writes the tree sum of this workgroup's terms to its slot of the half that starts at `start`.
// Every thread of the workgroup calls it (it has barriers).
fn write_partial_at(id: Invocation, term: vec2<f32>, start: u32) {
    let sum = workgroup_sum(id.local, term);
    if id.local == 0u {
        partials[start + workgroup_of(id)] = sum;
    }
}

// cᵀq's half (CURVATURE, at 0).
fn write_curvature_partial(id: Invocation, term: vec2<f32>) {
    write_partial_at(id, term, 0u);
}
