// system.wgsl ↔ crates/cpu/src/integrators/implicit_euler/system.rs: the linear system of one
// backward-Euler step, matrix-free,
//
//   A Δv = b,   A = M(1 + h·drag) − h ∂f/∂v − h² ∂f/∂x,   b = h (f + h ∂f/∂x v).
//
// For spring s with d = x_a − x_b, length ℓ, u = d/ℓ, α = max(0, 1 − r/ℓ) (the clamp keeps A
// symmetric positive definite; see the CPU twin): its block is
//
//   B_s = β uuᵀ + γ I,   β = h k_d + h² k_s (1 − α),   γ = h² k_s α,
//
// added to the (a, a) and (b, b) blocks of A and subtracted from (a, b) and (b, a); a spring
// crushed to zero length has u = 0 and α = 0. Kernels (one thread per spring or per particle):
//
// - `assemble_springs`: per spring, `blocks[s]` = (u, β, γ, h k_s ε_s) and, into
//   `per_spring_out`, g_s = f_s − h y_s with f_s the spring force (common.wgsl) and
//   y_s = K_s (v_a − v_b), K_s = k_s [(1 − α) uuᵀ + α I];
// - `assemble_particles`: b_i = h (m g − drag·m·v_i + Σ± g_s) (gather.wgsl: since
//   (∂f/∂x v)_i = −Σ± y_s, one gather gives h(f + h ∂f/∂x v)), and the diagonal block
//   D_i = m(1 + h·drag) I + Σ_{s ∋ i} B_s, stored as its inverse (the block-Jacobi
//   preconditioner) with the mass part: `diag[2i] = (P⁻¹xx, P⁻¹yy, P⁻¹zz, m(1 + h·drag))`,
//   `diag[2i + 1] = (P⁻¹xy, P⁻¹xz, P⁻¹yz, ρ_i²)` (P⁻¹ is symmetric; ρ_i² = Σ (h k_s ε_s)²,
//   what the f32 state resolves of each component of b_i, for the CG's stopping rule: a
//   spring's length is known to ε_s, half a ulp of its ends' largest coordinate);
// - `apply_springs`: z_s = B_s (p_a − p_b) into `per_spring_out`;
// - `apply_particles` (product.wgsl): out_i = m(1 + h·drag) p_i + Σ± z_s: out = A p.
//
// That is the product in two passes (`GpuOptions::per_spring`); by default fused_product.wgsl
// does it in one (`Stage::FusedProduct`), each particle computing its springs' z_s as it gathers
// them, with the same bits.
//
// With contact between bodies, the pairs in contact at the step's start are springs of the
// system too (body_contact.wgsl, `pair_system` and `pair_products`, which need the grid's
// bindings and so run as kernels of their own): they leave each particle's pair terms in `b`,
// `diag` and `out`, and `assemble_particles_with_pairs` and `apply_particles_with_pairs` add
// them after the springs' (the CPU's order: springs, then pairs).
//
// Every per-particle sum is a gather in ascending spring order (no float atomics). The inverse
// is the adjugate over the determinant, in f32: D_i is symmetric positive definite and
// diagonally dominated by the mass part for every scene the solver takes.
//
// `per_spring` (binding 3, read) and `per_spring_out` (binding 8, read_write) are the same
// buffer, bound in different dispatches.
//
// The per-spring kernels are dispatched once per spring chunk (common.wgsl, `SpringChunk`), with
// the chunk's `springs`, `blocks` and `per_spring_out` bound and indexed from 0; the particle
// kernels read every chunk through `per_spring_at` and `block_at` (the generated pieces
// `per_spring_chunks` and `block_chunks`; `blocks`, binding 7, is the first chunk). `p`, `out` and
// `diag` are declared in product.wgsl.

#import common
#import product
#import gather
#import per_spring_chunks
#import block_chunks

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> per_spring: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> mass: array<vec2<f32>>;
@group(0) @binding(6) var<storage, read> springs: array<Spring>;
@group(0) @binding(7) var<storage, read_write> blocks: array<SpringBlock>;
@group(0) @binding(8) var<storage, read_write> per_spring_out: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> b: array<vec4<f32>>;
@group(0) @binding(13) var<uniform> chunk: SpringChunk;

