//! The adjoint of [`crate::forces`]: given the cotangent ā of every particle's acceleration
//! a(x, v), adds āᵀ ∂a/∂(x, v) to (x̄, v̄) and āᵀ ∂a/∂θ to the gradient of the model's values θ.
//!
//! Reverse through a = w (f + f_c), f = m g − drag·m v + Σ springs (pinned: a = 0, nothing):
//!
//! - F̄ = w ā, w̄ += ā·(f + f_c);
//! - f̄ = F̄ + (∂f_c/∂f)ᵀ F̄ and (x̄, v̄, m̄, μ̄) from the contact law ([`contact_vjp`]);
//! - m̄ += f̄·(g − drag·v), ḡ += m f̄, drag̅ −= m v·f̄, v̄ −= drag·m f̄; each spring sum S_i gets
//!   S̄_i = f̄_i;
//! - spring s = (a, b): its force f_a = −s_f u, s_f = k_s(ℓ − r) + k_d (w·u), d = x_a − x_b,
//!   ℓ = |d|, u = d/ℓ, w = v_a − v_b, enters S_a with + and S_b with −, so its cotangent is
//!   ḡ = S̄_a − S̄_b and ([`spring_vjp`]) s̄ = −u·ḡ, ū = −s_f ḡ + s̄ k_d w,
//!   k̄_s = s̄(ℓ − r), k̄_d = s̄ (w·u), w̄ = s̄ k_d u, d̄ = ((ū − u(u·ū))/ℓ) + s̄ k_s u; then
//!   x̄_a += d̄, x̄_b −= d̄, v̄_a += w̄, v̄_b −= w̄ — the same signed gather as the forward's.
//!
//! Every array is written per particle or per spring by one task, in a fixed order: the same
//! bits for any thread count.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{FrictionModel, Model};
use softbody_terrain::Surface;

use super::Gradient;
use crate::body_contact::{PairForces, Partners};
use crate::contact::contact_force;
use crate::forces::{PARTICLE_CHUNK, acceleration_with};
use crate::spring_forces;

/// One evaluation of the accelerations a(x, v), kept for its transpose: each spring's force
/// and each particle's sum of them.
#[derive(Debug, Clone)]
pub struct Stage {
    per_spring: Vec<DVec3>,
    sums: Vec<DVec3>,
}

impl Stage {
    /// Sized for `model`.
    pub fn new(model: &Model) -> Stage {
        Stage {
            per_spring: vec![DVec3::ZERO; model.springs().len()],
            sums: vec![DVec3::ZERO; model.len()],
        }
    }

    /// Writes a(x, v) of every particle into `a`, as the explicit stages do (the same
    /// functions), keeping the springs' forces and each particle's sum of them, of the penalty
    /// forces between the `partners` and of its `external` force (whose cotangents are then the
    /// sum's, [`Scratch::sum_bar`]).
    pub fn evaluate(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        (x, v): (&[DVec3], &[DVec3]),
        (partners, external): (Option<&Partners>, Option<&[DVec3]>),
        a: &mut [DVec3],
    ) {
        spring_forces::compute(model.springs(), x, v, &mut self.per_spring);
        let (adjacency, per_spring) = (model.adjacency(), &self.per_spring);
        self.sums
            .par_iter_mut()
            .zip(a.par_iter_mut())
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (sum, a))| {
                // springs + (pairs + external), the stages' order.
                let mut besides = partners.map_or(DVec3::ZERO, |p| p.force(model, i, x, v));
                if let Some(external) = external {
                    besides += external[i];
                }
                *sum = spring_forces::gather(adjacency, per_spring, i) + besides;
                *a = if model.inv_mass[i] == 0.0 {
                    DVec3::ZERO
                } else {
                    acceleration_with(model, surfaces, i, x[i], v[i], *sum)
                };
            });
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        crate::vec_bytes(&self.per_spring) + crate::vec_bytes(&self.sums)
    }
}

/// Scratch of [`accelerations_vjp`], sized for one model.
#[derive(Debug, Clone)]
pub struct Scratch {
    /// S̄_i, the cotangent of each particle's spring sum.
    sum_bar: Vec<DVec3>,
    d_bar: Vec<DVec3>,
    w_bar: Vec<DVec3>,
}

