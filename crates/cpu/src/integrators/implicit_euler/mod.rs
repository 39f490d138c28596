//! Implicit (backward) Euler, linearised once per step:
//!
//! (M − h ∂f/∂v − h² ∂f/∂x) Δv = h (f + h ∂f/∂x v),  v' = v + Δv,  x' = x + h v',
//!
//! solved matrix-free by filtered, preconditioned CG ([`cg`], [`system`]) to a relative
//! residual of the scene's `cg_tolerance` ([`CG_TOLERANCE`] by default) or at most [`CG_MAX_ITERATIONS`] iterations, warm started from
//! the combination of the last [`cg::WARM_START_BASIS`] steps' Δv closest to the solution. The
//! preconditioner is the scene's `preconditioner`: aggregation multigrid on the lattice
//! ([`multigrid`]; the default, where every particle has lattice coordinates) or block Jacobi
//! (a model with a `particles` body always runs block Jacobi).
//!
//! Contact and friction live inside the solve, as velocity constraints (Baraff and Witkin's
//! constraint filtering), because explicit contact forces or position projections pump energy
//! into a stiff body at large steps. A particle that reaches a surface within the step
//! (φ + h v·N < ε, the surface with the smallest such value; for a particle touching at the end
//! of the last step, below ε plus the rounding of x and h v: [`resting_slack`]) becomes a
//! contact with a target
//! normal velocity v_n' = −φ/h, which lands it on the surface without moving positions; on a
//! fresh impact the target is max(−φ/h, k_r·(−v_n)), the restitution law. A contact either
//! - sticks: all of Δv is prescribed, v' = v_n' N; or
//! - slips: only the normal component is prescribed, and kinetic friction enters the
//!   right-hand side as an impulse μλ_n against the slip (viscous: −k_f λ_n v_t, capped so it
//!   never reverses the slip), λ_n being the contact's normal impulse.
//!
//! An active set decides, from the constraint impulses λ = A Δv − rhs of each solve: a contact
//! that pulls (λ_n < 0) is released; a sticking contact whose tangential impulse leaves the
//! Coulomb cone (|λ_t| > μλ_n) slips, with friction along λ_t; a slipping contact whose slip
//! reverses sticks (once per step, which rules out cycles); a free candidate that would end
//! the step inside a surface becomes a contact; a slipping contact's friction follows its
//! updated λ_n. At most [`ACTIVE_SET_ROUNDS`] solves per step. Pinned particles are fixed
//! constraints with Δv = 0. One contact per particle: where a particle touches two surfaces at
//! once (an inner corner), the one it reaches first within the step is constrained.
//!
//! Pairs of bodies in contact at the start of the step push apart inside the solve: each is a
//! linearised penalty spring of the system ([`system`], [`crate::body_contact`]); impacts and
//! friction between bodies are the response after the step, as for every integrator.
//!
//! With no springs and no contact this is v' = v + h g, x' = x + h v': symplectic Euler's
//! free fall. On the same contact laws as the explicit integrators' ([`crate::contact`]): a
//! sliding particle decelerates at μ|g_n|, and a particle on a slope shallower than atan μ
//! sticks.

pub mod cg;
pub mod lattice;
pub mod multigrid;
pub mod system;

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::implicit::resting_slack;
pub use softbody_scene::implicit::{ACTIVE_SET_ROUNDS, CG_MAX_ITERATIONS, CG_TOLERANCE};
use softbody_scene::{FrictionModel, History, Model, State, Statistics, StepError, Timings};

use self::cg::{Constraint, Scratch};
use self::multigrid::Multigrid;
use self::system::System;
use crate::body_contact::Partners;
use crate::forces::PARTICLE_CHUNK;
use softbody_terrain::Surface;

/// A slipping contact's friction impulse μλ_n takes the normal impulse λ_n of the solve before
/// (the solve is linear only with it fixed), and the step solves again while λ_n moves by more
/// than this, relative: the friction then matches its own solve's normal impulse to the
/// gradient tests' 1e-6, which the step's transpose assumes ([`crate::adjoint::implicit_euler`];
/// 1e-3 left the gradient 1e-4 off; the GPU's f32 twin refreshes to 1e-5).
pub(crate) const FRICTION_REFRESH: f64 = 1e-6;

/// `multigrid-kept` of a history whose multigrid had no values.
const NOTHING_KEPT: u32 = u32::MAX;

