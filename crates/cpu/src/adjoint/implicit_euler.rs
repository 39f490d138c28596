//! The transpose of one implicit Euler step, twin of [`crate::integrators::implicit_euler`].
//!
//! The step solves A Δv = b with A = M(1 + h·drag) + Σ_s B_s and b = h(m g − drag·m v +
//! Σ± (f_s − h K_s w_s)), Δv prescribed (−v) on pinned particles; then v' = v + Δv,
//! x' = x + h v'. With the cotangent (x̄', v̄') of the state after it:
//!
//! - ṽ = v̄' + h x̄' is the cotangent of v' and so of Δv; x̄ = x̄', v̄ = ṽ;
//! - μ solves the transposed system, A being symmetric the same one, A_ff μ_f = ṽ_f on the
//!   free particles (μ = 0 on the pinned ones), by the forward's preconditioned CG;
//! - a pinned particle's prescribed Δv = −v hands v̄ −= ṽ − (A μ) back;
//! - everything A and b depend on takes μᵀ ∂r/∂(x, v, θ) for the residual r = b − A Δv at the
//!   step's Δv (held fixed): per particle r_i ∋ h m_i (g − drag·v_i) − m_i(1 + h·drag) Δv_i,
//!   and per spring s = (a, b), with m = μ_a − μ_b, δ = Δv_a − Δv_b, q = w + δ (the new
//!   relative velocity), the scalar ([`spring_residual_vjp`])
//!
//!   φ_s = mᵀ(h f_s − h² K_s q − h k_d u uᵀ δ),  K_s = k_s[(1 − α) uuᵀ + α I],
//!   α = max(0, 1 − r/ℓ),
//!
//!   whose derivatives in d = x_a − x_b, w, k_s and k_d go to the springs' ends with the
//!   forward's signs. Where α is clamped at 0 (a compressed spring) its derivative is 0, the
//!   branch the forward took.
//!
//! In contact with the terrain, the step's final solve holds its active set: a slipping contact
//! on N with target t solves A Δv − b − λ_n (N + c) = 0, N·(v + Δv) = t (its friction impulse
//! λ_n c, c ⊥ N), a sticking one A Δv − b − λ = 0, v + Δv = t N. Then μ also satisfies μ = 0 on
//! sticking contacts and μ·(N + c) = 0 on slipping ones (μ's normal part prescribed from its
//! tangential one, solved again until it settles), ν = ṽ − A μ is each constraint's multiplier,
//! and the constraints' targets, normals and friction take their cotangents from ν, λ_n and μ
//! (docs/physics.md, "Gradients: the discrete adjoint").
//!
//! The forward's CG stops at the scene's relative residual τ (`simulation.cg_tolerance`): its
//! Δv, and so the run, is the exact step's to O(τ), and this transpose, solved to the same τ,
//! is the exact step's, which the computed run's derivative matches to the same order.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::implicit::Constraint;
use softbody_scene::{FrictionModel, Model, State};
use softbody_terrain::Surface;

use super::Gradient;
use super::body_contact::BodyAdjoint;
use super::forces::springs_transpose;
use crate::forces::PARTICLE_CHUNK;
use crate::integrators::implicit_euler::cg::{self, CgProblem, Preconditioner};
use crate::integrators::implicit_euler::multigrid::Multigrid;
use crate::integrators::implicit_euler::system::System;
use crate::integrators::implicit_euler::{Candidate, Mode};
use crate::vec_bytes;

