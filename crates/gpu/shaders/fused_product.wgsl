// fused_product.wgsl ↔ crates/cpu/src/integrators/implicit_euler/system.rs (`System::apply`):
// implicit Euler's product A p in one dispatch (product.wgsl's `apply_particles`), each
// particle computing its springs' terms z_s = B_s (p_a − p_b) from the blocks as it gathers
// them, instead of reading what system.wgsl's per-spring pass `apply_springs` wrote. Each term
// is computed at both of its ends, both times as seen from a (w = p_a − p_b, the same
// operations in `block_product`), so the gather adds and subtracts the very bits the
// per-spring pass would have written: the two routes agree bit for bit.
//
// No per-spring vector is written or read: per spring, the fused route reads the record, the
// block and the other end's p at each end; the two passes read the record, the block and both
// ends' p once and write z_s, which the gather reads at each end.

#import common
#import product
#import spring_chunks
#import block_chunks

// Chunk 0 of the spring records and of the blocks; `spring_at(s)` and `block_at(s)` (the
// generated pieces) read spring s from whichever chunk holds it.
@group(0) @binding(6) var<storage, read> springs: array<Spring>;
@group(0) @binding(7) var<storage, read> blocks: array<SpringBlock>;

fn gathered(s: u32) -> vec3<f32> {
    let spring = spring_at(s);
    return block_product(block_at(s), p[spring.a].xyz - p[spring.b].xyz);
}