/// A constraint in a history: a tag byte (0 free, 1 normal, 2 fixed) and the normal.
const CONSTRAINT_BYTES: usize = 25;

fn encode(s: Constraint) -> [u8; CONSTRAINT_BYTES] {
    let (tag, n) = match s {
        Constraint::Free => (0, DVec3::ZERO),
        Constraint::Normal(n) => (1, n),
        Constraint::Fixed => (2, DVec3::ZERO),
    };
    let mut bytes = [0; CONSTRAINT_BYTES];
    bytes[0] = tag;
    for (k, c) in n.to_array().into_iter().enumerate() {
        bytes[1 + 8 * k..9 + 8 * k].copy_from_slice(&c.to_le_bytes());
    }
    bytes
}

fn decode(bytes: &[u8]) -> Result<Constraint, StepError> {
    let n = DVec3::from_array(std::array::from_fn(|k| {
        f64::from_le_bytes(bytes[1 + 8 * k..9 + 8 * k].try_into().unwrap())
    }));
    match bytes[0] {
        0 => Ok(Constraint::Free),
        1 => Ok(Constraint::Normal(n)),
        2 => Ok(Constraint::Fixed),
        tag => Err(StepError::Invalid(format!(
            "restore: the history's `multigrid-constraints` has a constraint tag {tag}"
        ))),
    }
}

/// What a contact does in the step's solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Mode {
    Inactive,
    Stick,
    Slip,
}

/// A particle near a surface this step.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Candidate {
    pub(crate) particle: u32,
    pub(crate) surface: u32,
    /// The surface's distance and normal at the particle's start-of-step position.
    pub(crate) phi: f64,
    pub(crate) normal: DVec3,
    pub(crate) mode: Mode,
    /// Not touching at the end of the last step: a contact is a fresh impact.
    pub(crate) fresh: bool,
    /// Target normal velocity at the end of the step.
    pub(crate) vn_target: f64,
    /// Normal impulse the friction uses (estimated, then from the last solve).
    pub(crate) lambda_n: f64,
    /// Unit direction of the kinetic friction impulse.
    pub(crate) friction_dir: DVec3,
    /// The friction's direction is the tangential impulse of a solve that held the contact
    /// sticking (it switched to slipping), not the one against the start's slip.
    pub(crate) turned: bool,
    /// Released as pulling this step: stays free.
    released: bool,
    /// Switched from slipping to sticking this step: may not switch again.
    settled: bool,
}

impl Candidate {
    /// A slipping contact with Coulomb friction whose direction came from a sticking solve.
    pub(crate) fn held_direction(&self) -> bool {
        self.mode == Mode::Slip && self.turned
    }
}

/// Implicit Euler's state between steps and its scratch.
pub struct ImplicitEuler {
    system: System,
    /// The multigrid preconditioner (`None`: block Jacobi).
    multigrid: Option<Multigrid>,
    scratch: Scratch,
    b: Vec<DVec3>,
    rhs: Vec<DVec3>,
    z: Vec<DVec3>,
    dv: Vec<DVec3>,
    /// The Δv of the steps before the last, the latest first ([`cg::WARM_START_BASIS`] − 1).
    earlier: Vec<Vec<DVec3>>,
    /// The last step's Δv while this step's solve replaces it (then the latest of `earlier`).
    last: Vec<DVec3>,
    impulse: Vec<DVec3>,
    constraints: Vec<Constraint>,
    /// Touching a surface at the end of the last step (a new touch is a fresh impact).
    touching: Vec<bool>,
    /// Sticking at the end of the last step.
    sticking: Vec<bool>,
    /// The last step's contacts (sticking or slipping) as its final solve held them: what its
    /// transpose ([`crate::adjoint::implicit_euler`]) needs besides the states.
    contacts: Vec<Candidate>,
    /// The positions the multigrid's values were computed at (empty without a multigrid):
    /// with the constraints, what a resumed run needs to compute the values a run kept.
    prepared_x: Vec<DVec3>,
    /// Counters over the run.
    pub statistics: Statistics,
}

