//! Spring forces, computed once per spring and gathered per particle.
//!
//! For spring s = (a, b, r, k_s, k_d), with d = x_a − x_b and l = d/|d|:
//!
//! f_a = −[k_s(|d| − r) + k_d((v_a − v_b)·l)] l,  f_b = −f_a.
//!
//! [`compute`] writes f_a of every spring (in parallel, each spring independent);
//! [`gather`] sums them per particle over its adjacency run in ascending spring order. No
//! particle is written by two threads and every sum has one fixed order, so the result is the
//! same bits for any thread count (the GPU twin, `shaders/spring_forces.wgsl`, does the same).

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Adjacency, Springs};

/// Springs per rayon task: large enough to amortise scheduling, small enough to balance.
const SPRING_CHUNK: usize = 4096;

/// Force on particle `a` of one spring.
#[inline(always)]
pub fn spring_force(
    xa: DVec3,
    xb: DVec3,
    va: DVec3,
    vb: DVec3,
    rest: f64,
    ks: f64,
    kd: f64,
) -> DVec3 {
    let d = xa - xb;
    let len = d.length();
    // Validation refuses zero-length springs at rest; a spring crushed to zero length later has
    // no direction, and exerting no force is the only choice that does not invent one.
    if len == 0.0 {
        return DVec3::ZERO;
    }
    let l = d / len;
    -(ks * (len - rest) + kd * (va - vb).dot(l)) * l
}

/// Writes the force on `a` of every spring into `out`.
pub fn compute(springs: &Springs, x: &[DVec3], v: &[DVec3], out: &mut [DVec3]) {
    out.par_chunks_mut(SPRING_CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let base = c * SPRING_CHUNK;
            for (k, f) in chunk.iter_mut().enumerate() {
                let s = base + k;
                let (a, b) = (springs.a[s] as usize, springs.b[s] as usize);
                *f = spring_force(
                    x[a],
                    x[b],
                    v[a],
                    v[b],
                    springs.rest[s],
                    springs.stiffness[s],
                    springs.damping[s],
                );
            }
        });
}

/// Sum of the spring forces on particle `i`.
#[inline(always)]
pub fn gather(adjacency: &Adjacency, per_spring: &[DVec3], i: usize) -> DVec3 {
    let mut f = DVec3::ZERO;
    for &e in adjacency.of(i) {
        let s = (e >> 1) as usize;
        if e & 1 == 0 {
            f += per_spring[s];
        } else {
            f -= per_spring[s];
        }
    }
    f
}
