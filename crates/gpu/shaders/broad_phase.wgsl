// broad_phase.wgsl ↔ crates/cpu/src/broad_phase.rs: the hashed grid of the particles with a
// contact radius (neighbours.wgsl has the hash and the layout), built by a counting sort by
// bucket, every step from a snapshot of the state:
//
//   grid_clear                    counts[b] = 0
//   grid_count_start / _end       snapshot ← (x, v) at the step's start / end; per particle with
//                                 a radius its bucket b, and atomicAdd(counts[b], 1)
//   scan_up per level, upwards    counts ← the exclusive prefix sum of counts (below)
//   scan_down per level, down
//   grid_scatter                  slot = atomicAdd(counts[b], 1), sorted[slot] = i: counts[b]
//                                 ends as the end of b's run (its start was the prefix sum)
//   grid_sort                     each bucket's run sorted by particle index (insertion sort)
//
// The prefix sum: level 0 is the `buckets` counts, level l + 1 the totals of level l's blocks
// of 256 (`ScanLevel`: where a level lies in `counts` and where its block totals go). Each
// workgroup scans its block in shared memory and writes the block's total; going back down,
// each element adds its block's scanned total. The top level is one block. Integer sums: the
// result does not depend on the order of the additions.
//
// The only atomics are these integer counts. The scatter's slots within a bucket depend on
// thread timing; sorting each run (runs are short: a cell holds a few particles, a bucket a
// few cells) makes the grid a function of the positions alone, so a run repeats bit for bit.

#import common
#import neighbours

struct ScanLevel {
    // The level's first element in `counts`.
    offset: u32,
    // Its elements.
    count: u32,
    // Where its block totals go (the next level, or one word past the top).
    sums: u32,
    _pad: u32,
}

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
// `counts` again, for the kernels that count into it.
@group(0) @binding(3) var<storage, read_write> counts_atomic: array<atomic<u32>>;
// Each particle's bucket, NONE for a particle without a radius.
@group(0) @binding(4) var<storage, read_write> particle_bucket: array<u32>;
@group(0) @binding(5) var<uniform> scan_level: ScanLevel;

var<workgroup> block: array<u32, WORKGROUP_SIZE>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn grid_clear(id: Invocation) {
    let b = thread_of(id);
    if b < contact.buckets {
        counts[b] = 0u;
    }
}

// The snapshot of particle i at `base` and its count in the grid.
fn count(i: u32, base: u32) {
    if i >= params.n_particles {
        return;
    }
    let p = x[i];
    snapshot_x[base + i] = p;
    snapshot_v[base + i] = v[i];
    if particles[i].radius > 0.0 {
        let b = bucket_of(cell_of(p.xyz));
        particle_bucket[i] = b;
        atomicAdd(&counts_atomic[b], 1u);
    } else {
        particle_bucket[i] = NONE;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn grid_count_start(id: Invocation) {
    count(thread_of(id), 0u);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn grid_count_end(id: Invocation) {
    count(thread_of(id), params.n_particles);
}

// Each workgroup's block of the level: the exclusive prefix sums within the block, and the
// block's total. Barriers need every thread of the workgroup, so none returns early.
@compute @workgroup_size(WORKGROUP_SIZE)
fn scan_up(id: Invocation) {
    let group = workgroup_of(id);
    let t = id.local;
    let k = group * WORKGROUP_SIZE + t;
    let inside = k < scan_level.count;
    var value = 0u;
    if inside {
        value = counts[scan_level.offset + k];
    }
    block[t] = value;
    workgroupBarrier();
    // Hillis–Steele: after the round of step s, block[t] sums the 2s values ending at t.
    for (var step = 1u; step < WORKGROUP_SIZE; step *= 2u) {
        var earlier = 0u;
        if t >= step {
            earlier = block[t - step];
        }
        workgroupBarrier();
        block[t] += earlier;
        workgroupBarrier();
    }
    if inside {
        counts[scan_level.offset + k] = block[t] - value;
    }
    // A 2-D grid may have idle workgroups past the level's blocks: they write nothing.
    if t == WORKGROUP_SIZE - 1u && group * WORKGROUP_SIZE < scan_level.count {
        counts[scan_level.sums + group] = block[t];
    }
}

// Adds to each element of the level the scanned total of the blocks before its own.
@compute @workgroup_size(WORKGROUP_SIZE)
fn scan_down(id: Invocation) {
    let k = thread_of(id);
    if k < scan_level.count {
        counts[scan_level.offset + k] += counts[scan_level.sums + k / WORKGROUP_SIZE];
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn grid_scatter(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let b = particle_bucket[i];
    if b != NONE {
        sorted[atomicAdd(&counts_atomic[b], 1u)] = i;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn grid_sort(id: Invocation) {
    let b = thread_of(id);
    if b >= contact.buckets {
        return;
    }
    var start = 0u;
    if b > 0u {
        start = counts[b - 1u];
    }
    let end = counts[b];
    for (var k = start + 1u; k < end; k++) {
        let p = sorted[k];
        var at = k;
        while at > start && sorted[at - 1u] > p {
            sorted[at] = sorted[at - 1u];
            at -= 1u;
        }
        sorted[at] = p;
    }
}