/// The transpose of one implicit Euler step and its scratch, sized for one model.
#[derive(Debug)]
pub struct ImplicitAdjoint {
    system: System,
    multigrid: Option<Multigrid>,
    scratch: cg::Scratch,
    constraints: Vec<Constraint>,
    /// The step's Δv = v' − v.
    dv: Vec<DVec3>,
    /// ṽ, the cotangent of Δv.
    dv_bar: Vec<DVec3>,
    /// A μ.
    a_mu: Vec<DVec3>,
    /// μ, warm started from the last step's.
    mu: Vec<DVec3>,
    /// The step's b, and μ's prescribed part (its normal part where a contact slips).
    b: Vec<DVec3>,
    z: Vec<DVec3>,
    /// The step's contacts as the transpose holds them.
    held: Vec<Held>,
    /// Each spring's cotangents of d and w.
    d_bar: Vec<DVec3>,
    w_bar: Vec<DVec3>,
    /// The pairs of bodies of the step (its system's and its response's), when bodies can
    /// touch.
    bodies: Option<BodyAdjoint>,
}

impl ImplicitAdjoint {
    /// Sized for `model`, with the preconditioner its scene names.
    pub fn new(model: &Model) -> ImplicitAdjoint {
        let n = model.len();
        let s = model.springs().len();
        let system = System::new(model);
        let multigrid = match model.simulation.preconditioner {
            softbody_scene::Preconditioner::Multigrid => Multigrid::new(model, &system),
            softbody_scene::Preconditioner::BlockJacobi => None,
        };
        let constraints = (0..n)
            .map(|i| match model.is_pinned(i) {
                true => Constraint::Fixed,
                false => Constraint::Free,
            })
            .collect();
        ImplicitAdjoint {
            system,
            multigrid,
            scratch: cg::Scratch::new(n),
            constraints,
            dv: vec![DVec3::ZERO; n],
            dv_bar: vec![DVec3::ZERO; n],
            a_mu: vec![DVec3::ZERO; n],
            mu: vec![DVec3::ZERO; n],
            b: vec![DVec3::ZERO; n],
            z: vec![DVec3::ZERO; n],
            held: Vec::new(),
            d_bar: vec![DVec3::ZERO; s],
            w_bar: vec![DVec3::ZERO; s],
            bodies: model.contact.enabled().then(|| BodyAdjoint::new(model)),
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        self.system.memory_bytes()
            + self.multigrid.as_ref().map_or(0, Multigrid::memory_bytes)
            + self.scratch.memory_bytes()
            + vec_bytes(&self.constraints)
            + vec_bytes(&self.held)
            + self.bodies.as_ref().map_or(0, BodyAdjoint::memory_bytes)
            + [
                &self.dv,
                &self.dv_bar,
                &self.a_mu,
                &self.mu,
                &self.b,
                &self.z,
                &self.d_bar,
                &self.w_bar,
            ]
            .into_iter()
            .map(vec_bytes)
            .sum::<u64>()
    }

    /// Turns `(x_bar, v_bar)`, the cotangent of `end`, the state after the step from `start`,
    /// into the cotangent of `start`, adding the model's values' to `grad`; `recorded` is what
    /// the forward's step held besides the states ([`Recorded`]), its contacts on `surfaces`;
    /// with `external` forces on the particles in the step (which enter b as h f_ext, so their
    /// cotangent is h μ), their cotangents are added to the second of the pair.
    ///
    /// Where bodies can touch, the step ends with their pair response
    /// ([`crate::body_contact`]), whose transpose comes first, from the state before it (the
    /// step's own update of `start` by the recorded Δv), and the pairs in contact at the start
    /// are springs of the system ([`BodyAdjoint::implicit_vjp`]).
    pub(crate) fn step(
        &mut self,
        model: &Model,
        (start, end): (&State, &State),
        (surfaces, recorded): (&[Surface], &Recorded),
        external: Option<(&[DVec3], &mut [DVec3])>,
        (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
        grad: &mut Gradient,
    ) {
        let sim = &model.simulation;
        let h = sim.dt;
        let (x, v) = (&start.x[..], &start.v[..]);
        if let Some(bodies) = self.bodies.as_mut() {
            bodies.prepare(model, start);
            bodies.implicit_forward(model, start, &recorded.dv);
            bodies.respond_vjp(model, start, (&mut *x_bar, &mut *v_bar), grad);
        }
        let forces = external.as_ref().map(|(f, _)| *f);
        let partners = self.bodies.as_ref().map(BodyAdjoint::partners);
        (self.system).assemble(model, (partners, forces), x, v, &mut self.b);
        let held_dv = (!recorded.dv.is_empty()).then_some(&recorded.dv[..]);
        (&mut self.dv, &mut self.dv_bar, &mut *v_bar)
            .into_par_iter()
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (dv, vt, vb))| {
                *dv = held_dv.map_or(end.v[i] - v[i], |held| held[i]);
                *vt = *vb + h * x_bar[i];
                *vb = *vt;
            });
        let contacts = &recorded.contacts[..];
        for c in &self.held {
            self.constraints[c.particle as usize] = Constraint::Free;
            self.z[c.particle as usize] = DVec3::ZERO;
        }
        self.held.clear();
        if !contacts.is_empty() {
            self.system.apply(model, &self.dv, &mut self.a_mu);
        }
        for c in contacts {
            let i = c.particle as usize;
            let s = &surfaces[c.surface as usize];
            let n = c.normal;
            let lambda_n = n.dot(self.a_mu[i] - self.b[i]);
            let vt = v[i] - v[i].dot(n) * n;
            // The friction impulse j = λ_n c (c ⊥ n), or a constant where the viscous cap holds.
            let (friction, capped) = match (c.mode, s.friction_model) {
                (Mode::Slip, FrictionModel::Coulomb) => (s.friction * c.friction_dir, false),
                (Mode::Slip, FrictionModel::Viscous) => {
                    let capped =
                        s.friction * c.lambda_n * vt.length() > model.mass[i] * vt.length();
                    (
                        if capped {
                            DVec3::ZERO
                        } else {
                            -s.friction * vt
                        },
                        capped,
                    )
                }
                _ => (DVec3::ZERO, false),
            };
            self.constraints[i] = match c.mode {
                Mode::Slip => Constraint::Normal(n),
                _ => Constraint::Fixed,
            };
            self.held.push(Held {
                particle: c.particle,
                lambda_n,
                friction,
                capped,
            });
        }
        // μ solves the transpose with the friction's coupling: S(A μ − ṽ) = 0, μ = 0 where
        // the contact sticks and μ·(N + c) = 0 where it slips, the normal part prescribed
        // from the tangential one, round by round until it settles.
        for round in 0..=ADJOINT_ROUNDS {
            let mut moved = 0.0f64;
            let mut size = 0.0f64;
            for c in &self.held {
                let i = c.particle as usize;
                let z = match self.constraints[i] {
                    Constraint::Normal(n) => -c.friction.dot(self.mu[i]) * n,
                    _ => DVec3::ZERO,
                };
                moved = moved.max((z - self.z[i]).length());
                size = size.max(z.length());
                self.z[i] = z;
            }
            if round > 0 && moved <= 1e-12 * size {
                break;
            }
            CgProblem {
                preconditioner: match self.multigrid.as_mut() {
                    Some(mg) => Preconditioner::Multigrid(mg),
                    None => Preconditioner::BlockJacobi,
                },
                tolerance: model.simulation.cg_tolerance,
                ..CgProblem::new(
                    &mut self.system,
                    model,
                    &self.constraints,
                    &self.dv_bar,
                    &self.z,
                )
            }
            .solve(&mut self.mu, &mut self.scratch);
            if self.held.iter().all(|c| c.friction == DVec3::ZERO) {
                break;
            }
        }

        // Constrained particles: ν = ṽ − A μ, the multipliers of their velocity constraints.
        if self.constraints.iter().any(|s| *s != Constraint::Free) {
            self.system.apply(model, &self.mu, &mut self.a_mu);
            for (i, s) in self.constraints.iter().enumerate() {
                if *s == Constraint::Fixed && model.is_pinned(i) {
                    v_bar[i] -= self.dv_bar[i] - self.a_mu[i];
                }
            }
        }
        for (c, held) in contacts.iter().zip(&self.held) {
            let i = c.particle as usize;
            let k = c.surface as usize;
            let s = &surfaces[k];
            let n = c.normal;
            let nu = self.dv_bar[i] - self.a_mu[i];
            let (mu, at) = (self.mu[i], k + i * grad.surfaces);
            let vn = v[i].dot(n);
            let vt = v[i] - vn * n;
            let (mut n_bar, mut vt_bar, t_bar);
            match c.mode {
                // v + Δv = t N.
                Mode::Stick => {
                    v_bar[i] -= nu;
                    t_bar = nu.dot(n);
                    n_bar = c.vn_target * nu;
                    vt_bar = DVec3::ZERO;
                }
                // N·(v + Δv) = t, and A Δv − b − λ_n (N + c) = 0.
                _ => {
                    let nu = n.dot(nu);
                    v_bar[i] -= nu * n;
                    t_bar = nu;
                    n_bar = held.lambda_n * mu - nu * (v[i] + self.dv[i]);
                    vt_bar = DVec3::ZERO;
                    match s.friction_model {
                        FrictionModel::Coulomb => {
                            grad.friction[at] += held.lambda_n * mu.dot(c.friction_dir);
                            let speed = vt.length();
                            if !c.held_direction() && speed > 0.0 {
                                // d = −v_t/|v_t|.
                                let d = c.friction_dir;
                                let d_bar = s.friction * held.lambda_n * mu;
                                vt_bar = -(d_bar - d * d.dot(d_bar)) / speed;
                            }
                        }
                        FrictionModel::Viscous if held.capped => {
                            // j = −m v_t.
                            grad.mass[i] -= mu.dot(vt);
                            vt_bar = -model.mass[i] * mu;
                        }
                        FrictionModel::Viscous => {
                            grad.friction[at] -= held.lambda_n * mu.dot(vt);
                            vt_bar = -s.friction * held.lambda_n * mu;
                        }
                    }
                }
            }
            // t = −φ/h, or on a fresh impact max(−φ/h, k_r max(−v·N, 0)).
            let rebound = s.restitution * (-vn).max(0.0);
            let mut phi_bar = 0.0;
            if c.fresh && rebound > -c.phi / h {
                grad.restitution[at] += t_bar * (-vn).max(0.0);
                if vn < 0.0 {
                    v_bar[i] -= t_bar * s.restitution * n;
                    n_bar -= t_bar * s.restitution * v[i];
                }
            } else {
                phi_bar = -t_bar / h;
            }
            // v_t = v − (v·N) N.
            v_bar[i] += vt_bar - n * n.dot(vt_bar);
            n_bar -= n.dot(vt_bar) * v[i] + vn * vt_bar;
            // ∇φ = N, ∂N/∂x = J.
            x_bar[i] += phi_bar * n + s.normal_jacobian(x[i]).transpose() * n_bar;
        }

        if let Some((_, bar)) = external {
            for (b, mu) in bar.iter_mut().zip(&self.mu) {
                *b += h * *mu;
            }
        }

        // Per particle: mass, gravity, drag.
        let (mu, dv) = (&self.mu, &self.dv);
        v_bar
            .par_iter_mut()
            .zip(grad.mass.par_iter_mut())
            .zip(grad.gravity.par_iter_mut().zip(grad.drag.par_iter_mut()))
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, ((vb, mb), (gb, db)))| {
                let m = model.mass[i];
                let mu = mu[i];
                *mb += mu.dot(h * sim.gravity - h * sim.drag * v[i] - (1.0 + h * sim.drag) * dv[i]);
                *gb += h * m * mu;
                *db -= h * m * mu.dot(v[i] + dv[i]);
                *vb -= h * sim.drag * m * mu;
            });

        // Per spring, then each particle's gather with the forward's signs.
        let springs = model.springs();
        let (d_bar, w_bar) = (&mut self.d_bar[..], &mut self.w_bar[..]);
        springs_transpose(model, (d_bar, w_bar), grad, (x_bar, v_bar), |s, a, b| {
            let at = SpringAt {
                d: x[a] - x[b],
                w: v[a] - v[b],
                delta: dv[a] - dv[b],
                rest: springs.rest[s],
                stiffness: springs.stiffness[s],
                damping: springs.damping[s],
            };
            spring_residual_vjp(at, h, mu[a] - mu[b])
        });
        if let Some(bodies) = self.bodies.as_mut() {
            bodies.implicit_vjp(model, (x, v), (mu, dv), (x_bar, v_bar), grad);
        }
    }
}