impl ImplicitEuler {
    /// Sized for `model`.
    pub fn new(model: &Model) -> ImplicitEuler {
        let n = model.len();
        let zeros = || vec![DVec3::ZERO; n];
        let system = System::new(model);
        let multigrid = match model.simulation.preconditioner {
            softbody_scene::Preconditioner::Multigrid => Multigrid::new(model, &system),
            softbody_scene::Preconditioner::BlockJacobi => None,
        };
        let statistics = Statistics {
            preconditioner: Some(if multigrid.is_some() {
                softbody_scene::Preconditioner::Multigrid
            } else {
                softbody_scene::Preconditioner::BlockJacobi
            }),
            ..Statistics::default()
        };
        ImplicitEuler {
            system,
            scratch: Scratch::new(n),
            b: zeros(),
            rhs: zeros(),
            z: zeros(),
            dv: zeros(),
            earlier: vec![zeros(); cg::WARM_START_BASIS - 1],
            last: zeros(),
            impulse: zeros(),
            constraints: vec![Constraint::Free; n],
            touching: vec![false; n],
            sticking: vec![false; n],
            contacts: Vec::new(),
            prepared_x: match multigrid {
                Some(_) => zeros(),
                None => Vec::new(),
            },
            multigrid,
            statistics,
        }
    }