impl Scratch {
    /// Sized for `model`.
    pub fn new(model: &Model) -> Scratch {
        let (n, s) = (model.len(), model.springs().len());
        Scratch {
            sum_bar: vec![DVec3::ZERO; n],
            d_bar: vec![DVec3::ZERO; s],
            w_bar: vec![DVec3::ZERO; s],
        }
    }

    /// S̄_i of the last [`accelerations_vjp`]: the cotangent of each particle's sum of spring,
    /// penalty and external forces, and so of its penalty and external forces (0 where pinned).
    pub fn sum_bar(&self) -> &[DVec3] {
        &self.sum_bar
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        [&self.sum_bar, &self.d_bar, &self.w_bar]
            .into_iter()
            .map(crate::vec_bytes)
            .sum()
    }
}

/// Adds āᵀ ∂a/∂x to `x_bar`, āᵀ ∂a/∂v to `v_bar` and āᵀ ∂a/∂θ to `grad`, for the
/// accelerations `stage` evaluated at (x, v).
#[allow(clippy::too_many_arguments)]
pub fn accelerations_vjp(
    model: &Model,
    surfaces: &[Surface],
    (x, v): (&[DVec3], &[DVec3]),
    stage: &Stage,
    a_bar: &[DVec3],
    scratch: &mut Scratch,
    (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
    grad: &mut Gradient,
) {
    let springs = model.springs();
    let sim = &model.simulation;
    let (eps, h) = (sim.contact_distance, sim.dt);
    let ns = surfaces.len();
    let sums = &stage.sums;

    // Per particle: everything but the springs' own parameters and ends.
    let per_particle = scratch
        .sum_bar
        .par_iter_mut()
        .zip(x_bar.par_iter_mut().zip(v_bar.par_iter_mut()))
        .zip(grad.mass.par_iter_mut().zip(grad.inv_mass.par_iter_mut()))
        .zip(grad.gravity.par_iter_mut().zip(grad.drag.par_iter_mut()))
        .zip(grad.friction.par_chunks_mut(ns.max(1)))
        .enumerate()
        .with_min_len(PARTICLE_CHUNK);
    per_particle.for_each(
        |(i, ((((sum_bar, (xb, vb)), (mb, wb)), (gb, db)), mu_bar))| {
            let (m, w) = (model.mass[i], model.inv_mass[i]);
            if w == 0.0 {
                *sum_bar = DVec3::ZERO;
                return;
            }
            let f = m * sim.gravity - sim.drag * m * v[i] + sums[i];
            let touching = !surfaces.iter().all(|s| s.clear_of(x[i], eps));
            let fc = if touching {
                contact_force(surfaces, eps, h, m, x[i], v[i], f)
            } else {
                DVec3::ZERO
            };
            let big_f = w * a_bar[i];
            *wb += a_bar[i].dot(f + fc);
            let c = if touching {
                contact_vjp(surfaces, eps, h, m, x[i], v[i], f, big_f, mu_bar)
            } else {
                ContactBar::default()
            };
            let f_bar = big_f + c.f;
            *xb += c.x;
            *vb += c.v - sim.drag * m * f_bar;
            *mb += c.m + f_bar.dot(sim.gravity - sim.drag * v[i]);
            *gb += m * f_bar;
            *db -= m * v[i].dot(f_bar);
            *sum_bar = f_bar;
        },
    );

    let sum_bar = &scratch.sum_bar;
    let (d_bar, w_bar) = (&mut scratch.d_bar, &mut scratch.w_bar);
    springs_transpose(model, (d_bar, w_bar), grad, (x_bar, v_bar), |s, a, b| {
        spring_vjp(
            (x[a], x[b]),
            (v[a], v[b]),
            springs.rest[s],
            springs.stiffness[s],
            springs.damping[s],
            sum_bar[a] - sum_bar[b],
        )
    });
}

/// The springs' share of a transpose: `bar(s, a, b)`, the cotangents of spring s = (a, b), for
/// every spring, a chunk of springs per task; the cotangents of d and w kept per spring in
/// `d_bar`, `w_bar` and those of k_s and k_d added to `grad`; then each particle's x̄ and v̄
/// gather d̄ and w̄ with the forward's signs (x̄_a += d̄, x̄_b −= d̄), in a fixed order.
pub(crate) fn springs_transpose(
    model: &Model,
    (d_bar, w_bar): (&mut [DVec3], &mut [DVec3]),
    grad: &mut Gradient,
    (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
    bar: impl Fn(usize, usize, usize) -> SpringBar + Sync,
) {
    let springs = model.springs();
    const CHUNK: usize = 4096;
    d_bar
        .par_chunks_mut(CHUNK)
        .zip(w_bar.par_chunks_mut(CHUNK))
        .zip(grad.stiffness.par_chunks_mut(CHUNK))
        .zip(grad.damping.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(c, (((d_bar, w_bar), kb), cb))| {
            let n = d_bar.len();
            let (w_bar, kb, cb) = (&mut w_bar[..n], &mut kb[..n], &mut cb[..n]);
            let (ea, eb) = (&springs.a[c * CHUNK..][..n], &springs.b[c * CHUNK..][..n]);
            for j in 0..n {
                let bar = bar(c * CHUNK + j, ea[j] as usize, eb[j] as usize);
                (d_bar[j], w_bar[j]) = (bar.d, bar.w);
                kb[j] += bar.stiffness;
                cb[j] += bar.damping;
            }
        });
    let (adjacency, d_bar, w_bar) = (model.adjacency(), &*d_bar, &*w_bar);
    x_bar
        .par_iter_mut()
        .zip(v_bar.par_iter_mut())
        .enumerate()
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(i, (xb, vb))| {
            *xb += spring_forces::gather(adjacency, d_bar, i);
            *vb += spring_forces::gather(adjacency, w_bar, i);
        });
}

/// The cotangents of one spring's inputs ([`spring_vjp`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpringBar {
    /// Of d = x_a − x_b.
    pub d: DVec3,
    /// Of w = v_a − v_b.
    pub w: DVec3,
    /// Of k_s.
    pub stiffness: f64,
    /// Of k_d.
    pub damping: f64,
}

