//! Contact between particles of bodies: radii, bodies and lattice places, and the penalty's κ.

use crate::scene::BodyContact;

/// Contact between particles of bodies: each particle's radius and place, and the rule that
/// decides which pairs may touch (docs/physics.md, "Contact between bodies").
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Contacts {
    /// r_i, metres; 0 touches no particle.
    pub radius: Vec<f64>,
    /// The body of each particle (an index into `Model::bodies`).
    pub body: Vec<u32>,
    /// Lattice coordinates of each particle of a cuboid or a mesh body; `None` for a
    /// `particles` body.
    pub lattice: Vec<Option<[i32; 3]>>,
    /// Whether each body's particles touch each other.
    pub self_contact: Vec<bool>,
    /// The laws of the contact.
    pub laws: BodyContact,
}

/// Self-contact ignores pairs of a cuboid this close on the lattice (Chebyshev distance, in
/// cells): the particles a spring joins (up to two cells apart) and their neighbours at rest.
pub const SELF_CONTACT_EXCLUSION: i32 = 2;

/// κ of the penalty force between bodies in contact, in units of m_red/h², in the explicit
/// integrators' stages (ω h = √κ ≈ 0.32): both backends' (docs/physics.md, "Contact between
/// bodies").
pub const PENALTY: f64 = 0.1;

/// κ inside implicit Euler's solve, where the pair is a linearised spring like any other:
/// backward Euler damps any stiffness, and a stiff penalty keeps the overlap under load small
/// at large steps (κ = 100 lets a pile at h = 1/60 s sink to 0.79 R; 10⁴ makes the
/// linearisation at the step start too coarse and the pile never settles).
pub const PENALTY_IMPLICIT: f64 = 1000.0;

/// κ of the penalty in `integrator`'s steps ([`PENALTY_IMPLICIT`] for implicit Euler, else
/// [`PENALTY`]); the response between bodies presses its friction with the same penalty.
pub fn penalty(integrator: crate::Integrator) -> f64 {
    if integrator == crate::Integrator::ImplicitEuler {
        PENALTY_IMPLICIT
    } else {
        PENALTY
    }
}

/// The overlap, as a fraction of R, that the response between bodies leaves to the penalty
/// force. A push is a move without a force, which the springs around it answer with elastic
/// energy, so pushes must stay rare, and short: at 5%, implicit Euler's pile in the bowl at
/// h = 1/60 s gains up to 1.5 J in a step, at 10% 0.08 J (of 206 J), and 1.25 J when a push
/// triggered at 10% goes on to 5%.
pub const SLOP: f64 = 0.1;

impl Contacts {
    /// Whether any pair can ever touch: a particle with a radius in a body with
    /// `self_contact`, or in two different bodies.
    pub fn enabled(&self) -> bool {
        let mut with_radius = self
            .radius
            .iter()
            .zip(&self.body)
            .filter(|(r, _)| **r > 0.0)
            .map(|(_, b)| *b);
        let Some(first) = with_radius.next() else {
            return false;
        };
        self.self_contact.iter().any(|&s| s) || with_radius.any(|b| b != first)
    }
}
