//! The transpose of one step of each explicit integrator, twin of [`crate::integrators`].
//!
//! Each step is recomputed from its start (x, v) with [`Stage::evaluate`] (the
//! stage states and the state before the collision response R, and where bodies can touch the
//! pairs and the state before the pair response after it), and swept back through the pair
//! response, R and the stages, with ā the cotangent handed to
//! [`super::forces::accelerations_vjp`] (and the penalty's share of each particle's force
//! cotangent to [`BodyAdjoint::penalty_vjp`]) at the stage state named:
//!
//! - explicit Euler, x' = x + h v, v' = v + h a: after R, ā = h v̄' at (x, v), x̄ = x̄',
//!   v̄ = v̄' + h x̄';
//! - symplectic Euler, v' = v + h a, x' = x + h v': v̄' += h x̄', then ā = h v̄' at (x, v),
//!   x̄ = x̄', v̄ = v̄';
//! - midpoint, y_m = y + (h/2) y'(y), y' ← y + h y'(y_m): ā_m = h v̄' at y_m, v̄_m = h x̄' + its
//!   share, then x̄ = x̄' + x̄_m, v̄ = v̄' + v̄_m + (h/2) x̄_m, ā = (h/2) v̄_m at y;
//! - RK4: k̄_j = c_j (h/6) ȳ' with c = (1, 2, 2, 1); stage j at y_j = y + β_j h k_{j−1}
//!   (β = 0, ½, ½, 1) hands ȳ_j = (x̄_j, k̄x_j + ∂/∂v) back to ȳ and β_j h ȳ_j to k̄_{j−1},
//!   from the fourth stage to the first.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Integrator, Model, State};
use softbody_terrain::Surface;

use super::Gradient;
use super::body_contact::BodyAdjoint;
use super::collision_response::respond_one_vjp;
use super::forces::{Scratch, Stage, accelerations_vjp};
use crate::forces::PARTICLE_CHUNK;
use crate::vec_bytes;

/// The transpose of one explicit step and its scratch, sized for one model.
#[derive(Debug)]
pub struct StepAdjoint {
    integrator: Integrator,
    scratch: Scratch,
    /// Each stage's evaluation of the forces.
    stages: Vec<Stage>,
    /// Stage states (x_j, v_j) and accelerations a_j, j = 1…4 (RK4; fewer for the others).
    xs: Vec<Vec<DVec3>>,
    vs: Vec<Vec<DVec3>>,
    accs: Vec<Vec<DVec3>>,
    /// The state before the collision response.
    pre: (Vec<DVec3>, Vec<DVec3>),
    /// Contact between bodies, where they can touch.
    bodies: Option<BodyAdjoint>,
    /// Cotangents: of a stage's acceleration, of a stage state, of the k's.
    a_bar: Vec<DVec3>,
    stage_bar: (Vec<DVec3>, Vec<DVec3>),
    k_bar: (Vec<DVec3>, Vec<DVec3>),
}

