//! Control forces: an external force on each particle, frame by frame, the input a run's
//! gradient can be taken with respect to (Python's `run(controls=)`, the adjoint's
//! `Options::controls`).
//!
//! Frame f's forces u_f act in the steps k with frame_step(f) ≤ k < frame_step(f + 1) (step k
//! takes the state after k steps to the next); the last frame's act in none. The force on
//! particle i enters its acceleration as u_{f,i} / m_i, beside gravity, drag and the springs;
//! pinned particles take none. A solver matches steps to frames by its step count, so a
//! restored solver applies each frame's forces as the run it came from did.

use std::sync::Arc;

use glam::DVec3;

use crate::{Model, StepError};

/// F × N external forces for the run of a model (frame f's N first), each frame's held over
/// its steps.
#[derive(Debug, Clone, PartialEq)]
pub struct Controls {
    forces: Arc<[DVec3]>,
    particles: usize,
    /// Each frame's step, `Simulation::frame_step`.
    frame_steps: Arc<[u64]>,
}

impl Controls {
    /// The forces `forces` (F × N for the F frames of the run of `model` and its N particles,
    /// frame-major); [`StepError::Invalid`] unless there is one per particle per frame, each
    /// finite.
    pub fn new(model: &Model, forces: impl Into<Arc<[DVec3]>>) -> Result<Controls, StepError> {
        let forces = forces.into();
        let sim = &model.simulation;
        let frames = sim.frame_count();
        let n = model.len();
        if forces.len() as u64 != frames * n as u64 {
            return Err(StepError::Invalid(format!(
                "controls: {} forces for {frames} frames of {n} particles (F × N = {})",
                forces.len(),
                frames * n as u64
            )));
        }
        if let Some(k) = forces.iter().position(|f| !f.is_finite()) {
            return Err(StepError::Invalid(format!(
                "controls: frame {}'s force on particle {} is not finite ({})",
                k / n.max(1),
                k % n.max(1),
                forces[k]
            )));
        }
        Ok(Controls {
            forces,
            particles: n,
            frame_steps: (0..frames).map(|f| sim.frame_step(f)).collect(),
        })
    }

    /// [`StepError::Invalid`] unless these are controls for the run of `model` (its particles
    /// and its frames' steps): what a solver checks before it takes them.
    pub fn check(&self, model: &Model) -> Result<(), StepError> {
        let sim = &model.simulation;
        let fits = self.particles == model.len()
            && self.frame_steps.len() as u64 == sim.frame_count()
            && self
                .frame_steps
                .iter()
                .enumerate()
                .all(|(f, &s)| s == sim.frame_step(f as u64));
        if fits {
            Ok(())
        } else {
            Err(StepError::Invalid(format!(
                "controls for {} frames of {} particles do not fit this run's {} frames of {}",
                self.frame_steps.len(),
                self.particles,
                sim.frame_count(),
                model.len()
            )))
        }
    }

    /// All the forces, frame-major.
    pub fn forces(&self) -> &[DVec3] {
        &self.forces
    }

    /// Frame `f`'s forces, one per particle.
    pub fn frame(&self, f: usize) -> &[DVec3] {
        &self.forces[f * self.particles..][..self.particles]
    }

    /// The frame whose forces act in step `step`, and the step at which the next frame's take
    /// over; `None` from the last frame's step on (no forces act).
    pub fn at(&self, step: u64) -> Option<(usize, u64)> {
        // frame_steps[0] = 0 ≤ step, so the point is at least 1.
        let f = self.frame_steps.partition_point(|&s| s <= step) - 1;
        self.frame_steps.get(f + 1).map(|&next| (f, next))
    }

    /// The work of frame `f`'s forces between positions `from` and `to`,
    /// W = Σ_i u_{f,i} · (to_i − from_i): exact for a force held constant along any path.
    pub fn work(&self, f: usize, from: &[DVec3], to: &[DVec3]) -> f64 {
        self.frame(f)
            .iter()
            .zip(from.iter().zip(to))
            .map(|(u, (a, b))| u.dot(*b - *a))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Scene;

    fn model(frame_rate: f64) -> Model {
        let text = format!(
            "[simulation]\ndt = 0.01\nduration = 0.1\nframe_rate = {frame_rate}\n\
             [[body]]\nkind = \"cuboid\"\nsize = [1.0, 1.0, 1.0]\nresolution = [2, 2, 2]\n\
             mass = 1.0\nstructural = {{ stiffness = 10.0, damping = 0.0 }}\n"
        );
        let scene = Scene::from_toml(&text, std::path::Path::new("controls.toml")).expect("scene");
        Model::build(&scene).0
    }

    #[test]
    fn each_frames_forces_act_from_its_step_to_the_next_frames() {
        // 10 steps, a frame every 3⅓ (frame_step: 0, 3, 7, 10): the last frame's forces act
        // in no step.
        let m = model(30.0);
        let frames = m.simulation.frame_count() as usize;
        let n = m.len();
        assert_eq!(
            (0..frames as u64)
                .map(|f| m.simulation.frame_step(f))
                .collect::<Vec<_>>(),
            [0, 3, 7, 10]
        );
        let c = Controls::new(&m, vec![DVec3::X; frames * n]).unwrap();
        let at: Vec<_> = (0..11).map(|k| c.at(k)).collect();
        assert_eq!(
            at,
            [
                Some((0, 3)),
                Some((0, 3)),
                Some((0, 3)),
                Some((1, 7)),
                Some((1, 7)),
                Some((1, 7)),
                Some((1, 7)),
                Some((2, 10)),
                Some((2, 10)),
                Some((2, 10)),
                None,
            ]
        );
    }

    #[test]
    fn controls_of_another_shape_or_not_finite_are_refused() {
        let m = model(50.0);
        let (frames, n) = (m.simulation.frame_count() as usize, m.len());
        let short = Controls::new(&m, vec![DVec3::ZERO; frames * n - 1]).unwrap_err();
        assert!(
            short
                .to_string()
                .contains(&format!("for {frames} frames of {n} particles"))
        );
        let mut u = vec![DVec3::ZERO; frames * n];
        u[n + 2].y = f64::NAN;
        let nan = Controls::new(&m, u).unwrap_err();
        assert!(
            nan.to_string().contains("frame 1's force on particle 2"),
            "{nan}"
        );
    }

    #[test]
    fn the_work_is_the_forces_dot_the_displacements() {
        let m = model(50.0);
        let (frames, n) = (m.simulation.frame_count() as usize, m.len());
        let u: Vec<DVec3> = (0..frames * n)
            .map(|k| DVec3::new(k as f64, 1.0, -2.0))
            .collect();
        let c = Controls::new(&m, u).unwrap();
        let from = vec![DVec3::ZERO; n];
        let to = vec![DVec3::new(0.5, 2.0, 1.0); n];
        // Σ_i (f·n + i)·0.5 + 2 − 2 for frame f = 1.
        let expected: f64 = (0..n).map(|i| (n + i) as f64 * 0.5).sum();
        assert_eq!(c.work(1, &from, &to), expected);
    }
}
