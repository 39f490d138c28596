//! The adjoint of [`crate::body_contact`], on the forward's branches: the pairs the broad phase
//! found (at the step's start for the explicit stages' penalty and implicit Euler's pair blocks,
//! at the state after the terrain's response, or implicit Euler's update, for the pair
//! response), which of them push, approach, are fresh impacts, stick or slip, and whether a push
//! or a cap applies.
//!
//! A pair (a, b) with W = w_a + w_b, m = 1/W, n = (x_a − x_b)/d, u = v_a − v_b:
//!
//! - the penalty at a stage, P = F n, F = k (R − d) − c (u·n), k = κ m/h², c = 2 √(k m), +P on a
//!   and −P on b, so its cotangent is ḡ = f̄_a − f̄_b (each particle's force cotangent, as the
//!   springs'): F̄ = n·ḡ, n̄ = F ḡ − F̄ c u, ū = −F̄ c n, d̄ = −F̄ k, and through k and c, both
//!   linear in m, W̄ = −m (k k̄ + c c̄) with k̄ = F̄ (R − d), c̄ = −F̄ (u·n);
//! - the response, v_a += w_a P, v_b −= w_b P, x_a += w_a Δ, x_b −= w_b Δ, every pair's from
//!   the state before any is applied: P̄ = w_a v̄_a − w_b v̄_b, Δ̄ = w_a x̄_a − w_b x̄_b,
//!   w̄_a += P·v̄_a + Δ·x̄_a, w̄_b −= P·v̄_b + Δ·x̄_b, and P̄, Δ̄ back through the pair's law
//!   ([`pair_vjp`]): the push Δ = ((1 − SLOP)R − d)/W n, the normal impulse
//!   J_n = (−k_r u_n − u_n)/W (k_r = 0 unless fresh), the tangential one −j_t t̂ with
//!   t̂ = u_t/|u_t|, j_t = |u_t|/W (stick, or the viscous cap), μ J (kinetic) or μ J |u_t|
//!   (viscous), J = J_n + h max(0, k max(0, R − d) − c u_n);
//! - then x̄_a += d̄_x, x̄_b −= d̄_x with d̄_x = (n̄ − n (n·n̄))/d + d̄ n, v̄_a += ū, v̄_b −= ū,
//!   and W̄ to w̄_a and w̄_b (pinned particles, w = 0, keep theirs).
//!
//! The pairs' cotangents are computed side by side and scattered in pair order, the friction's
//! and restitution's onto the pair's first particle: the same bits for any thread count.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::model::penalty as penalty_kappa;
use softbody_scene::{FrictionModel, Model, State};
use softbody_terrain::Surface;

use super::Gradient;
use super::forces::unit_vjp;
use crate::body_contact::{
    BodyContact, PENALTY, PENALTY_IMPLICIT, Partners, SLOP, pair, penalty_coefficients, penalty_law,
};
use crate::forces::PARTICLE_CHUNK;
use crate::integrators::finish;
use crate::vec_bytes;

/// The cotangents of one pair's inputs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PairBar {
    /// Of x_a − x_b.
    pub x: DVec3,
    /// Of v_a − v_b.
    pub v: DVec3,
    /// Of W = w_a + w_b.
    pub w: f64,
    /// Of μ (or k_f) of contact between bodies.
    pub friction: f64,
    /// Of k_r of contact between bodies.
    pub restitution: f64,
}

/// The transpose of contact between bodies in one explicit step, and the forward's pairs it
/// needs.
#[derive(Debug)]
pub struct BodyAdjoint {
    contact: BodyContact,
    /// The state after the terrain's response, which the pair response starts from.
    after: (Vec<DVec3>, Vec<DVec3>),
    /// The pairs the response takes.
    pairs: Vec<[u32; 2]>,
    /// Each pair's cotangents and its particles' own shares of w̄ (the response's).
    bars: Vec<(PairBar, [f64; 2])>,
}

