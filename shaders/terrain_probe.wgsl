// terrain_probe.wgsl: the test kernel of crates/gpu/tests/terrain_twin.rs, appended to
// terrain.wgsl (which binds group 1). For each input point p (w = a contact reach) and each
// surface k it writes, at out[2·(i·K + k)] and the next slot, terrain_query(k, p.xyz) and
// terrain_query_within(k, p.xyz, p.w), K being the number of surfaces.

@group(0) @binding(0) var<storage, read> probe_points: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> probe_out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn probe(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
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