@compute @workgroup_size(WORKGROUP_SIZE)
fn assemble_springs(id: Invocation) {
    let j = thread_of(id);
    if j >= chunk.count {
        return;
    }
    let h = params.dt;
    let spring = springs[j];
    let xa = x[spring.a].xyz;
    let xb = x[spring.b].xyz;
    let va = v[spring.a].xyz;
    let vb = v[spring.b].xyz;
    let d = xa - xb;
    let len = length(d);
    var u = vec3<f32>(0.0);
    var alpha = 0.0;
    if len > 0.0 {
        u = d / len;
        alpha = max(1.0 - spring.rest / len, 0.0);
    }
    let ks = spring.stiffness;
    let w = va - vb;
    let y = ks * (1.0 - alpha) * dot(u, w) * u + ks * alpha * w;
    let f = spring_force(spring, xa, xb, va, vb);
    per_spring_out[j] = vec4<f32>(f - h * y, 0.0);
    let beta = h * spring.damping + h * h * ks * (1.0 - alpha);
    let resolution = h * ks * half_ulp(max(largest(xa), largest(xb)));
    blocks[j] = SpringBlock(u, beta, h * h * ks * alpha, resolution);
}

// The largest coordinate of p in magnitude.
fn largest(p: vec3<f32>) -> f32 {
    let a = abs(p);
    return max(a.x, max(a.y, a.z));
}

// Half a ulp of a (finite, non-negative) f32: how well a coordinate of that size is known.
fn half_ulp(a: f32) -> f32 {
    return 0.5 * (bitcast<f32>(bitcast<u32>(a) + 1u) - a);
}

// b_i and the inverse diagonal block of particle i, with the pairs' share of the force
// (the right-hand side over h) `pair_force` and of the block, (xx, yy, zz) `pair_dd` and
// (xy, xz, yz) `pair_off`.
fn assemble_particle(i: u32, pair_force: vec3<f32>, pair_dd: vec3<f32>, pair_off: vec3<f32>) {
    let h = params.dt;
    let m = mass[i].x;
    let md = m * (1.0 + h * params.drag);
    let f = m * params.gravity - params.drag * m * v[i].xyz + gather(i);
    b[i] = vec4<f32>(h * (f + pair_force), 0.0);
    // The diagonal block's upper triangle: (xx, yy, zz) and (xy, xz, yz).
    var dd = vec3<f32>(md);
    var off = vec3<f32>(0.0);
    // ρ_i² = Σ (h k_s ε_s)²: what the f32 state resolves of each component of b_i, squared
    // (the springs' errors independent, they add in squares).
    var resolution2 = 0.0;
    let entries = params.n_particles + 1u;
    let end = adjacency[i + 1u];
    for (var k = adjacency[i]; k < end; k++) {
        let blk = block_at(adjacency[entries + k] >> 1u);
        let u = blk.u;
        dd += blk.beta * u * u + vec3<f32>(blk.gamma);
        off += blk.beta * vec3<f32>(u.x * u.y, u.x * u.z, u.y * u.z);
        resolution2 += blk.resolution * blk.resolution;
    }
    dd += pair_dd;
    off += pair_off;
    // Cofactors of the symmetric block [[a, d, e], [d, b, f], [e, f, c]].
    let a = dd.x;
    let bb = dd.y;
    let c = dd.z;
    let dxy = off.x;
    let e = off.y;
    let fyz = off.z;
    let c00 = bb * c - fyz * fyz;
    let c11 = a * c - e * e;
    let c22 = a * bb - dxy * dxy;
    let c01 = e * fyz - dxy * c;
    let c02 = dxy * fyz - bb * e;
    let c12 = dxy * e - a * fyz;
    let inv_det = 1.0 / (a * c00 + dxy * c01 + e * c02);
    diag[2u * i] = vec4<f32>(vec3<f32>(c00, c11, c22) * inv_det, md);
    diag[2u * i + 1u] = vec4<f32>(vec3<f32>(c01, c02, c12) * inv_det, resolution2);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn assemble_particles(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        assemble_particle(i, vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    }
}

// For models whose bodies touch: `pair_system` (body_contact.wgsl) has left the pairs' terms in
// b and diag.
@compute @workgroup_size(WORKGROUP_SIZE)
fn assemble_particles_with_pairs(id: Invocation) {
    let i = thread_of(id);
    if i < params.n_particles {
        assemble_particle(i, b[i].xyz, diag[2u * i].xyz, diag[2u * i + 1u].xyz);
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn apply_springs(id: Invocation) {
    let j = thread_of(id);
    if j >= chunk.count {
        return;
    }
    let spring = springs[j];
    per_spring_out[j] = vec4<f32>(block_product(blocks[j], p[spring.a].xyz - p[spring.b].xyz), 0.0);
}
