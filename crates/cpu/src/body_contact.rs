//! Contact between particles of bodies, applied after each step (every integrator): pairs (i, j)
//! of different bodies, or of one body with `self_contact` beyond its rest neighbourhood
//! ([`Contacts::admits`]), closer than the sum of their radii, d = |x_i − x_j| < R = r_i + r_j.
//!
//! For each pair, with n = (x_i − x_j)/d, w = 1/m, and the relative velocity u = v_i − v_j:
//!
//! - if u·n < 0 (approaching), a normal impulse J_n = (u_n' − u·n)/(w_i + w_j) takes the
//!   relative normal velocity to u_n' = −k_r·u·n on a fresh impact and to 0 otherwise; a fresh
//!   impact is what it is against terrain (docs/physics.md): the pair started the step apart
//!   (d_start ≥ R) and approaches faster than a fall from rest through the contact distance ε
//!   at the step's own relative normal acceleration a_n, (u·n)² > 2·a_n·ε;
//! - friction on the relative tangential velocity u_t: Coulomb, the impulse that stops the slip,
//!   |u_t|/(w_i + w_j), if it is at most μ·J_n (static), else μ·J_n against u_t (kinetic);
//!   viscous, k_f·J_n·|u_t| against u_t, capped at the impulse that stops the slip;
//! - if d < R, the pair is pushed apart to d = R, each particle by its share w/(w_i + w_j).
//!
//! Every pair's impulse and push is computed from the state after the step, before any is
//! applied (one Jacobi sweep), then added to i and subtracted from j in pair order: equal and
//! opposite, so linear momentum changes only by rounding, and the same bits for any thread
//! count. Pinned particles (w = 0) take nothing; a pair of two takes nothing.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Contacts, FrictionModel, Model, State};

use crate::broad_phase::BroadPhase;
use crate::vec_bytes;

/// The broad phase and the per-pair results of the response.
#[derive(Debug, Default)]
pub struct BodyContact {
    broad: BroadPhase,
    /// (velocity impulse P, position push Δ) of each pair: i gets +w_i·(P, Δ), j −w_j·(P, Δ).
    results: Vec<(DVec3, DVec3)>,
    pairs: Vec<[u32; 2]>,
}

impl BodyContact {
    /// Empty: the buffers grow on the first step.
    pub fn new() -> BodyContact {
        BodyContact::default()
    }

    /// The response of the state `now` at the end of a step that started at `start`; returns
    /// the lowest particle it left with a non-finite position or velocity (only the particles
    /// of touching pairs change).
    pub fn respond(&mut self, model: &Model, start: &State, now: &mut State) -> Option<usize> {
        let c = &model.contact;
        let pairs = self.broad.pairs(&now.x, &c.radius, |i, j| {
            c.admits(&model.adjacency, &model.springs, i, j)
        });
        self.pairs.clear();
        self.pairs.extend_from_slice(pairs);
        let (x, v) = (&now.x[..], &now.v[..]);
        let w = &model.inv_mass[..];
        let sim = &model.simulation;
        self.results.clear();
        self.pairs
            .par_iter()
            .map(|&[i, j]| {
                let (i, j) = (i as usize, j as usize);
                pair(
                    c,
                    sim.dt,
                    sim.contact_distance,
                    (w[i], w[j]),
                    [i, j],
                    (x, v),
                    start,
                )
            })
            .collect_into_vec(&mut self.results);
        let (x, v) = (&mut now.x, &mut now.v);
        for (&[i, j], &(p, d)) in self.pairs.iter().zip(&self.results) {
            let (i, j) = (i as usize, j as usize);
            v[i] += w[i] * p;
            v[j] -= w[j] * p;
            x[i] += w[i] * d;
            x[j] -= w[j] * d;
        }
        self.pairs
            .iter()
            .flatten()
            .map(|&p| p as usize)
            .filter(|&p| !x[p].is_finite() || !v[p].is_finite())
            .min()
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        self.broad.memory_bytes() + vec_bytes(&self.results) + vec_bytes(&self.pairs)
    }
}

/// The impulse P and push Δ of one pair, per unit of inverse mass (see the module doc).
fn pair(
    c: &Contacts,
    h: f64,
    eps: f64,
    (wi, wj): (f64, f64),
    [i, j]: [usize; 2],
    (x, v): (&[DVec3], &[DVec3]),
    start: &State,
) -> (DVec3, DVec3) {
    let w = wi + wj;
    let reach = c.radius[i] + c.radius[j];
    let offset = x[i] - x[j];
    let d = offset.length();
    if w == 0.0 || d == 0.0 {
        // Pinned both, or on top of each other with no direction to push along.
        return (DVec3::ZERO, DVec3::ZERO);
    }
    let n = offset / d;
    let push = (reach - d).max(0.0) / w * n;
    let u = v[i] - v[j];
    let un = u.dot(n);
    if un >= 0.0 {
        return (DVec3::ZERO, push);
    }
    let laws = &c.laws;
    let u0 = start.v[i] - start.v[j];
    let a_n = (-(u - u0).dot(n) / h).max(0.0);
    let apart = start.x[i].distance(start.x[j]) >= reach;
    let fresh = apart && un * un > 2.0 * a_n * eps;
    let target = if fresh { -laws.restitution * un } else { 0.0 };
    let jn = (target - un) / w;
    let ut = u - un * n;
    let slip = ut.length();
    let jt = if slip > 0.0 {
        let stop = slip / w;
        let jt = match laws.friction_model {
            FrictionModel::Coulomb if stop <= laws.friction * jn => stop,
            FrictionModel::Coulomb => laws.friction * jn,
            FrictionModel::Viscous => (laws.friction * jn * slip).min(stop),
        };
        -jt / slip * ut
    } else {
        DVec3::ZERO
    };
    (jn * n + jt, push)
}
