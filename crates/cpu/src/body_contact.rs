//! Contact between particles of bodies: pairs (i, j) of different bodies, or of one body with
//! `self_contact` beyond its rest neighbourhood ([`softbody_scene::Model::admits`]), closer
//! than the sum of their radii, d = |x_i − x_j| < R = r_i + r_j.
//!
//! Within the step, each pair that was in contact at its start pushes apart with a penalty
//! force ([`Partners`]), so that a resting stack is held by forces, as terrain holds a body (a
//! pair that meets within the step is an impact, left to the response): a critically damped
//! spring along n = (x_i − x_j)/d,
//!
//!   F = max(0, k (R − d) − c (u·n)) n,   k = κ m_red / h²,   c = 2 √(k m_red),
//!
//! with m_red = 1/(w_i + w_j). Its overlap under a load L is L h²/(κ m_red). The explicit
//! integrators evaluate it at every stage with κ = [`PENALTY`]: the pair's own oscillation is
//! ω h = √κ, well inside their stability, and the overlap micrometres for a body resting on
//! another at h = 1e-4 s. It is +F on i and −F on j, computed for the pair (min, max) by both
//! particles, so the two are bit-equal and opposite. Implicit Euler takes it into its linear
//! system as a spring along n (stiffness k, damping c, the transverse term dropped as for a
//! compressed spring) with κ = [`PENALTY_IMPLICIT`]: backward Euler damps any stiffness, and
//! at the large steps it is used for, a stiff penalty is what keeps overlaps small (0.05 mm, 0.1% of R,
//! for 6 N between two of the 64 g particles of the pile in the bowl at h = 1/60 s).
//!
//! After each step (every integrator), the response; for each pair, with w = 1/m and the
//! relative velocity u = v_i − v_j:
//!
//! - if u·n < 0 (approaching), a normal impulse J_n = (u_n' − u·n)/(w_i + w_j) takes the
//!   relative normal velocity to u_n' = −k_r·u·n on a fresh impact and to 0 otherwise; a fresh
//!   impact is what it is against terrain (docs/physics.md): the pair started the step apart
//!   (d_start ≥ R) and approaches faster than a fall from rest through the contact distance ε
//!   at the step's own relative normal acceleration a_n, (u·n)² > 2·a_n·ε;
//! - friction on the relative tangential velocity u_t, with the pair pressed by
//!   J = J_n + h·|F| (the impulse and the penalty force over the step): Coulomb, the impulse that
//!   stops the slip, |u_t|/(w_i + w_j), if it is at most μ·J (static), else μ·J against u_t
//!   (kinetic); viscous, k_f·J·|u_t| against u_t, capped at the impulse that stops the slip;
//! - if d < (1 − [`SLOP`])·R, the pair is pushed apart to that distance, each particle by its
//!   share w/(w_i + w_j): the penalty force holds overlaps far smaller, and a push within the
//!   slop would move particles with no force, which their springs answer with a chatter.
//!
//! Every pair's impulse and push is computed from the state after the step, before any is
//! applied (one Jacobi sweep), then added to i and subtracted from j in pair order: equal and
//! opposite, so linear momentum changes only by rounding, and the same bits for any thread
//! count. Pinned particles (w = 0) take nothing; a pair of two takes nothing.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::model::penalty as penalty_kappa;
use softbody_scene::{Adjacency, FrictionModel, Model, State};

use crate::broad_phase::BroadPhase;
use crate::vec_bytes;

pub use softbody_scene::model::{PENALTY, PENALTY_IMPLICIT, SLOP};

/// Forces that the explicit stages add to the springs': between particles (contact between
/// bodies), and the external forces a caller applies ([`External`]). A generic parameter of the
/// integrators, so that a model whose bodies cannot touch, run without external forces, pays
/// nothing.
pub trait PairForces: Sync {
    /// Whether the force is always zero (the passes then update whole rows side by side).
    const NONE: bool = false;
    /// The force on particle i at the stage state (x, v).
    fn force(&self, model: &Model, i: usize, x: &[DVec3], v: &[DVec3]) -> DVec3;
}

/// No forces between particles.
pub struct NoPairs;

impl PairForces for NoPairs {
    const NONE: bool = true;
    #[inline(always)]
    fn force(&self, _: &Model, _: usize, _: &[DVec3], _: &[DVec3]) -> DVec3 {
        DVec3::ZERO
    }
}

