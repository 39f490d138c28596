//! Time integrators. Each advances the state by one step h = dt; the explicit family
//! (explicit Euler, symplectic Euler, midpoint, RK4) evaluates accelerations (gravity, drag,
//! springs, [`crate::contact`]) and ends with [`crate::collision_response`]; implicit Euler
//! handles contact inside its solve.
//!
//! Each explicit stage is one fused [`pipeline::pass`](crate::pipeline::pass): spring forces at
//! the stage's (x, v), then per particle its acceleration and the stage update, written to other
//! arrays than the ones read (the workspace double-buffers the state). The last stage also
//! applies the collision response and checks finiteness ([`finish`]). Updates have no
//! reductions, so any split gives the same bits.

pub mod explicit_euler;
pub mod implicit_euler;
pub mod midpoint;
pub mod rk4;
pub mod symplectic_euler;

use glam::DVec3;
use softbody_scene::Model;

use crate::collision_response::respond_one;
use crate::terrain::Surface;

/// The end of an explicit step for particle i: its collision response (unless it is pinned),
/// then whether its position and velocity are finite.
#[inline(always)]
pub(crate) fn finish(
    model: &Model,
    surfaces: &[Surface],
    i: usize,
    x: &mut DVec3,
    v: &mut DVec3,
) -> bool {
    if !surfaces.is_empty() && model.inv_mass[i] != 0.0 {
        respond_one(surfaces, model.simulation.contact_distance, x, v);
    }
    x.is_finite() && v.is_finite()
}