/// The cotangents of [`spring_forces::spring_force`]'s inputs for the cotangent `g` of f_a.
///
/// Inlined into the per-spring loop, with one division (as the forward's): the result
/// returned through memory and six divisions took half the loop's time.
#[inline(always)]
pub fn spring_vjp(
    (xa, xb): (DVec3, DVec3),
    (va, vb): (DVec3, DVec3),
    rest: f64,
    ks: f64,
    kd: f64,
    g: DVec3,
) -> SpringBar {
    let d = xa - xb;
    let len = d.length();
    if len == 0.0 {
        return SpringBar {
            d: DVec3::ZERO,
            w: DVec3::ZERO,
            stiffness: 0.0,
            damping: 0.0,
        };
    }
    let inv = 1.0 / len;
    let u = d * inv;
    let w = va - vb;
    let wu = w.dot(u);
    let sf = ks * (len - rest) + kd * wu;
    let s_bar = -u.dot(g);
    let u_bar = -sf * g + s_bar * kd * w;
    SpringBar {
        d: (u_bar - u * u.dot(u_bar)) * inv + s_bar * ks * u,
        w: s_bar * kd * u,
        stiffness: s_bar * (len - rest),
        damping: s_bar * wu,
    }
}

/// The cotangents of [`contact_force`]'s inputs ([`contact_vjp`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactBar {
    /// Of the applied force f.
    pub f: DVec3,
    /// Of the position.
    pub x: DVec3,
    /// Of the velocity.
    pub v: DVec3,
    /// Of the mass (through the stopping force m/h).
    pub m: f64,
}