impl BodyAdjoint {
    /// Sized for `model`.
    pub fn new(model: &Model) -> BodyAdjoint {
        let n = model.len();
        BodyAdjoint {
            contact: BodyContact::new(),
            after: (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]),
            pairs: Vec::new(),
            bars: Vec::new(),
        }
    }

    /// Finds the pairs of the step that starts at `start`, between which the stages' penalty
    /// acts.
    pub fn prepare(&mut self, model: &Model, start: &State) {
        self.contact.prepare(model, start);
    }

    /// The pairs of the last [`BodyAdjoint::prepare`].
    pub fn partners(&self) -> &Partners {
        self.contact.partners()
    }

    /// The state after the terrain's response of the state `pre` at the end of the step from
    /// `start`, by the last stage's own function, and the pairs in contact there.
    pub fn forward(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        start: &State,
        (pre_x, pre_v): (&[DVec3], &[DVec3]),
    ) {
        let (x, v) = (&mut self.after.0, &mut self.after.1);
        x.copy_from_slice(pre_x);
        v.copy_from_slice(pre_v);
        x.par_iter_mut()
            .zip(v.par_iter_mut())
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (x, v))| {
                // Whether the result is finite was the forward's to check.
                finish(model, surfaces, i, (start.x[i], start.v[i]), x, v);
            });
        self.find_pairs(model);
    }

    /// The state after implicit Euler's step from `start` with velocity change `dv` (the step's
    /// own update, v' = v + Δv, x' = x + h v': the same bits), which the pair response starts
    /// from, and the pairs in contact there.
    pub fn implicit_forward(&mut self, model: &Model, start: &State, dv: &[DVec3]) {
        let h = model.simulation.dt;
        (&mut self.after.0, &mut self.after.1, dv)
            .into_par_iter()
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (x, v, dv))| {
                *v = start.v[i] + *dv;
                *x = start.x[i] + h * *v;
            });
        self.find_pairs(model);
    }

    /// The pairs the response takes: those touching after the step.
    fn find_pairs(&mut self, model: &Model) {
        let pairs = self.contact.touching(model, &self.after.0);
        self.pairs.clear();
        self.pairs.extend_from_slice(pairs);
    }

    /// Turns the cotangent of the state after the pair response of the step from `start` into
    /// the cotangent of the state before it ([`BodyAdjoint::forward`]'s), adding the masses',
    /// the friction's and the restitution's to `grad`.
    pub fn respond_vjp(
        &mut self,
        model: &Model,
        start: &State,
        (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
        grad: &mut Gradient,
    ) {
        let w = &model.inv_mass[..];
        let at = (&self.after.0[..], &self.after.1[..]);
        let (xb, vb) = (&*x_bar, &*v_bar);
        self.pairs
            .par_iter()
            .map(|&[a, b]| {
                let (a, b) = (a as usize, b as usize);
                let (p, d) = pair(model, [a, b], at, start);
                let p_bar = w[a] * vb[a] - w[b] * vb[b];
                let d_bar = w[a] * xb[a] - w[b] * xb[b];
                let bar = pair_vjp(model, [a, b], at, start, (p_bar, d_bar));
                let own = [p.dot(vb[a]) + d.dot(xb[a]), -(p.dot(vb[b]) + d.dot(xb[b]))];
                (bar, own)
            })
            .collect_into_vec(&mut self.bars);
        for (&[a, b], bar) in self.pairs.iter().zip(&self.bars) {
            scatter(model, [a as usize, b as usize], bar, (x_bar, v_bar), grad);
        }
    }

    /// Adds the cotangents of the penalty forces' inputs at the stage state (x, v) to
    /// `(x_bar, v_bar)` and `grad`, for `force_bar`, the cotangent of each particle's force
    /// besides the springs' ([`super::forces::Scratch::sum_bar`]).
    pub fn penalty_vjp(
        &mut self,
        model: &Model,
        (x, v): (&[DVec3], &[DVec3]),
        force_bar: &[DVec3],
        (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
        grad: &mut Gradient,
    ) {
        let pairs = self.contact.partners().pairs();
        pairs
            .par_iter()
            .map(|&[a, b]| {
                let (a, b) = (a as usize, b as usize);
                let bar = penalty_vjp(model, [a, b], (x, v), force_bar[a] - force_bar[b]);
                (bar, [0.0; 2])
            })
            .collect_into_vec(&mut self.bars);
        for (&[a, b], bar) in pairs.iter().zip(&self.bars) {
            scatter(model, [a as usize, b as usize], bar, (x_bar, v_bar), grad);
        }
    }

    /// Adds μᵀ ∂r/∂(x, v, w) of the pairs' share of implicit Euler's residual at the step's
    /// start (x, v) to `(x_bar, v_bar)` and `grad`, for the transpose's solution `mu` and the
    /// step's `dv` ([`pair_residual_vjp`]); the pairs are the [`BodyAdjoint::prepare`]d ones.
    pub fn implicit_vjp(
        &mut self,
        model: &Model,
        (x, v): (&[DVec3], &[DVec3]),
        (mu, dv): (&[DVec3], &[DVec3]),
        (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
        grad: &mut Gradient,
    ) {
        let pairs = self.contact.partners().pairs();
        pairs
            .par_iter()
            .map(|&[a, b]| {
                let (a, b) = (a as usize, b as usize);
                let along = (mu[a] - mu[b], dv[a] - dv[b]);
                (pair_residual_vjp(model, [a, b], (x, v), along), [0.0; 2])
            })
            .collect_into_vec(&mut self.bars);
        for (&[a, b], bar) in pairs.iter().zip(&self.bars) {
            scatter(model, [a as usize, b as usize], bar, (x_bar, v_bar), grad);
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        self.contact.memory_bytes()
            + vec_bytes(&self.after.0)
            + vec_bytes(&self.after.1)
            + vec_bytes(&self.pairs)
            + vec_bytes(&self.bars)
    }
}

/// Adds pair (a, b)'s cotangents to its particles: the differences' with the forward's signs,
/// W̄ and each particle's own share `own` to the inverse masses (pinned ones keep w = 0), the
/// laws' onto a.
fn scatter(
    model: &Model,
    [a, b]: [usize; 2],
    (bar, own): &(PairBar, [f64; 2]),
    (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
    grad: &mut Gradient,
) {
    x_bar[a] += bar.x;
    x_bar[b] -= bar.x;
    v_bar[a] += bar.v;
    v_bar[b] -= bar.v;
    for (p, own) in [(a, own[0]), (b, own[1])] {
        if model.inv_mass[p] != 0.0 {
            grad.inv_mass[p] += bar.w + own;
        }
    }
    grad.body_friction[a] += bar.friction;
    grad.body_restitution[a] += bar.restitution;
}

/// The cotangent of x_a − x_b for the cotangents `n_bar` of n = (x_a − x_b)/d and `d_bar` of
/// d = |x_a − x_b|.
fn offset_vjp(n: DVec3, d: f64, n_bar: DVec3, d_bar: f64) -> DVec3 {
    unit_vjp(n, d, n_bar) + d_bar * n
}

/// The cotangents of the penalty force P on a of the pair [a, b] (a < b) at (x, v)
/// (the law of [`crate::body_contact`] with κ = [`PENALTY`]) for its cotangent `g`; zero where
/// it does not push.
pub fn penalty_vjp(
    model: &Model,
    [a, b]: [usize; 2],
    (x, v): (&[DVec3], &[DVec3]),
    g: DVec3,
) -> PairBar {
    let Some(p) = penalty_law(model, PENALTY, [a, b], x, v) else {
        return PairBar::default();
    };
    let (n, k, c) = (p.normal, p.stiffness, p.damping);
    let reach = model.contact.radius[a] + model.contact.radius[b];
    let d = (x[a] - x[b]).length();
    let u = v[a] - v[b];
    let m = 1.0 / (model.inv_mass[a] + model.inv_mass[b]);
    let f_bar = n.dot(g);
    let (k_bar, c_bar) = (f_bar * (reach - d), -f_bar * u.dot(n));
    PairBar {
        x: offset_vjp(n, d, p.force * g - f_bar * c * u, -f_bar * k),
        v: -f_bar * c * n,
        w: -m * (k * k_bar + c * c_bar),
        ..PairBar::default()
    }
}

/// The cotangents of the inputs of pair (a, b)'s share of implicit Euler's residual at the
/// step's start (x, v) along m = μ_a − μ_b with the step's δ = Δv_a − Δv_b: the scalar
///
/// φ = (m·n) [h k (R − d) − β n·(u + δ)],  β = h c + h² k,
///
/// ([`crate::integrators::implicit_euler::system`]: the pair's h(F − h k u_n) n in b and its
/// block β nnᵀ) with κ = [`PENALTY_IMPLICIT`], on the branch the step assembled: zero where the
/// penalty did not push at the start, the pair then left out of the system.
pub fn pair_residual_vjp(
    model: &Model,
    [a, b]: [usize; 2],
    (x, v): (&[DVec3], &[DVec3]),
    (m, delta): (DVec3, DVec3),
) -> PairBar {
    let Some(p) = penalty_law(model, PENALTY_IMPLICIT, [a, b], x, v) else {
        return PairBar::default();
    };
    let h = model.simulation.dt;
    let (n, k, c) = (p.normal, p.stiffness, p.damping);
    let reach = model.contact.radius[a] + model.contact.radius[b];
    let d = (x[a] - x[b]).length();
    let q = v[a] - v[b] + delta;
    let beta = h * c + h * h * k;
    let (s, e) = (m.dot(n), n.dot(q));
    let inner = h * k * (reach - d) - beta * e;
    let (k_bar, c_bar) = (s * (h * (reach - d) - h * h * e), -s * h * e);
    PairBar {
        x: offset_vjp(n, d, inner * m - s * beta * q, -s * h * k),
        v: -s * beta * n,
        w: -(k * k_bar + c * c_bar) / (model.inv_mass[a] + model.inv_mass[b]),
        ..PairBar::default()
    }
}

/// The cotangents of the inputs of a pair's response (its impulse P and push Δ per unit of
/// inverse mass, [`crate::body_contact`]) for the cotangents `(p_bar, d_bar)` of P and Δ, on
/// the forward's branches; the start state decides only branches (whether the impact is
/// fresh).
pub fn pair_vjp(
    model: &Model,
    [i, j]: [usize; 2],
    (x, v): (&[DVec3], &[DVec3]),
    start: &State,
    (p_bar, d_bar): (DVec3, DVec3),
) -> PairBar {
    let c = &model.contact;
    let sim = &model.simulation;
    let (h, eps) = (sim.dt, sim.contact_distance);
    let w = model.inv_mass[i] + model.inv_mass[j];
    let reach = c.radius[i] + c.radius[j];
    let offset = x[i] - x[j];
    let d = offset.length();
    let mut bar = PairBar::default();
    if w == 0.0 || d == 0.0 {
        return bar;
    }
    let n = offset / d;
    let (mut n_bar, mut dist_bar) = (DVec3::ZERO, 0.0);
    // Δ = gap/W n.
    let gap = (1.0 - SLOP) * reach - d;
    if gap > 0.0 {
        let size_bar = n.dot(d_bar);
        n_bar += gap / w * d_bar;
        dist_bar -= size_bar / w;
        bar.w -= size_bar * gap / (w * w);
    }
    let u = v[i] - v[j];
    let un = u.dot(n);
    if un < 0.0 {
        let m = 1.0 / w;
        let (k, c_damp) = penalty_coefficients(penalty_kappa(sim.integrator), h, m);
        let overlap = (reach - d).max(0.0);
        let q = k * overlap - c_damp * un;
        let pressed = h * q.max(0.0);
        let laws = &c.laws;
        let u0 = start.v[i] - start.v[j];
        let a_n = (-(u - u0).dot(n) / h).max(0.0);
        let apart = start.x[i].distance(start.x[j]) >= reach;
        let fresh = apart && un * un > 2.0 * a_n * eps;
        let kr = if fresh { laws.restitution } else { 0.0 };
        let jn = (-kr * un - un) / w;
        let ut = u - un * n;
        let slip = ut.length();
        let press = jn + pressed;
        let (mut ut_bar, mut press_bar) = (DVec3::ZERO, 0.0);
        if slip > 0.0 {
            // J_t = −j_t t̂.
            let t = ut / slip;
            let stop = slip / w;
            let mu = laws.friction;
            let (jt, slip_per_jt, press_per_jt, mu_per_jt, w_per_jt) = match laws.friction_model {
                FrictionModel::Coulomb if stop <= mu * press => {
                    (stop, 1.0 / w, 0.0, 0.0, -stop / w)
                }
                FrictionModel::Coulomb => (mu * press, 0.0, mu, press, 0.0),
                FrictionModel::Viscous if mu * press * slip <= stop => {
                    (mu * press * slip, mu * press, mu * slip, press * slip, 0.0)
                }
                FrictionModel::Viscous => (stop, 1.0 / w, 0.0, 0.0, -stop / w),
            };
            let jt_bar = -t.dot(p_bar);
            ut_bar = unit_vjp(t, slip, -jt * p_bar) + jt_bar * slip_per_jt * t;
            press_bar = jt_bar * press_per_jt;
            bar.friction = jt_bar * mu_per_jt;
            bar.w += jt_bar * w_per_jt;
        }
        // P = J_n n + J_t; J = J_n + pressed.
        let jn_bar = n.dot(p_bar) + press_bar;
        n_bar += jn * p_bar;
        // u_t = u − u_n n.
        let mut un_bar = -n.dot(ut_bar);
        n_bar -= un * ut_bar;
        // J_n = (−k_r u_n − u_n)/W.
        un_bar -= (1.0 + kr) * jn_bar / w;
        bar.w -= jn_bar * jn / w;
        if fresh {
            bar.restitution = -un * jn_bar / w;
        }
        // pressed = h·max(0, k·max(0, R − d) − c u_n), k and c linear in m = 1/W.
        if q > 0.0 {
            let q_bar = h * press_bar;
            if reach > d {
                dist_bar -= q_bar * k;
            }
            un_bar -= q_bar * c_damp;
            bar.w -= m * (k * q_bar * overlap - c_damp * q_bar * un);
        }
        // u_n = u·n.
        bar.v = ut_bar + un_bar * n;
        n_bar += un_bar * u;
    }
    bar.x = offset_vjp(n, d, n_bar, dist_bar);
    bar
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use glam::DVec3;
    use softbody_scene::{Model, Scene, State};

    use super::{pair_residual_vjp, pair_vjp, penalty_vjp};
    use crate::body_contact::{PENALTY, PENALTY_IMPLICIT, pair, penalty_law};

    /// Two one-particle bodies of radius 5 cm (R = 0.1 m), 0.5 and 0.7 kg, at h = 1e-3 s.
    fn model(friction_model: &str, friction: f64) -> Model {
        let body = |y: f64, m: f64| {
            format!(
                "[[body]]\nkind = \"particles\"\npositions = [[0.0, {y}, 0.0]]\nmasses = [{m}]\n\
                 contact_radius = 0.05\n"
            )
        };
        let toml = format!(
            "[simulation]\ndt = 1e-3\nduration = 0.01\ncontact_distance = 0.01\n\
             body_restitution = 0.5\nbody_friction = {friction}\n\
             body_friction_model = \"{friction_model}\"\n{}{}",
            body(0.2, 0.5),
            body(0.0, 0.7)
        );
        let scene = Scene::from_toml(&toml, Path::new("pair.toml")).unwrap();
        Model::build(&scene).0
    }

    /// A pair's configuration: its positions and velocities, and where the step started.
    struct At {
        name: &'static str,
        model: Model,
        x: [DVec3; 2],
        v: [DVec3; 2],
        start: State,
    }

    fn at(name: &'static str, model: Model, x: [DVec3; 2], v: [DVec3; 2], apart: bool) -> At {
        // Started the step at the end's relative velocity (no normal acceleration), apart or
        // overlapping.
        let gap = if apart { 0.12 } else { 0.098 };
        let start = State {
            x: vec![x[1] + gap * (x[0] - x[1]).normalize(), x[1]],
            v: v.to_vec(),
        };
        At {
            name,
            model,
            x,
            v,
            start,
        }
    }

    /// A scalar of the pair's law at a model and (x, v).
    type Scalar<'a> = dyn Fn(&Model, &[DVec3], &[DVec3]) -> f64 + 'a;

    /// Central differences (δ = 1e-6) of `s` along particle a's position and velocity (each
    /// axis), w_a, μ and k_r, against `bar`'s cotangents of x_a − x_b, v_a − v_b, W, μ, k_r:
    /// each law is smooth on its branch, which the moves are far from leaving, so differences
    /// agree to ~1e-9 of the scale.
    fn check(at: &At, bar: super::PairBar, s: &Scalar<'_>) {
        let e = 1e-6;
        let diff = |f: &dyn Fn(f64) -> f64| (f(e) - f(-e)) / (2.0 * e);
        let close = |what: &str, adjoint: f64, fd: f64| {
            assert!(
                (adjoint - fd).abs() < 1e-7 * fd.abs().max(1.0),
                "{}: {what}: adjoint {adjoint:e}, differences {fd:e}",
                at.name
            );
        };
        for axis in 0..3 {
            let unit = DVec3::AXES[axis];
            let fd = diff(&|t| {
                let x = [at.x[0] + t * unit, at.x[1]];
                s(&at.model, &x, &at.v)
            });
            close("x", bar.x[axis], fd);
            let fd = diff(&|t| {
                let v = [at.v[0] + t * unit, at.v[1]];
                s(&at.model, &at.x, &v)
            });
            close("v", bar.v[axis], fd);
        }
        let moved = |change: &dyn Fn(&mut Model, f64)| {
            diff(&|t| {
                let mut m = at.model.clone();
                change(&mut m, t);
                s(&m, &at.x, &at.v)
            })
        };
        close("w", bar.w, moved(&|m, t| m.inv_mass[0] += t));
        let fd = moved(&|m, t| m.contact.laws.friction += t);
        close("friction", bar.friction, fd);
        let fd = moved(&|m, t| m.contact.laws.restitution += t);
        close("restitution", bar.restitution, fd);
    }

    /// The pair response's cotangents against differences of its P̄·P + Δ̄·Δ, on every branch:
    /// fresh impacts pushed apart, kinetic and static; an approach that is not fresh, with
    /// viscous friction under and at its cap; a pair moving apart, pushed only.
    #[test]
    fn the_pair_responses_derivatives_are_its_differences() {
        let (p_bar, d_bar) = (DVec3::new(0.3, -1.1, 0.7), DVec3::new(-0.5, 0.2, 0.9));
        let deep = [DVec3::new(0.01, 0.085, 0.005), DVec3::ZERO];
        let shallow = [
            DVec3::new(0.01, 0.0945, -0.004),
            DVec3::new(0.0, 0.0, 0.002),
        ];
        let falling = [DVec3::new(0.8, -3.0, 0.2), DVec3::new(0.0, 0.1, 0.0)];
        let pressing = [DVec3::new(0.3, -0.2, 0.1), DVec3::new(0.0, 0.0, -0.05)];
        let cases = [
            at("kinetic", model("coulomb", 0.1), deep, falling, true),
            at("static", model("coulomb", 0.6), deep, falling, true),
            at("viscous", model("viscous", 0.3), shallow, pressing, false),
            at(
                "viscous, capped",
                model("viscous", 3.0),
                shallow,
                pressing,
                false,
            ),
            at(
                "moving apart",
                model("coulomb", 0.3),
                deep,
                [DVec3::Y, DVec3::ZERO],
                true,
            ),
        ];
        for at in &cases {
            let (x, v) = (&at.x[..], &at.v[..]);
            let bar = pair_vjp(&at.model, [0, 1], (x, v), &at.start, (p_bar, d_bar));
            check(at, bar, &|m, x, v| {
                let (p, d) = pair(m, [0, 1], (x, v), &at.start);
                p_bar.dot(p) + d_bar.dot(d)
            });
        }
        // The branches are the ones named: the first impacts are fresh, the viscous pair's not.
        assert!(cases[0].start.x[0].distance(cases[0].start.x[1]) >= 0.1);
        assert!(cases[2].start.x[0].distance(cases[2].start.x[1]) < 0.1);
    }

    /// The penalty's cotangents against differences of ḡ·P, approaching and moving apart (the
    /// damping against the spring, F still positive).
    #[test]
    fn the_penaltys_derivatives_are_its_differences() {
        let g = DVec3::new(0.3, -1.1, 0.7);
        let x = [
            DVec3::new(0.01, 0.0945, -0.004),
            DVec3::new(0.0, 0.0, 0.002),
        ];
        for (name, va) in [
            ("approaching", DVec3::new(0.3, -0.2, 0.1)),
            ("moving apart", DVec3::new(0.3, 0.1, 0.1)),
        ] {
            let at = at(name, model("coulomb", 0.3), x, [va, DVec3::ZERO], false);
            let (x, v) = (&at.x[..], &at.v[..]);
            assert!(penalty_law(&at.model, PENALTY, [0, 1], x, v).is_some());
            let bar = penalty_vjp(&at.model, [0, 1], (x, v), g);
            check(&at, bar, &|m, x, v| {
                penalty_law(m, PENALTY, [0, 1], x, v).map_or(0.0, |p| p.force * p.normal.dot(g))
            });
        }
    }

    /// Implicit Euler's pair residual's cotangents against differences of φ written out from
    /// the system's assembly (the pair's h(F − h k u_n) n in b, its block β nnᵀ), pressing and
    /// moving apart with the penalty still pushing.
    #[test]
    fn the_pair_residuals_derivatives_are_its_differences() {
        let (m, delta) = (DVec3::new(0.3, -1.1, 0.7), DVec3::new(0.02, -0.05, 0.01));
        let x = [
            DVec3::new(0.01, 0.0945, -0.004),
            DVec3::new(0.0, 0.0, 0.002),
        ];
        for (name, va) in [
            ("approaching", DVec3::new(0.3, -0.2, 0.1)),
            ("moving apart", DVec3::new(0.3, 0.002, 0.1)),
        ] {
            let at = at(name, model("coulomb", 0.3), x, [va, DVec3::ZERO], false);
            let (x, v) = (&at.x[..], &at.v[..]);
            assert!(penalty_law(&at.model, PENALTY_IMPLICIT, [0, 1], x, v).is_some());
            let bar = pair_residual_vjp(&at.model, [0, 1], (x, v), (m, delta));
            check(&at, bar, &|model, x, v| {
                let h = model.simulation.dt;
                penalty_law(model, PENALTY_IMPLICIT, [0, 1], x, v).map_or(0.0, |p| {
                    let (n, k) = (p.normal, p.stiffness);
                    let un = (v[0] - v[1]).dot(n);
                    let beta = h * p.damping + h * h * k;
                    m.dot(h * (p.force - h * k * un) * n - beta * n.dot(delta) * n)
                })
            });
        }
    }
}
