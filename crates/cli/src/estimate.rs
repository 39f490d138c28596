//! What `softbody check` says a run will cost, from the scene's counts alone (memory, output,
//! time), and the pieces of large cuboids it finds the stable step on, so that checking a
//! scene never costs what running it does.

use softbody::scene::{BodyShape, Cuboid, Scene};
use softbody::{Integrator, scene::model::estimated_scene_bytes};

/// The most particles a side of the piece of a cuboid that the stable step is found on.
/// Every spring family reaches two cells, so a particle two from each face has all its
/// springs: the piece holds the lattice's stiffest particle, and the guaranteed bound is the
/// whole cuboid's. Its stiffest mode is a wave of a few cells: the estimate on a 32-a-side
/// piece is within 0.5 % of the whole cuboid's (0.1 % above it at 40³, 0.4 % at 100³, 0.45 %
/// at 200³; a 16-a-side piece was 1.3 % above), where the whole cuboid's takes 36 s and
/// 1.5 GB at 200³.
pub const PIECE: u32 = 32;

/// Bytes a particle takes in a JSON Lines frame: its position and velocity, six numbers at up
/// to 17 significant digits (124 B on average on `scenes/jelly-on-slope.toml`'s frames, 129 B
/// at most).
pub const JSONL_BYTES_PER_PARTICLE: u64 = 128;

/// Particle-steps a second of an integrator on the CPU on two cores, conservative: the slowest
/// figures of BENCHMARKS.md. Symplectic and explicit Euler: 8.0 M (27 cubes in a bowl, body
/// contact taking 30 % of the step; lone cubes run at 13–90 M); midpoint and RK4 evaluate the
/// forces two and four times a step. Implicit Euler: 0.5 M (0.53 M on the mesh torus, 0.60 M
/// on the 46³ cube at its slowest).
pub fn particle_steps_per_second(integrator: Integrator) -> f64 {
    use Integrator::*;
    match integrator {
        ExplicitEuler | SymplecticEuler => 8.0e6,
        Midpoint => 4.0e6,
        Rk4 => 2.0e6,
        ImplicitEuler => 0.5e6,
    }
}

/// A run's estimated cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cost {
    /// What the CPU solver holds, bytes (`estimated_scene_bytes`).
    pub memory: u64,
    /// The memory this process may still allocate, and what limits it.
    pub available: Option<(u64, &'static str)>,
    /// The frames as JSON Lines (the default format), bytes, header left out.
    pub output: u64,
    /// Wall-clock seconds of the stepping on two cores.
    pub seconds: f64,
}

/// The cost of running `scene`, from its counts.
pub fn cost(scene: &Scene) -> Cost {
    let sim = &scene.simulation;
    let particles = scene.particle_count();
    Cost {
        memory: estimated_scene_bytes(scene),
        available: softbody::scene::memory::available_memory(),
        output: sim
            .frame_count()
            .saturating_mul(particles)
            .saturating_mul(JSONL_BYTES_PER_PARTICLE),
        seconds: sim.steps() as f64 * particles as f64 / particle_steps_per_second(sim.integrator),
    }
}

/// `scene` with each cuboid of more than [`PIECE`] particles a side cut to a piece of the same
/// lattice: the same spacing, springs and mass per particle, at most [`PIECE`] particles a side
/// and no pinned particles (they would name particles the piece does not have; the stable step
/// is that of the particles that move). `None` when no cuboid is that large.
pub fn pieces(scene: &Scene) -> Option<Scene> {
    let mut cut = scene.clone();
    let mut any = false;
    for body in &mut cut.bodies {
        if let BodyShape::Cuboid(c) = &mut body.shape
            && c.resolution.iter().any(|&r| r > PIECE)
        {
            *c = piece(c);
            body.pinned.clear();
            any = true;
        }
    }
    any.then_some(cut)
}

fn piece(c: &Cuboid) -> Cuboid {
    let resolution = c.resolution.map(|r| r.min(PIECE));
    let mut size = c.size;
    for axis in 0..3 {
        size[axis] *= f64::from(resolution[axis] - 1) / f64::from(c.resolution[axis] - 1);
    }
    let count = |r: [u32; 3]| r.iter().map(|&n| f64::from(n)).product::<f64>();
    Cuboid {
        resolution,
        size,
        mass: c.mass * count(resolution) / count(c.resolution),
        ..c.clone()
    }
}

/// `bytes` in the largest binary unit that keeps a number of at least 1: "512 B", "1.5 KiB",
/// "11.2 GiB".
pub fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

/// `seconds` as "0.42 s", "3.5 min", "2.1 h" or "3.0 days".
pub fn human_seconds(seconds: f64) -> String {
    match seconds {
        s if s < 60.0 => format!("{s:.2} s"),
        s if s < 3600.0 => format!("{:.1} min", s / 60.0),
        s if s < 86400.0 => format!("{:.1} h", s / 3600.0),
        s => format!("{:.1} days", s / 86400.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_durations_read_in_their_unit() {
        assert_eq!(human_bytes(512), "512 B");
        assert_eq!(human_bytes(1536), "1.5 KiB");
        assert_eq!(human_bytes(12 << 30), "12.0 GiB");
        assert_eq!(human_seconds(0.4249), "0.42 s");
        assert_eq!(human_seconds(210.0), "3.5 min");
        assert_eq!(human_seconds(7560.0), "2.1 h");
        assert_eq!(human_seconds(3.0 * 86400.0), "3.0 days");
    }
}
