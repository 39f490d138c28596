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
// after it. Twins: `softbody_gpu::layout::{Status, StepIndex}`.

struct Status {
    // The first step (1-based, within the submission) with a non-finite value, or NONE.
    bad_step: atomic<u32>,
    // The lowest particle with a non-finite x or v at that step, or NONE.
    bad_particle: atomic<u32>,
    // The lowest particle with a non-finite x at that step, or NONE.
    bad_position: atomic<u32>,
}

struct StepIndex {
    step: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(1) var<storage, read> x: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> v: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> status: Status;
@group(0) @binding(4) var<uniform> step_index: StepIndex;

@compute @workgroup_size(WORKGROUP_SIZE)
fn check_finite(id: Invocation) {
    let i = thread_of(id);
    if i >= params.n_particles {
        return;
    }
    let step = step_index.step;
    if atomicLoad(&status.bad_step) < step {
        return;
    }
    let bad_x = !all_finite(x[i].xyz);
    let bad_v = !all_finite(v[i].xyz);
    if bad_x || bad_v {
        atomicMin(&status.bad_step, step);
        atomicMin(&status.bad_particle, i);
        if bad_x {
            atomicMin(&status.bad_position, i);
        }
    }
}
