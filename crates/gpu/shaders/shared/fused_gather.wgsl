// fused_gather.wgsl: the fused step's springs through the CSR adjacency (gather.wgsl's loop over
// `gathered(s)`), for any model: imported by the fused step (explicit.wgsl, `Stage::FusedStep`).
// Models whose bodies are all lattices take stencil.wgsl instead (`Stage::FusedStencil`), which
// reads no spring record and no adjacency.

#import common
#import gather
#import spring_chunks

// Chunk 0 of the spring records; `spring_at(s)` (the generated piece `spring_chunks`) reads
// spring s from whichever chunk holds it.
@group(0) @binding(7) var<storage, read> springs: array<Spring>;

// Spring s's force on its end a at the state (x, v): what spring_forces.wgsl writes. Only the
// other end is read; the ends are put in (a, b) order by selection, not by a branch, which
// lanes of one SIMD group would take both ways.
fn gathered(s: u32) -> vec3<f32> {
    let spring = spring_at(s);
    let mine = spring.a == own;
    let other = select(spring.a, spring.b, mine);
    let xo = x[other].xyz;
    let vo = v[other].xyz;
    return spring_force(
        spring,
        select(xo, own_x, mine),
        select(own_x, xo, mine),
        select(vo, own_v, mine),
        select(own_v, vo, mine),
    );
}
