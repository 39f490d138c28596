// reduce.wgsl: the deterministic workgroup sum shared by energy.wgsl and cg.wgsl (and
// cg_common.wgsl).
//
// workgroup_sum(local, term) adds the 256 threads' terms in shared memory by a fixed tree (pairs
// at distance 128, 64, …, 1) and returns the sum to every thread. Every thread of the workgroup
// must call it (it has barriers): kernels that reduce do not return early past the end of their
// range, they contribute 0. The partial sums of the workgroups are then added in order, by the
// host (energies) or by one workgroup (sum_in_order, the CG scalars): the same bits for the same
// input on one adapter, and no float atomics. Sums are vec2 so that one pass can reduce two
// quantities; a single one rides in .x with 0 in .y.

#import common

var<workgroup> reduce_scratch: array<vec2<f32>, WORKGROUP_SIZE>;

fn workgroup_sum(local: u32, term: vec2<f32>) -> vec2<f32> {
    reduce_scratch[local] = term;
    workgroupBarrier();
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride >>= 1u) {
        if local < stride {
            reduce_scratch[local] = reduce_scratch[local] + reduce_scratch[local + stride];
        }
        workgroupBarrier();
    }
    let total = reduce_scratch[0];
    // No thread may overwrite the scratch (in a later call) before all have read the total.
    workgroupBarrier();
    return total;
}