    /// Bytes held on the heap (the per-step contact candidates excluded).
    pub fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        self.system.memory_bytes()
            + self.multigrid.as_ref().map_or(0, Multigrid::memory_bytes)
            + self.scratch.memory_bytes()
            + [
                &self.b,
                &self.rhs,
                &self.z,
                &self.dv,
                &self.last,
                &self.impulse,
            ]
            .into_iter()
            .chain(&self.earlier)
            .map(vec_bytes)
            .sum::<u64>()
            + vec_bytes(&self.constraints)
            + vec_bytes(&self.touching)
            + vec_bytes(&self.sticking)
            + vec_bytes(&self.contacts)
            + vec_bytes(&self.prepared_x)
    }

    /// How the system's products are computed: `matrix-free-lattice` on lattice bodies
    /// ([`lattice`]: cuboids and mesh bodies), `matrix-free` by the spring list.
    pub fn kernel_name(&self) -> &'static str {
        match self.system.lattice {
            Some(_) => "matrix-free-lattice",
            None => "matrix-free",
        }
    }

    /// What the next step starts from besides the state: the warm start Δv, who touches and
    /// sticks, and with a multigrid, what its values were computed for (positions and
    /// constraints) and how long they have been kept ([`Multigrid::prepare`]).
    pub fn history(&self) -> History {
        let mut history = History::default();
        let vectors = |v: &[DVec3]| -> Vec<u8> {
            v.iter()
                .flat_map(|v| v.to_array())
                .flat_map(f64::to_le_bytes)
                .collect()
        };
        history.push("dv", vectors(&self.dv));
        history.push("dv-earlier", vectors(&self.earlier.concat()));
        if let Some(mg) = &self.multigrid {
            let (constraints, kept) = mg.kept().unwrap_or((&[], NOTHING_KEPT));
            history.push("multigrid-x", vectors(&self.prepared_x));
            history.push(
                "multigrid-constraints",
                constraints.iter().flat_map(|s| encode(*s)).collect(),
            );
            history.push("multigrid-kept", kept.to_le_bytes().to_vec());
        }
        history.push(
            "touching",
            self.touching.iter().map(|&b| u8::from(b)).collect(),
        );
        history.push(
            "sticking",
            self.sticking.iter().map(|&b| u8::from(b)).collect(),
        );
        history
    }

    /// Takes up [`ImplicitEuler::history`]'s: with a multigrid, computes the values the run
    /// kept from the positions and constraints they were computed for (a model with contact
    /// between bodies keeps none).
    pub fn restore(&mut self, model: &Model, history: &History) -> Result<(), StepError> {
        let n = self.dv.len();
        let vectors = |name: &str, out: &mut [DVec3]| -> Result<(), StepError> {
            let bytes = history.part(name, 24 * out.len())?;
            for (v, bytes) in out.iter_mut().zip(bytes.chunks_exact(24)) {
                *v = DVec3::from_array(std::array::from_fn(|k| {
                    f64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().unwrap())
                }));
            }
            Ok(())
        };
        vectors("dv", &mut self.dv)?;
        // A history without the earlier solutions (written before the warm start combined
        // them) leaves them zero: the first step after it starts from the last Δv alone.
        let mut earlier = vec![DVec3::ZERO; self.earlier.len() * n];
        if history.parts.iter().any(|(name, _)| name == "dv-earlier") {
            vectors("dv-earlier", &mut earlier)?;
        }
        for (e, saved) in self.earlier.iter_mut().zip(earlier.chunks_exact(n.max(1))) {
            e.copy_from_slice(saved);
        }
        // A history without the multigrid's parts (written before its values were kept
        // across steps) kept nothing.
        let kept_part = history
            .parts
            .iter()
            .any(|(name, _)| name == "multigrid-kept");
        if let Some(mg) = self.multigrid.as_mut() {
            let kept = match kept_part {
                true => u32::from_le_bytes(history.part("multigrid-kept", 4)?.try_into().unwrap()),
                false => NOTHING_KEPT,
            };
            if kept != NOTHING_KEPT {
                vectors("multigrid-x", &mut self.prepared_x)?;
            }
            if kept == NOTHING_KEPT || self.system.pairs.is_some() {
                mg.forget();
            } else {
                let bytes = history.part("multigrid-constraints", CONSTRAINT_BYTES * n)?;
                let constraints: Vec<Constraint> = bytes
                    .chunks_exact(CONSTRAINT_BYTES)
                    .map(decode)
                    .collect::<Result<_, _>>()?;
                // The system at those positions (its diagonal blocks and springs' blocks do not
                // depend on the velocities); the next step assembles its own.
                let zeros = vec![DVec3::ZERO; n];
                (self.system).assemble(model, (None, None), &self.prepared_x, &zeros, &mut self.b);
                mg.restore(&self.system, model, &constraints, kept);
            }
        }
        for (name, flags) in [
            ("touching", &mut self.touching),
            ("sticking", &mut self.sticking),
        ] {
            let bytes = history.part(name, n)?;
            flags.iter_mut().zip(bytes).for_each(|(f, &b)| *f = b != 0);
        }
        Ok(())
    }

    /// One step, with the pairs of bodies in contact at its start `partners` (given exactly
    /// when the model has contact between bodies) and the `external` forces on the particles,
    /// its stages timed into `timings`:
    /// "assemble" (the linear system),
    /// "contacts" (candidates, constraints, active set), "cg" (the solves), "update".
    pub fn step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        (partners, external): (Option<&Partners>, Option<&[DVec3]>),
        state: &mut State,
        timings: &mut Timings,
    ) {
        let sim = &model.simulation;
        let (h, eps) = (sim.dt, sim.contact_distance);
        timings.time("assemble", || {
            let around = (partners, external);
            (self.system).assemble(model, around, &state.x, &state.v, &mut self.b)
        });
        let mut candidates = timings.time("contacts", || {
            self.find_candidates(model, surfaces, state, h, eps)
        });

        self.last.copy_from_slice(&self.dv);
        for _ in 0..ACTIVE_SET_ROUNDS {
            timings.time("contacts", || {
                self.constrain(model, surfaces, state, &candidates)
            });
            let earlier: [&[DVec3]; cg::WARM_START_BASIS - 1] =
                std::array::from_fn(|j| self.earlier[j].as_slice());
            let outcome = timings.time("cg", || {
                let problem = cg::CgProblem::new(
                    &mut self.system,
                    model,
                    &self.constraints,
                    &self.rhs,
                    &self.z,
                );
                cg::CgProblem {
                    earlier: &earlier,
                    tolerance: model.simulation.cg_tolerance,
                    preconditioner: match self.multigrid.as_mut() {
                        Some(mg) => cg::Preconditioner::Multigrid(mg),
                        None => cg::Preconditioner::BlockJacobi,
                    },
                    ..problem
                }
                .solve(&mut self.dv, &mut self.scratch)
            });
            let st = &mut self.statistics;
            st.cg_iterations += outcome.iterations as u64;
            st.cg_solves += 1;
            st.cg_max_residual = st.cg_max_residual.max(outcome.relative_residual);
            if candidates.is_empty()
                || !timings.time("contacts", || {
                    self.update_active_set(model, surfaces, state, &mut candidates)
                })
            {
                break;
            }
        }
        if let Some(mg) = &self.multigrid
            && mg.computed_at() == Some(self.system.assembly())
        {
            self.prepared_x.copy_from_slice(&state.x);
        }
        self.earlier.rotate_right(1);
        std::mem::swap(&mut self.earlier[0], &mut self.last);
        timings.time("update", || self.finish(&candidates, h, state));
    }

    /// The last step's contacts with the terrain as its final solve held them, by particle.
    pub(crate) fn contacts(&self) -> &[Candidate] {
        &self.contacts
    }

    /// The last step's Δv.
    pub(crate) fn dv(&self) -> &[DVec3] {
        &self.dv
    }

    /// Records who touches and sticks, then v ← v + Δv, x ← x + h v.
    fn finish(&mut self, candidates: &[Candidate], h: f64, state: &mut State) {
        self.touching.fill(false);
        self.sticking.fill(false);
        self.contacts.clear();
        for c in candidates {
            self.touching[c.particle as usize] = c.mode != Mode::Inactive;
            self.sticking[c.particle as usize] = c.mode == Mode::Stick;
            if c.mode != Mode::Inactive {
                self.contacts.push(*c);
            }
        }
        let dv = &self.dv;
        state
            .x
            .par_iter_mut()
            .zip(state.v.par_iter_mut())
            .zip(dv.par_iter())
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|((x, v), dv)| {
                *v += *dv;
                *x += h * *v;
            });
    }

    /// Particles that may reach a surface within the step, each with its nearest surface.
    fn find_candidates(
        &self,
        model: &Model,
        surfaces: &[Surface],
        state: &State,
        h: f64,
        eps: f64,
    ) -> Vec<Candidate> {
        if surfaces.is_empty() {
            return Vec::new();
        }
        let g = model.simulation.gravity.length();
        (0..model.len())
            .into_par_iter()
            .with_min_len(PARTICLE_CHUNK)
            .filter_map(|i| {
                if model.is_pinned(i) {
                    return None;
                }
                let (x, v) = (state.x[i], state.v[i]);
                // Far enough that nothing this step can bring it within ε, even with twice its
                // speed: skip the exact test.
                let reach = eps + h * (2.0 * v.length() + h * g);
                let (surface, contact) = surfaces
                    .iter()
                    .enumerate()
                    .filter_map(|(k, s)| s.query(x, reach).map(|c| (k, c)))
                    .min_by(|a, b| {
                        let pa = a.1.phi + h * v.dot(a.1.normal);
                        let pb = b.1.phi + h * v.dot(b.1.normal);
                        pa.total_cmp(&pb)
                    })?;
                let mut c = Candidate {
                    particle: i as u32,
                    surface: surface as u32,
                    phi: contact.phi,
                    normal: contact.normal,
                    mode: Mode::Inactive,
                    fresh: !self.touching[i],
                    vn_target: 0.0,
                    lambda_n: 0.0,
                    friction_dir: DVec3::ZERO,
                    turned: false,
                    released: false,
                    settled: false,
                };
                let slack = if self.touching[i] {
                    resting_slack(x, v, h, f64::EPSILON)
                } else {
                    0.0
                };
                if contact.phi + h * v.dot(contact.normal) < eps + slack {
                    self.activate(
                        model,
                        &surfaces[surface],
                        state,
                        h,
                        &mut c,
                        self.sticking[i],
                    );
                }
                Some(c)
            })
            .collect()
    }

    /// Makes a candidate a contact: its target normal velocity, an estimate of its normal
    /// impulse, and whether it starts sticking.
    fn activate(
        &self,
        model: &Model,
        surface: &Surface,
        state: &State,
        h: f64,
        c: &mut Candidate,
        was_sticking: bool,
    ) {
        let i = c.particle as usize;
        let (v, m, n) = (state.v[i], model.mass[i], c.normal);
        let vn = v.dot(n);
        // Landing exactly on the surface takes v_n' = −φ/h. A fresh impact rebounds at k_r times
        // its approach speed instead, unless landing needs more (a particle that has sunk in):
        // adding the two would eat the rebound by up to φ/h, which does not shrink with h.
        c.vn_target = -c.phi / h;
        if c.fresh {
            c.vn_target = c.vn_target.max(surface.restitution * (-vn).max(0.0));
        }
        // Impulse to reach the target normal velocity against the applied force, ignoring the
        // springs' share: the solve replaces it with the real one.
        c.lambda_n = (m * (c.vn_target - vn) - self.b[i].dot(n)).max(0.0);
        let vt = v - vn * n;
        let speed = vt.length();
        c.turned = false;
        c.friction_dir = if speed > 0.0 {
            -vt / speed
        } else {
            DVec3::ZERO
        };
        let coulomb = surface.friction_model == FrictionModel::Coulomb && surface.friction > 0.0;
        c.mode = if coulomb && (was_sticking || m * speed <= surface.friction * c.lambda_n) {
            Mode::Stick
        } else {
            Mode::Slip
        };
    }

    /// Writes constraints, prescribed Δv and the right-hand side with friction impulses.
    fn constrain(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        state: &State,
        candidates: &[Candidate],
    ) {
        for (i, s) in self.constraints.iter_mut().enumerate() {
            *s = if model.is_pinned(i) {
                Constraint::Fixed
            } else {
                Constraint::Free
            };
        }
        self.z
            .par_iter_mut()
            .zip(state.v.par_iter())
            .zip(self.constraints.par_iter())
            .for_each(|((z, v), s)| {
                *z = if *s == Constraint::Fixed {
                    -*v
                } else {
                    DVec3::ZERO
                }
            });
        self.impulse.fill(DVec3::ZERO);
        for c in candidates {
            let i = c.particle as usize;
            let (v, n) = (state.v[i], c.normal);
            match c.mode {
                Mode::Inactive => {}
                Mode::Stick => {
                    self.constraints[i] = Constraint::Fixed;
                    self.z[i] = c.vn_target * n - v;
                }
                Mode::Slip => {
                    self.constraints[i] = Constraint::Normal(n);
                    self.z[i] = (c.vn_target - v.dot(n)) * n;
                    let s = &surfaces[c.surface as usize];
                    self.impulse[i] = match s.friction_model {
                        FrictionModel::Coulomb => s.friction * c.lambda_n * c.friction_dir,
                        FrictionModel::Viscous => {
                            let vt = v - v.dot(n) * n;
                            (-s.friction * c.lambda_n * vt)
                                .clamp_length_max(model.mass[i] * vt.length())
                        }
                    };
                }
            }
        }
        self.rhs
            .par_iter_mut()
            .zip(self.b.par_iter().zip(self.impulse.par_iter()))
            .for_each(|(r, (b, j))| *r = *b + *j);
    }

    /// Revises the active set from the last solve; returns whether anything changed.
    fn update_active_set(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        state: &State,
        candidates: &mut [Candidate],
    ) -> bool {
        let h = model.simulation.dt;
        // Constraint impulses λ = A Δv − rhs (reuse the impulse buffer for A Δv).
        let mut a_dv = std::mem::take(&mut self.impulse);
        self.system.apply(model, &self.dv, &mut a_dv);
        let mut changed = false;
        for c in candidates.iter_mut() {
            let i = c.particle as usize;
            let s = &surfaces[c.surface as usize];
            let n = c.normal;
            let lambda = a_dv[i] - self.rhs[i];
            let lambda_n = lambda.dot(n);
            let v_new = state.v[i] + self.dv[i];
            match c.mode {
                Mode::Inactive => {
                    if !c.released && c.phi + h * v_new.dot(n) < 0.0 {
                        let was = c.settled;
                        self.activate(model, s, state, h, c, false);
                        c.settled = was;
                        changed = true;
                    }
                }
                _ if lambda_n < 0.0 => {
                    c.mode = Mode::Inactive;
                    c.released = true;
                    changed = true;
                }
                Mode::Stick => {
                    c.lambda_n = lambda_n;
                    let lambda_t = lambda - lambda_n * n;
                    let t = lambda_t.length();
                    if !c.settled && t > s.friction * lambda_n * (1.0 + 1e-9) {
                        c.mode = Mode::Slip;
                        c.friction_dir = lambda_t / t;
                        c.turned = true;
                        changed = true;
                    }
                }
                Mode::Slip => {
                    let slip = v_new - v_new.dot(n) * n;
                    let coulomb = s.friction_model == FrictionModel::Coulomb && s.friction > 0.0;
                    if coulomb && !c.settled && slip.dot(c.friction_dir) > 0.0 {
                        // Friction overshot: the slip reversed, so the contact sticks.
                        c.mode = Mode::Stick;
                        c.settled = true;
                        changed = true;
                    } else if s.friction > 0.0
                        && (lambda_n - c.lambda_n).abs()
                            > FRICTION_REFRESH * lambda_n.abs().max(c.lambda_n)
                    {
                        c.lambda_n = lambda_n;
                        changed = true;
                    }
                }
            }
        }
        self.impulse = a_dv;
        changed
    }
}