impl StepAdjoint {
    /// Sized for `model`, whose integrator must be explicit.
    pub fn new(model: &Model) -> StepAdjoint {
        let n = model.len();
        let zeros = || vec![DVec3::ZERO; n];
        let stages = match model.simulation.integrator {
            Integrator::Rk4 => 4,
            Integrator::Midpoint => 2,
            _ => 1,
        };
        StepAdjoint {
            integrator: model.simulation.integrator,
            scratch: Scratch::new(model),
            stages: (0..stages).map(|_| Stage::new(model)).collect(),
            xs: (0..stages).map(|_| zeros()).collect(),
            vs: (0..stages).map(|_| zeros()).collect(),
            accs: (0..stages).map(|_| zeros()).collect(),
            pre: (zeros(), zeros()),
            bodies: model.contact.enabled().then(|| BodyAdjoint::new(model)),
            a_bar: zeros(),
            stage_bar: (zeros(), zeros()),
            k_bar: (zeros(), zeros()),
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        let all = |v: &[Vec<DVec3>]| v.iter().map(vec_bytes).sum::<u64>();
        self.scratch.memory_bytes()
            + self.bodies.as_ref().map_or(0, BodyAdjoint::memory_bytes)
            + self.stages.iter().map(Stage::memory_bytes).sum::<u64>()
            + all(&self.xs)
            + all(&self.vs)
            + all(&self.accs)
            + [
                &self.pre.0,
                &self.pre.1,
                &self.a_bar,
                &self.stage_bar.0,
                &self.stage_bar.1,
                &self.k_bar.0,
                &self.k_bar.1,
            ]
            .into_iter()
            .map(vec_bytes)
            .sum::<u64>()
    }

    /// Turns `(x_bar, v_bar)`, the cotangent of the state after the step that starts at
    /// `start`, into the cotangent of `start`, adding the model's values' to `grad`; with
    /// `external` forces on the particles in the step, their cotangents are added to the
    /// second of the pair.
    pub fn step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        start: &State,
        external: Option<(&[DVec3], &mut [DVec3])>,
        (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
        grad: &mut Gradient,
    ) {
        let h = model.simulation.dt;
        let (forces, mut forces_bar) = external.unzip();
        self.forward(model, surfaces, start, forces);
        if let Some(bodies) = self.bodies.as_mut() {
            bodies.respond_vjp(model, start, (x_bar, v_bar), grad);
        }
        self.respond_vjp(model, surfaces, start, (x_bar, v_bar), grad);
        let mut vjp = |s: &mut Self,
                       j: usize,
                       a_bar: Option<&[DVec3]>,
                       (ox, ov): (&mut [DVec3], &mut [DVec3]),
                       grad: &mut Gradient| {
            let a_bar = a_bar.unwrap_or(&s.a_bar);
            let at = (&s.xs[j][..], &s.vs[j][..]);
            let out = (&mut *ox, &mut *ov);
            accelerations_vjp(
                model,
                surfaces,
                at,
                &s.stages[j],
                a_bar,
                &mut s.scratch,
                out,
                grad,
            );
            if let Some(bodies) = s.bodies.as_mut() {
                bodies.penalty_vjp(model, at, s.scratch.sum_bar(), (ox, ov), grad);
            }
            if let Some(bar) = forces_bar.as_deref_mut() {
                axpy(bar, 1.0, s.scratch.sum_bar());
            }
        };
        match self.integrator {
            Integrator::ExplicitEuler => {
                scaled(&mut self.a_bar, h, v_bar);
                axpy(v_bar, h, x_bar);
                vjp(self, 0, None, (x_bar, v_bar), grad);
            }
            Integrator::SymplecticEuler => {
                axpy(v_bar, h, x_bar);
                scaled(&mut self.a_bar, h, v_bar);
                vjp(self, 0, None, (x_bar, v_bar), grad);
            }
            Integrator::Midpoint => {
                // The midpoint stage: ā_m = h v̄', v̄_m = h x̄', x̄_m = 0.
                let (mut xm_bar, mut vm_bar) = std::mem::take(&mut self.stage_bar);
                xm_bar.fill(DVec3::ZERO);
                scaled(&mut vm_bar, h, x_bar);
                scaled(&mut self.a_bar, h, v_bar);
                vjp(self, 1, None, (&mut xm_bar, &mut vm_bar), grad);
                axpy(x_bar, 1.0, &xm_bar);
                axpy(v_bar, 1.0, &vm_bar);
                axpy(v_bar, 0.5 * h, &xm_bar);
                scaled(&mut self.a_bar, 0.5 * h, &vm_bar);
                self.stage_bar = (xm_bar, vm_bar);
                vjp(self, 0, None, (x_bar, v_bar), grad);
            }
            Integrator::Rk4 => {
                // ȳ' kept whole (in the buffers of the state before the response, which the
                // response's transpose no longer needs); x̄, v̄ gather the stages' shares.
                let (mut yx, mut yv) = std::mem::take(&mut self.stage_bar);
                let (mut kx, mut kv) = std::mem::take(&mut self.k_bar);
                let (mut ox, mut ov) = std::mem::take(&mut self.pre);
                ox.copy_from_slice(x_bar);
                ov.copy_from_slice(v_bar);
                // k̄_4 = (h/6) ȳ'.
                scaled(&mut kx, h / 6.0, &ox);
                scaled(&mut kv, h / 6.0, &ov);
                // Stage j + 1 at y + β h k_j hands β h ȳ_{j+1} to k̄_j, whose own weight is c_j.
                for (j, beta, c) in [(3, 1.0, 2.0), (2, 0.5, 2.0), (1, 0.5, 1.0)] {
                    // ȳ_j = (∂aᵀ k̄v, k̄x + ∂aᵀ k̄v) at stage j.
                    yx.fill(DVec3::ZERO);
                    yv.copy_from_slice(&kx);
                    vjp(self, j, Some(&kv), (&mut yx, &mut yv), grad);
                    axpy(x_bar, 1.0, &yx);
                    axpy(v_bar, 1.0, &yv);
                    let (ox, ov, yx, yv) = (&ox, &ov, &yx, &yv);
                    kx.par_iter_mut()
                        .zip(kv.par_iter_mut())
                        .enumerate()
                        .with_min_len(PARTICLE_CHUNK)
                        .for_each(|(i, (kx, kv))| {
                            *kx = c * h / 6.0 * ox[i] + beta * h * yx[i];
                            *kv = c * h / 6.0 * ov[i] + beta * h * yv[i];
                        });
                }
                // The first stage, at y itself: k1 = (v, a(x, v)).
                axpy(v_bar, 1.0, &kx);
                vjp(self, 0, Some(&kv), (x_bar, v_bar), grad);
                self.stage_bar = (yx, yv);
                self.k_bar = (kx, kv);
                self.pre = (ox, ov);
            }
            Integrator::ImplicitEuler => unreachable!("implicit Euler has its own transpose"),
        }
    }

    /// The stage states and accelerations of the step from `start` with the `external` forces,
    /// the state before the collision response, and that before the pair response, by the
    /// forward's formulas.
    fn forward(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        start: &State,
        external: Option<&[DVec3]>,
    ) {
        let h = model.simulation.dt;
        let (x, v) = (&start.x[..], &start.v[..]);
        self.xs[0].copy_from_slice(x);
        self.vs[0].copy_from_slice(v);
        if let Some(bodies) = self.bodies.as_mut() {
            bodies.prepare(model, start);
        }
        let accel = |s: &mut Self, j: usize| {
            let at = (&s.xs[j][..], &s.vs[j][..]);
            let partners = s.bodies.as_ref().map(BodyAdjoint::partners);
            let besides = (partners, external);
            s.stages[j].evaluate(model, surfaces, at, besides, &mut s.accs[j]);
        };
        accel(self, 0);
        let stages = self.xs.len();
        // Stage j + 1 at y + β h k_j (midpoint: β = ½; RK4: ½, ½, 1).
        for j in 0..stages - 1 {
            let beta = if stages == 4 && j == 2 { 1.0 } else { 0.5 };
            let (_, tail) = self.xs.split_at_mut(j + 1);
            let (vhead, vtail) = self.vs.split_at_mut(j + 1);
            let (vj, aj) = (&vhead[j], &self.accs[j]);
            tail[0]
                .par_iter_mut()
                .zip(vtail[0].par_iter_mut())
                .enumerate()
                .with_min_len(PARTICLE_CHUNK)
                .for_each(|(i, (xn, vn))| {
                    *xn = x[i] + beta * h * vj[i];
                    *vn = v[i] + beta * h * aj[i];
                });
            accel(self, j + 1);
        }
        let (vs, accs) = (&self.vs, &self.accs);
        let integrator = self.integrator;
        self.pre
            .0
            .par_iter_mut()
            .zip(self.pre.1.par_iter_mut())
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, (xp, vp))| {
                (*xp, *vp) = match integrator {
                    Integrator::ExplicitEuler => (x[i] + h * v[i], v[i] + h * accs[0][i]),
                    Integrator::SymplecticEuler => {
                        let v1 = v[i] + h * accs[0][i];
                        (x[i] + h * v1, v1)
                    }
                    Integrator::Midpoint => (x[i] + h * vs[1][i], v[i] + h * accs[1][i]),
                    _ => {
                        let sx = v[i] + 2.0 * vs[1][i] + 2.0 * vs[2][i] + vs[3][i];
                        let sv = accs[0][i] + 2.0 * accs[1][i] + 2.0 * accs[2][i] + accs[3][i];
                        (x[i] + h / 6.0 * sx, v[i] + h / 6.0 * sv)
                    }
                };
            });
        if let Some(bodies) = self.bodies.as_mut() {
            bodies.forward(model, surfaces, start, (&self.pre.0, &self.pre.1));
        }
    }

    /// Turns the cotangent of the state after the terrain's collision response into the
    /// cotangent of the state before it (pinned particles take no response).
    fn respond_vjp(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        start: &State,
        (x_bar, v_bar): (&mut [DVec3], &mut [DVec3]),
        grad: &mut Gradient,
    ) {
        if surfaces.is_empty() {
            return;
        }
        let sim = &model.simulation;
        let (eps, h) = (sim.contact_distance, sim.dt);
        let (pre_x, pre_v) = (&self.pre.0, &self.pre.1);
        x_bar
            .par_iter_mut()
            .zip(v_bar.par_iter_mut())
            .zip(grad.restitution.par_chunks_mut(surfaces.len()))
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, ((xb, vb), kr_bar))| {
                if model.inv_mass[i] != 0.0 {
                    (*xb, *vb) = respond_one_vjp(
                        surfaces,
                        eps,
                        h,
                        (start.x[i], start.v[i]),
                        (pre_x[i], pre_v[i]),
                        (*xb, *vb),
                        kr_bar,
                    );
                }
            });
    }
}

/// out = s·a.
fn scaled(out: &mut [DVec3], s: f64, a: &[DVec3]) {
    out.par_iter_mut()
        .zip(a.par_iter())
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(o, a)| *o = s * *a);
}

/// y += s·a.
fn axpy(y: &mut [DVec3], s: f64, a: &[DVec3]) {
    y.par_iter_mut()
        .zip(a.par_iter())
        .with_min_len(PARTICLE_CHUNK)
        .for_each(|(y, a)| *y += s * *a);
}
