// gather.wgsl: the per-particle gather over the CSR adjacency, imported by forces.wgsl,
// system.wgsl and product.wgsl, and by fused_gather.wgsl for the fused step (explicit.wgsl).
//
// `adjacency` holds the offsets (n + 1 words) followed by the entries (2·springs words): particle
// i's run is entries[offsets[i]..offsets[i+1]], in ascending spring order, entry e = 2s + side.
// gather(i) = Σ over the run of +gathered(s) (side 0: i is a) or −gathered(s) (side 1: i is b),
// in that order: the CPU's `spring_forces::gather`, with one fixed order per particle and no
// float atomics, so a run repeats bit for bit on one adapter.
//
// `gathered(s)`, spring s's vector as seen from its end a, is the including stage's: forces.wgsl
// and system.wgsl read it from the per-spring vectors a per-spring kernel wrote; the fused step
// computes the spring force itself from the two ends' states. The same loop in both keeps the
// order, hence the bits: the fused step gathers exactly what the per-spring path gathers.

#import common

@group(0) @binding(4) var<storage, read> adjacency: array<u32>;

fn gather(i: u32) -> vec3<f32> {
    var sum = vec3<f32>(0.0);
    let entries = params.n_particles + 1u;
    let end = adjacency[i + 1u];
    for (var k = adjacency[i]; k < end; k++) {
        let e = adjacency[entries + k];
        let f = gathered(e >> 1u);
        if (e & 1u) == 0u {
            sum += f;
        } else {
            sum -= f;
        }
    }
    return sum;
}
