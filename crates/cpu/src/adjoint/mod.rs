//! Reverse-mode gradients of a whole run: the discrete adjoint of the integrators as they are
//! implemented, so that what is differentiated is the computed trajectory, not the ODE.
//!
//! A run is the map (x₀, v₀, θ) ↦ (x_k, v_k)_{k ≤ T}, one step Φ at a time. For a loss
//! L = Σ_frames ℓ_f(x_f, v_f), the adjoint sweeps back from the last step: with the cotangent
//! (x̄, v̄) of the state after step k, the cotangent of the state before it is
//! (∂Φ/∂(x, v))ᵀ (x̄, v̄), plus the frame's own ∂ℓ/∂(x, v), and the model's values θ gather
//! (∂Φ/∂θ)ᵀ (x̄, v̄) on the way ([`integrators`] for each explicit method's transpose,
//! [`implicit_euler`] for implicit Euler's, [`forces`] for the accelerations',
//! [`collision_response`] for the response's, [`body_contact`] for contact between bodies').
//! The states the sweep needs come from checkpoints every √T steps or so and a recomputation of
//! each segment by the forward solver itself ([`run`]): the forward is deterministic, so the
//! recomputed states are the forward's bits (checked at every segment's end).
//!
//! Contact is differentiated along the branch the forward took. Where a law has a kink — a
//! contact starting or ending, stick ↔ slip, a cap on friction reached — the gradient is the
//! one-sided derivative of the branch the forward run took at that step (docs/physics.md).

pub mod body_contact;
pub mod collision_response;
pub mod forces;
pub mod implicit_euler;
pub mod integrators;
pub mod run;

use glam::DVec3;
use softbody_scene::Model;

/// The gradient of a loss with respect to the values of a model, accumulated step by step.
///
/// Values that are global in the model (gravity, drag, each surface's friction and
/// restitution, those of contact between bodies) are accumulated per particle, each particle's
/// by one task (contact between bodies': each pair's onto its first particle, in pair order),
/// and summed in particle order at the end ([`Gradient::gravity_total`] and the others): the
/// same bits for any thread count.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradient {
    /// ∂L/∂m_i, through m g, the drag m v and the stopping force m/h of friction.
    pub mass: Vec<f64>,
    /// ∂L/∂w_i, w_i = 1/m_i the inverse mass that turns forces into accelerations.
    pub inv_mass: Vec<f64>,
    /// ∂L/∂k_s per spring, in the order of [`Model::springs`].
    pub stiffness: Vec<f64>,
    /// ∂L/∂k_d per spring.
    pub damping: Vec<f64>,
    /// Each particle's part of ∂L/∂g.
    pub gravity: Vec<DVec3>,
    /// Each particle's part of ∂L/∂drag.
    pub drag: Vec<f64>,
    /// Each particle's part of ∂L/∂μ_k, `max(surfaces, 1)` per particle (so that every
    /// particle has its chunk, also without terrain).
    pub friction: Vec<f64>,
    /// Each particle's part of ∂L/∂k_r,k, laid out as `friction`.
    pub restitution: Vec<f64>,
    /// Each particle's part of ∂L/∂μ of contact between bodies (a pair's, its first
    /// particle's).
    pub body_friction: Vec<f64>,
    /// Each particle's part of ∂L/∂k_r of contact between bodies, as `body_friction`.
    pub body_restitution: Vec<f64>,
    /// The number of terrain surfaces.
    pub surfaces: usize,
}

impl Gradient {
    /// Zero, sized for `model` and its terrain.
    pub fn zeros(model: &Model) -> Gradient {
        let (n, s, k) = (model.len(), model.springs().len(), model.terrain.len());
        Gradient {
            mass: vec![0.0; n],
            inv_mass: vec![0.0; n],
            stiffness: vec![0.0; s],
            damping: vec![0.0; s],
            gravity: vec![DVec3::ZERO; n],
            drag: vec![0.0; n],
            friction: vec![0.0; n * k.max(1)],
            restitution: vec![0.0; n * k.max(1)],
            body_friction: vec![0.0; n],
            body_restitution: vec![0.0; n],
            surfaces: k,
        }
    }

    /// ∂L/∂g.
    pub fn gravity_total(&self) -> DVec3 {
        self.gravity.iter().fold(DVec3::ZERO, |s, g| s + *g)
    }

    /// ∂L/∂drag.
    pub fn drag_total(&self) -> f64 {
        self.drag.iter().fold(0.0, |s, d| s + d)
    }

    /// ∂L/∂μ of contact between bodies.
    pub fn body_friction_total(&self) -> f64 {
        self.body_friction.iter().fold(0.0, |s, d| s + d)
    }

    /// ∂L/∂k_r of contact between bodies.
    pub fn body_restitution_total(&self) -> f64 {
        self.body_restitution.iter().fold(0.0, |s, d| s + d)
    }

    /// ∂L/∂μ of surface `k`.
    pub fn friction_of(&self, k: usize) -> f64 {
        self.per_surface(&self.friction, k)
    }

    /// ∂L/∂k_r of surface `k`.
    pub fn restitution_of(&self, k: usize) -> f64 {
        self.per_surface(&self.restitution, k)
    }

    fn per_surface(&self, values: &[f64], k: usize) -> f64 {
        values
            .iter()
            .skip(k)
            .step_by(self.surfaces.max(1))
            .fold(0.0, |s, d| s + d)
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        let f = |v: &Vec<f64>| crate::vec_bytes(v);
        f(&self.mass)
            + f(&self.inv_mass)
            + f(&self.stiffness)
            + f(&self.damping)
            + crate::vec_bytes(&self.gravity)
            + f(&self.drag)
            + f(&self.friction)
            + f(&self.restitution)
            + f(&self.body_friction)
            + f(&self.body_restitution)
    }
}
