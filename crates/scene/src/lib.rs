//! The scene side of `softbody`: the TOML scene format, its validation, the spring topology, and
//! the model and state layout shared by every solver.
//!
//! ```
//! use softbody_scene::{Model, Scene};
//! let scene = Scene::from_toml(r#"
//!     [simulation]
//!     dt = 0.001
//!     duration = 1.0
//!     [[body]]
//!     kind = "cuboid"
//!     size = [1.0, 1.0, 1.0]
//!     resolution = [3, 3, 3]
//!     mass = 1.0
//!     structural = { stiffness = 100.0 }
//! "#, "inline.toml".as_ref()).unwrap();
//! let (model, state) = Model::build(&scene);
//! assert_eq!(model.len(), 27);
//! assert_eq!(model.springs().len(), 54);
//! assert_eq!(state.x.len(), 27);
//! ```
#![warn(missing_docs)]

pub mod controls;
pub mod error;
pub mod format;
pub mod implicit;
mod initial_energy;
pub mod memory;
pub mod mesh;
pub mod model;
pub mod scene;
pub mod shapes;
pub mod solver;
pub mod topology;
mod validate;
pub mod voxel;
mod winding;

use std::fmt;
use std::str::FromStr;

pub use controls::Controls;
pub use error::{Diagnostic, Invalid, KeyPath, Num, SceneError};
pub use format::FrictionModel;
pub use format::SurfaceKind;
pub use implicit::Preconditioner;
pub use model::{
    Adjacency, BodyRange, Contacts, Lattice, LatticeMask, LatticeSpring, Model, Springs, State,
    largest_stable_step,
};
pub use scene::{
    Body, BodyContact, BodyShape, Cuboid, ExplicitSpring, Heightfield, MeshBody, MeshMass,
    ParticleSet, Scene, Simulation, SpringCounts, SpringParams, Terrain, TerrainShape,
    TriangleMesh, rotation_from_degrees,
};
pub use solver::{Energies, History, Instability, Solver, Statistics, StepError, Timer, Timings};

/// The time integrators, by the names scene files and the command line use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// x' = x + h v, v' = v + h a(x, v).
    ExplicitEuler,
    /// v' = v + h a(x, v), x' = x + h v'.
    SymplecticEuler,
    /// The midpoint (RK2) method on (x, v).
    Midpoint,
    /// Classic fourth-order Runge–Kutta on (x, v).
    Rk4,
    /// Backward Euler, linearised once per step and solved by preconditioned CG.
    ImplicitEuler,
}

impl Integrator {
    /// Every integrator, in the order tables list them.
    pub const ALL: [Integrator; 5] = [
        Integrator::ExplicitEuler,
        Integrator::SymplecticEuler,
        Integrator::Midpoint,
        Integrator::Rk4,
        Integrator::ImplicitEuler,
    ];

    /// The name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Integrator::ExplicitEuler => "explicit-euler",
            Integrator::SymplecticEuler => "symplectic-euler",
            Integrator::Midpoint => "midpoint",
            Integrator::Rk4 => "rk4",
            Integrator::ImplicitEuler => "implicit-euler",
        }
    }
}

impl fmt::Display for Integrator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Integrator {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(i) = Integrator::ALL.into_iter().find(|i| i.name() == s) {
            return Ok(i);
        }
        // One spelling everywhere (files, flags, output names): a near miss is answered, not
        // taken.
        let near = s.to_ascii_lowercase().replace('_', "-");
        if let Some(i) = Integrator::ALL.into_iter().find(|i| i.name() == near) {
            return Err(format!("unknown integrator `{s}`; did you mean `{i}`?"));
        }
        let names: Vec<_> = Integrator::ALL.iter().map(|i| i.name()).collect();
        Err(format!(
            "unknown integrator `{s}`; expected one of {}",
            names.join(", ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::Integrator;

    /// Names are the files' spellings; one that differs in case or in `_` for `-` is answered
    /// with the name it means.
    #[test]
    fn integrator_names_parse_and_near_misses_are_answered() {
        assert_eq!("rk4".parse(), Ok(Integrator::Rk4));
        assert_eq!("implicit-euler".parse(), Ok(Integrator::ImplicitEuler));
        assert_eq!(
            "RK4".parse::<Integrator>(),
            Err("unknown integrator `RK4`; did you mean `rk4`?".to_owned())
        );
        assert_eq!(
            "Symplectic_Euler".parse::<Integrator>(),
            Err(
                "unknown integrator `Symplectic_Euler`; did you mean `symplectic-euler`?"
                    .to_owned()
            )
        );
        assert_eq!(
            "verlet".parse::<Integrator>(),
            Err(
                "unknown integrator `verlet`; expected one of explicit-euler, symplectic-euler, \
                 midpoint, rk4, implicit-euler"
                    .to_owned()
            )
        );
    }
}