/// What the transpose of a forward step takes besides its start and end states: its contacts
/// with the terrain as its final solve held them, and where bodies can touch, its Δv (the end
/// state is then the pair response's, which the step's own update does not give back).
#[derive(Debug, Clone, Default)]
pub(crate) struct Recorded {
    pub(crate) contacts: Vec<Candidate>,
    pub(crate) dv: Vec<DVec3>,
}

impl Recorded {
    /// The solver's last step's.
    pub(crate) fn of(solver: &crate::CpuSolver, model: &Model) -> Recorded {
        let (contacts, dv) = solver.implicit_step();
        Recorded {
            contacts: contacts.to_vec(),
            dv: match model.contact.enabled() {
                true => dv.to_vec(),
                false => Vec::new(),
            },
        }
    }

    /// Bytes held on the heap.
    pub(crate) fn memory_bytes(&self) -> u64 {
        vec_bytes(&self.contacts) + vec_bytes(&self.dv)
    }
}

/// Solves of the transpose per step at most while a slipping contact's friction coupling
/// moves μ's prescribed part: it contracts as the forward's refresh of λ_n does, whose rounds
/// are [`softbody_scene::implicit::ACTIVE_SET_ROUNDS`] at most.
const ADJOINT_ROUNDS: u32 = 32;

