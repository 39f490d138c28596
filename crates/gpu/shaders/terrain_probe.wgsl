// terrain_probe.wgsl: the probe kernel of the terrain twin tests (crates/gpu/tests/terrain_twin.rs,
// through softbody_gpu::debug::terrain_probe), composed after common.wgsl and terrain.wgsl
// (which binds group 1). For each input point p (w = a contact reach) and each surface k it
// writes, at out[2·(i·K + k)] and the next slot, terrain_query(k, p.xyz) and
// terrain_query_within(k, p.xyz, p.w), K being the number of surfaces.

#import common
#import terrain

@group(0) @binding(1) var<storage, read> probe_points: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> probe_out: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn terrain_probe(id: Invocation) {
    let i = thread_of(id);
    if i >= arrayLength(&probe_points) {
        return;
    }
    let p = probe_points[i];
    let count = arrayLength(&surfaces);
    for (var k = 0u; k < count; k++) {
        let slot = 2u * (i * count + k);
        probe_out[slot] = terrain_query(k, p.xyz);
        probe_out[slot + 1u] = terrain_query_within(k, p.xyz, p.w);
    }
}
