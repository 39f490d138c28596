// finite.wgsl: the instability record of one particle (check_finite.wgsl's header has the
// scheme), imported by check_finite.wgsl and the fused step (explicit.wgsl).
// Twins: `softbody_gpu::layout::{Status, StepIndex}`.

#import common

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

@group(0) @binding(3) var<storage, read_write> status: Status;
@group(0) @binding(5) var<uniform> step_index: StepIndex;

// Records particle i if its (x, v) after step `step_index.step` holds a non-finite value,
// unless an earlier step of the submission was recorded already.
fn check_particle(i: u32, xi: vec3<f32>, vi: vec3<f32>) {
    let step = step_index.step;
    if atomicLoad(&status.bad_step) < step {
        return;
    }
    let bad_x = !all_finite(xi);
    let bad_v = !all_finite(vi);
    if bad_x || bad_v {
        atomicMin(&status.bad_step, step);
        atomicMin(&status.bad_particle, i);
        if bad_x {
            atomicMin(&status.bad_position, i);
        }
    }
}
