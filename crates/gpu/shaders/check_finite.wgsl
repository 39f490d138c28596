// check_finite.wgsl ↔ `softbody_cpu::first_non_finite`: the instability check after every step.
//
// The CPU reports the first step whose state holds a non-finite value, and the lowest such
// particle. Many steps run in one GPU submission, so the check records them on the device:
//
// - `step_index.step` is the step's number within its submission (1, 2, …). The host keeps a
//   constant table of these numbers, one per 256-byte slot, and binds the step's slot with a
//   dynamic offset when it encodes the dispatch: no extra dispatch and no host write per step.
// - A thread whose particle has a non-finite x or v does atomicMin(bad_step, step),
//   atomicMin(bad_particle, i), and atomicMin(bad_position, i) if x is the culprit.
// - Consecutive dispatches are ordered (each is its own usage scope), so a step's check sees what
//   earlier checks recorded: once bad_step holds an earlier step, later checks record nothing,
//   and bad_particle stays the lowest particle of the first bad step. That particle's x was
//   non-finite iff bad_position == bad_particle (the CPU says "position" before "velocity").
//
// The host resets the status to (NONE, NONE, NONE) before each submission and reads it back
// after it. The record is finite.wgsl's `check_particle`, shared with the fused step
// (explicit.wgsl), which checks the state it has just written.

#import common
#import finite

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
// status (binding 3) and step_index (binding 5) are declared by finite.wgsl.

@compute @workgroup_size(WORKGROUP_SIZE)
fn check_finite(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    check_particle(i, x[i].xyz, v[i].xyz);
}
