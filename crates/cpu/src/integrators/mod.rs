//! Time integrators. Each advances the state by one step h = dt; the explicit family
//! (explicit Euler, symplectic Euler, midpoint, RK4) evaluates [`crate::forces::accelerations`]
//! and is followed by [`crate::collision_response`]; implicit Euler handles contact inside its
//! solve.
//!
//! Element-wise updates are parallel over particles; they have no reductions, so any split
//! gives the same bits.

pub mod explicit_euler;
pub mod implicit_euler;
pub mod midpoint;
pub mod rk4;
pub mod symplectic_euler;

use glam::DVec3;
use rayon::prelude::*;

use crate::forces::PARTICLE_CHUNK;

/// `y[i] = x[i] + s·d[i]` for every i.
pub(crate) fn axpy_into(y: &mut [DVec3], x: &[DVec3], s: f64, d: &[DVec3]) {
    y.par_iter_mut()
        .zip(x.par_iter().zip(d.par_iter()))
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(y, (x, d))| *y = *x + s * *d);
}

/// `y[i] += s·d[i]` for every i.
pub(crate) fn axpy(y: &mut [DVec3], s: f64, d: &[DVec3]) {
    y.par_iter_mut()
        .zip(d.par_iter())
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(y, d)| *y += s * *d);
}