/// The cotangents of [`contact_force`]'s inputs for the cotangent `fc_bar` of its result; each
/// surface's friction coefficient's cotangent is added to `mu_bar` (one per surface). The
/// branches are the forward's: which surfaces touch, stick or slip, and which caps hold.
#[allow(clippy::too_many_arguments)]
pub fn contact_vjp(
    surfaces: &[Surface],
    eps: f64,
    h: f64,
    m: f64,
    x: DVec3,
    v: DVec3,
    f: DVec3,
    fc_bar: DVec3,
    mu_bar: &mut [f64],
) -> ContactBar {
    let mut bar = ContactBar::default();
    if surfaces.iter().all(|s| s.clear_of(x, eps)) {
        return bar;
    }
    for (k, s) in surfaces.iter().enumerate() {
        let Some(c) = s.query(x, eps) else { continue };
        let n = c.normal;
        let fn_dot = n.dot(f);
        if fn_dot >= 0.0 {
            continue;
        }
        let press = -fn_dot;
        let vt = v - v.dot(n) * n;
        let ft = f - fn_dot * n;
        let fr = friction_vjp(s.friction_model, s.friction, press, h, m, vt, ft, fc_bar);
        mu_bar[k] += fr.mu;
        bar.m += fr.m;
        // total += press n + friction(press, vt, ft).
        let press_bar = n.dot(fc_bar) + fr.press;
        let mut n_bar = press * fc_bar;
        // vt = v − (v·n) n.
        bar.v += fr.vt - n * n.dot(fr.vt);
        n_bar -= v.dot(n) * fr.vt + n.dot(fr.vt) * v;
        // ft = f − (n·f) n.
        bar.f += fr.ft - n * n.dot(fr.ft);
        n_bar -= fn_dot * fr.ft + n.dot(fr.ft) * f;
        // press = −n·f.
        bar.f -= press_bar * n;
        n_bar -= press_bar * f;
        bar.x += s.normal_jacobian(x).transpose() * n_bar;
    }
    bar
}

/// The cotangents of [`crate::contact::friction`]'s inputs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrictionBar {
    /// Of μ (or k_f).
    pub mu: f64,
    /// Of the press f_n.
    pub press: f64,
    /// Of the mass.
    pub m: f64,
    /// Of the slip v_t.
    pub vt: DVec3,
    /// Of the tangential applied force f_t.
    pub ft: DVec3,
}

/// The cotangents of [`crate::contact::friction`]'s inputs for the cotangent `bar` of its
/// result, on the branch the forward takes.
#[allow(clippy::too_many_arguments)]
pub fn friction_vjp(
    model: FrictionModel,
    mu: f64,
    press: f64,
    h: f64,
    m: f64,
    vt: DVec3,
    ft: DVec3,
    bar: DVec3,
) -> FrictionBar {
    let stop = m / h;
    let mut out = FrictionBar::default();
    match model {
        FrictionModel::Coulomb => {
            let limit = mu * press;
            let speed = vt.length();
            if stop * speed > limit {
                // −limit·t̂, t̂ = vt/|vt|.
                let t = vt / speed;
                let limit_bar = -t.dot(bar);
                out.mu = press * limit_bar;
                out.press = mu * limit_bar;
                out.vt = unit_vjp(t, speed, -limit * bar);
            } else {
                // g = −ft − stop·vt, capped at the limit.
                let g = -ft - stop * vt;
                let (g_bar, limit_bar) = clamp_vjp(g, limit, bar);
                out.mu = press * limit_bar;
                out.press = mu * limit_bar;
                out.ft = -g_bar;
                out.vt = -stop * g_bar;
                out.m = -vt.dot(g_bar) / h;
            }
        }
        FrictionModel::Viscous => {
            // g = −μ·press·vt, capped at stop·|vt|.
            let g = -mu * press * vt;
            let speed = vt.length();
            let (g_bar, cap_bar) = clamp_vjp(g, stop * speed, bar);
            if cap_bar != 0.0 {
                out.m = cap_bar * speed / h;
                out.vt = cap_bar * stop * vt / speed;
            }
            out.mu = -press * vt.dot(g_bar);
            out.press = -mu * vt.dot(g_bar);
            out.vt += -mu * press * g_bar;
        }
    }
    out
}

/// The cotangents (of g, of the limit) of `g.clamp_length_max(limit)` for the cotangent `bar`.
fn clamp_vjp(g: DVec3, limit: f64, bar: DVec3) -> (DVec3, f64) {
    let len_sq = g.length_squared();
    if len_sq > limit * limit {
        // limit·ĝ.
        let len = len_sq.sqrt();
        let unit = g / len;
        (unit_vjp(unit, len, limit * bar), unit.dot(bar))
    } else {
        (bar, 0.0)
    }
}

/// The cotangent of s for the cotangent `bar` of ŝ = s/|s| (ŝ = `unit`, |s| = `len`).
#[inline]
pub(crate) fn unit_vjp(unit: DVec3, len: f64, bar: DVec3) -> DVec3 {
    (bar - unit * unit.dot(bar)) / len
}
