// pairs_probe.wgsl: the probe kernel of the body-contact twin tests
// (crates/gpu/tests/body_contact_twin.rs, through `GpuSolver::debug_contact_pairs`), composed
// after common.wgsl and neighbours.wgsl. For each particle i it counts its partners j > i in the
// grid of the end snapshot (`next_partner`, as the response finds them) into probe_count[i] and
// writes the first C of them, in the search's order, to probe_pairs[i·C ..], C being
// arrayLength(probe_pairs) / n.

#import common
#import neighbours

@group(0) @binding(1) var<storage, read_write> probe_count: array<u32>;
@group(0) @binding(2) var<storage, read_write> probe_pairs: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn pairs_probe(id: Invocation) {
    let i = thread_of(id);
    let n = params.n_particles;
    if i >= n {
        return;
    }
    let capacity = arrayLength(&probe_pairs) / n;
    var found = 0u;
    if particles[i].radius > 0.0 {
        var it = neighbours_of(snapshot_x[n + i].xyz);
        loop {
            let j = next_partner(i, &it, n);
            if j == NONE {
                break;
            }
            if j > i {
                if found < capacity {
                    probe_pairs[i * capacity + found] = j;
                }
                found += 1u;
            }
        }
    }
    probe_count[i] = found;
}