/// A contact of the step as the transpose holds it.
#[derive(Debug, Clone, Copy)]
struct Held {
    particle: u32,
    /// λ_n = N·(A Δv − b), the final solve's normal impulse.
    lambda_n: f64,
    /// c of the friction impulse λ_n c (zero where it does not scale with λ_n).
    friction: DVec3,
    /// The viscous friction's cap holds: the impulse is −m v_t.
    capped: bool,
}

/// A spring at the start of a step: its ends' difference d and relative velocity w, the
/// step's δ = Δv_a − Δv_b, and its values.
#[derive(Debug, Clone, Copy)]
pub struct SpringAt {
    /// d = x_a − x_b.
    pub d: DVec3,
    /// w = v_a − v_b.
    pub w: DVec3,
    /// δ = Δv_a − Δv_b.
    pub delta: DVec3,
    /// Rest length r.
    pub rest: f64,
    /// k_s.
    pub stiffness: f64,
    /// k_d.
    pub damping: f64,
}

/// The derivatives of φ = mᵀ(h f_s − h² K_s (w + δ) − h k_d u uᵀ δ) (the module's) in d, w,
/// k_s and k_d, as [`super::forces::SpringBar`].
#[inline(always)]
pub fn spring_residual_vjp(s: SpringAt, h: f64, m: DVec3) -> super::forces::SpringBar {
    let len = s.d.length();
    if len == 0.0 {
        // No direction: the forward's force and block are zero.
        return super::forces::SpringBar {
            d: DVec3::ZERO,
            w: DVec3::ZERO,
            stiffness: 0.0,
            damping: 0.0,
        };
    }
    let inv = 1.0 / len;
    let u = s.d * inv;
    let (k, kd, r) = (s.stiffness, s.damping, s.rest);
    let (alpha, alpha_len) = if len > r {
        (1.0 - r * inv, r * inv * inv)
    } else {
        (0.0, 0.0)
    };
    let q = s.w + s.delta;
    let (cu, e, sd, wu, mq) = (u.dot(m), u.dot(q), u.dot(s.delta), u.dot(s.w), m.dot(q));
    let p = k * (len - r) + kd * wu;
    let h2 = h * h;
    let u_bar = -h * kd * cu * s.w
        - h * p * m
        - h2 * k * (1.0 - alpha) * (cu * q + e * m)
        - h * kd * (sd * m + cu * s.delta);
    let len_bar = -h * k * cu - h2 * k * (mq - e * cu) * alpha_len;
    super::forces::SpringBar {
        d: (u_bar - u * u.dot(u_bar)) * inv + len_bar * u,
        w: -h * kd * cu * u - h2 * k * ((1.0 - alpha) * cu * u + alpha * m),
        stiffness: -h * (len - r) * cu - h2 * ((1.0 - alpha) * e * cu + alpha * mq),
        damping: -h * cu * (wu + sd),
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::{SpringAt, spring_residual_vjp};

    /// φ itself, by the module's formula written out with the forward's block.
    fn phi(s: SpringAt, h: f64, m: DVec3) -> f64 {
        let len = s.d.length();
        let u = s.d / len;
        let alpha = (1.0 - s.rest / len).max(0.0);
        let f = -(s.stiffness * (len - s.rest) + s.damping * s.w.dot(u)) * u;
        let k = |p: DVec3| s.stiffness * ((1.0 - alpha) * u.dot(p) * u + alpha * p);
        m.dot(h * f - h * h * k(s.w + s.delta) - h * s.damping * u.dot(s.delta) * u)
    }

    /// Each derivative against central differences of φ, stretched and compressed (where α is
    /// clamped): φ is a smooth function of each input on either side, so differences with
    /// δ = 1e-6 agree to ~1e-9 of the scale.
    #[test]
    fn the_residuals_derivatives_are_its_differences() {
        let (h, m) = (2e-3, DVec3::new(0.3, -1.1, 0.7));
        for stretch in [1.3, 0.8] {
            let s = SpringAt {
                d: DVec3::new(0.2, 0.05, -0.1) * stretch,
                w: DVec3::new(-0.4, 0.9, 0.3),
                delta: DVec3::new(0.02, -0.07, 0.05),
                rest: DVec3::new(0.2, 0.05, -0.1).length(),
                stiffness: 800.0,
                damping: 3.0,
            };
            let bar = spring_residual_vjp(s, h, m);
            let diff = |f: &dyn Fn(f64) -> SpringAt, scale: f64| {
                let e = 1e-6 * scale;
                (phi(f(e), h, m) - phi(f(-e), h, m)) / (2.0 * e)
            };
            for axis in 0..3 {
                let unit = DVec3::AXES[axis];
                let fd = diff(
                    &|e| SpringAt {
                        d: s.d + e * unit,
                        ..s
                    },
                    1.0,
                );
                assert!(
                    (bar.d[axis] - fd).abs() < 1e-8 * fd.abs().max(1.0),
                    "d {stretch}"
                );
                let fd = diff(
                    &|e| SpringAt {
                        w: s.w + e * unit,
                        ..s
                    },
                    1.0,
                );
                assert!(
                    (bar.w[axis] - fd).abs() < 1e-8 * fd.abs().max(1.0),
                    "w {stretch}"
                );
            }
            let fd = diff(
                &|e| SpringAt {
                    stiffness: s.stiffness + e,
                    ..s
                },
                1.0,
            );
            assert!((bar.stiffness - fd).abs() < 1e-8 * fd.abs().max(1e-3));
            let fd = diff(
                &|e| SpringAt {
                    damping: s.damping + e,
                    ..s
                },
                1.0,
            );
            assert!((bar.damping - fd).abs() < 1e-8 * fd.abs().max(1e-3));
        }
    }
}