/// External forces on the particles (a control input, held over a frame's steps), added to
/// the forces between particles `inner`.
pub struct External<'a, P> {
    /// The force on each particle, N.
    pub forces: &'a [DVec3],
    /// The forces between particles besides them.
    pub inner: &'a P,
}

impl<P: PairForces> PairForces for External<'_, P> {
    #[inline(always)]
    fn force(&self, model: &Model, i: usize, x: &[DVec3], v: &[DVec3]) -> DVec3 {
        self.inner.force(model, i, x, v) + self.forces[i]
    }
}

/// The pairs in contact at the start of the step and each particle's partners among them.
#[derive(Debug, Default)]
pub struct Partners {
    /// The pairs (a, b), a < b, sorted.
    pairs: Vec<[u32; 2]>,
    /// Per particle, `2·pair + side` (side 0 where it is the pair's a): its partners k of
    /// pairs (k, p), ascending, then the j of pairs (p, j), ascending — the springs' layout,
    /// so the implicit system gathers pair terms as it gathers springs.
    adjacency: Adjacency,
}

impl Partners {
    /// The partners of `pairs` (sorted by (a, b)) among `n` particles.
    fn rebuild(&mut self, n: usize, pairs: &[[u32; 2]]) {
        self.pairs.clear();
        self.pairs.extend_from_slice(pairs);
        self.adjacency
            .rebuild(n, pairs.iter().map(|&[a, b]| (a, b)));
    }

    /// The pairs, sorted by (a, b).
    pub fn pairs(&self) -> &[[u32; 2]] {
        &self.pairs
    }

    /// Each particle's entries `2·pair + side` (see [`Adjacency`]).
    pub fn adjacency(&self) -> &Adjacency {
        &self.adjacency
    }
}

impl PairForces for Partners {
    /// The penalty forces on particle i at the stage state (x, v), summed over its partners in
    /// ascending order.
    #[inline(always)]
    fn force(&self, model: &Model, i: usize, x: &[DVec3], v: &[DVec3]) -> DVec3 {
        self.adjacency.of(i).iter().fold(DVec3::ZERO, |f, &e| {
            let [a, b] = self.pairs[(e >> 1) as usize];
            let p = penalty(model, [a as usize, b as usize], x, v);
            if e & 1 == 0 { f + p } else { f - p }
        })
    }
}

/// The penalty force on a of the pair [a, b] (a < b), 0 unless they overlap.
#[inline(never)]
fn penalty(model: &Model, pair: [usize; 2], x: &[DVec3], v: &[DVec3]) -> DVec3 {
    penalty_law(model, PENALTY, pair, x, v).map_or(DVec3::ZERO, |p| p.force * p.normal)
}

/// The penalty between a and b (a < b) at (x, v) with stiffness κ: its magnitude F > 0 on a
/// along n, and the pair's (k, c); `None` where it does not push.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Penalty {
    pub normal: DVec3,
    pub force: f64,
    pub stiffness: f64,
    pub damping: f64,
}

/// The penalty law of the module doc with stiffness κ (in units of m_red/h²).
#[inline(always)]
pub(crate) fn penalty_law(
    model: &Model,
    kappa: f64,
    [a, b]: [usize; 2],
    x: &[DVec3],
    v: &[DVec3],
) -> Option<Penalty> {
    let reach = model.contact.radius[a] + model.contact.radius[b];
    let offset = x[a] - x[b];
    let d2 = offset.length_squared();
    let w = model.inv_mass[a] + model.inv_mass[b];
    if d2 >= reach * reach || d2 == 0.0 || w == 0.0 {
        return None;
    }
    let d = d2.sqrt();
    let normal = offset / d;
    let (stiffness, damping) = penalty_coefficients(kappa, model.simulation.dt, 1.0 / w);
    let force = stiffness * (reach - d) - damping * (v[a] - v[b]).dot(normal);
    (force > 0.0).then_some(Penalty {
        normal,
        force,
        stiffness,
        damping,
    })
}

/// (k, c) of a penalty of stiffness κ for a pair of reduced mass `m_red` at step `h`:
/// k = κ m_red/h², critically damped.
pub(crate) fn penalty_coefficients(kappa: f64, h: f64, m_red: f64) -> (f64, f64) {
    let k = kappa * m_red / (h * h);
    (k, 2.0 * (k * m_red).sqrt())
}

/// The broad phase, the stages' partners and the per-pair results of the response.
#[derive(Debug, Default)]
pub struct BodyContact {
    broad: BroadPhase,
    partners: Partners,
    /// (velocity impulse P, position push Δ) of each pair: i gets +w_i·(P, Δ), j −w_j·(P, Δ).
    results: Vec<(DVec3, DVec3)>,
    pairs: Vec<[u32; 2]>,
}

impl BodyContact {
    /// Empty: the buffers grow on the first step.
    pub fn new() -> BodyContact {
        BodyContact::default()
    }

    /// Makes the partners of the step that starts at `state` ready: the pairs in contact
    /// there.
    pub fn prepare(&mut self, model: &Model, state: &State) {
        let c = &model.contact;
        let pairs = self
            .broad
            .pairs(&state.x, &c.radius, |i, j| model.admits(i, j));
        self.partners.rebuild(model.len(), pairs);
    }

    /// The admitted pairs in contact at the positions `x`, sorted by (i, j): those the response
    /// at `x` takes.
    pub(crate) fn touching(&mut self, model: &Model, x: &[DVec3]) -> &[[u32; 2]] {
        self.broad
            .pairs(x, &model.contact.radius, |i, j| model.admits(i, j))
    }

    /// The partners the stages' penalty forces act between.
    pub fn partners(&self) -> &Partners {
        &self.partners
    }

    /// The response of the state `now` at the end of a step that started at `start`; returns
    /// the lowest particle it left with a non-finite position or velocity (only the particles
    /// of touching pairs change).
    pub fn respond(&mut self, model: &Model, start: &State, now: &mut State) -> Option<usize> {
        let c = &model.contact;
        let pairs = self
            .broad
            .pairs(&now.x, &c.radius, |i, j| model.admits(i, j));
        self.pairs.clear();
        self.pairs.extend_from_slice(pairs);
        let (x, v) = (&now.x[..], &now.v[..]);
        let w = &model.inv_mass[..];
        self.results.clear();
        self.pairs
            .par_iter()
            .map(|&[i, j]| pair(model, [i as usize, j as usize], (x, v), start))
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
        self.broad.memory_bytes()
            + vec_bytes(&self.results)
            + vec_bytes(&self.pairs)
            + vec_bytes(&self.partners.pairs)
            + vec_bytes(&self.partners.adjacency.offsets)
            + vec_bytes(&self.partners.adjacency.entries)
    }
}

/// The impulse P and push Δ of one pair, per unit of inverse mass (see the module doc).
pub(crate) fn pair(
    model: &Model,
    [i, j]: [usize; 2],
    (x, v): (&[DVec3], &[DVec3]),
    start: &State,
) -> (DVec3, DVec3) {
    let c = &model.contact;
    let sim = &model.simulation;
    let (h, eps) = (sim.dt, sim.contact_distance);
    let w = model.inv_mass[i] + model.inv_mass[j];
    let reach = c.radius[i] + c.radius[j];
    let offset = x[i] - x[j];
    let d = offset.length();
    if w == 0.0 || d == 0.0 {
        // Pinned both, or on top of each other with no direction to push along.
        return (DVec3::ZERO, DVec3::ZERO);
    }
    let n = offset / d;
    let push = ((1.0 - SLOP) * reach - d).max(0.0) / w * n;
    let u = v[i] - v[j];
    let un = u.dot(n);
    if un >= 0.0 {
        return (DVec3::ZERO, push);
    }
    let (k, c_damp) = penalty_coefficients(penalty_kappa(sim.integrator), h, 1.0 / w);
    let pressed = h * (k * (reach - d).max(0.0) - c_damp * un).max(0.0);
    let laws = &c.laws;
    let u0 = start.v[i] - start.v[j];
    let a_n = (-(u - u0).dot(n) / h).max(0.0);
    let apart = start.x[i].distance(start.x[j]) >= reach;
    let fresh = apart && un * un > 2.0 * a_n * eps;
    let target = if fresh { -laws.restitution * un } else { 0.0 };
    let jn = (target - un) / w;
    let ut = u - un * n;
    let slip = ut.length();
    let press = jn + pressed;
    let jt = if slip > 0.0 {
        let stop = slip / w;
        let jt = match laws.friction_model {
            FrictionModel::Coulomb if stop <= laws.friction * press => stop,
            FrictionModel::Coulomb => laws.friction * press,
            FrictionModel::Viscous => (laws.friction * press * slip).min(stop),
        };
        -jt / slip * ut
    } else {
        DVec3::ZERO
    };
    (jn * n + jt, push)
}
