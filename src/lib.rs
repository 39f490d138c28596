//! `softbody`: mass-spring soft bodies, simulated on the CPU (f64, rayon) or a GPU (wgpu).
//!
//! The crate ties the pieces together for programs that embed it and for the `softbody` CLI:
//! run a scene file to kept frames with the [`service`] (what the CLI, sweeps and Python call),
//! or load a [`Scene`] (changing its values with [`Setting`]s and [`Overrides`]), open a
//! [`Solver`] on a [`Backend`], and [`run`](run::run) it frame by frame into a
//! [`FrameSink`](output::FrameSink)
//! (JSON Lines, CSV, NPZ, or VTK/PLY/OBJ series; JSON Lines read back by
//! [`output::jsonl::Reader`]), or measure the integrators against a converged reference with a
//! [`compare::Study`]. Any value of a scene file can be changed by its key path with a
//! [`Setting`] ([`load_scene`]), and a [`sweep`] runs a scene many times with values changed.
//!
//! ```
//! use softbody::{Backend, Scene, Solver};
//! let scene = Scene::from_toml(r#"
//!     [simulation]
//!     integrator = "symplectic-euler"
//!     dt = 0.001
//!     duration = 0.5
//!     [[body]]
//!     kind = "cuboid"
//!     size = [1.0, 1.0, 1.0]
//!     resolution = [4, 4, 4]
//!     center = [0.0, 1.0, 0.0]
//!     mass = 1.0
//!     structural = { stiffness = 500.0, damping = 1.0 }
//!     shear = { stiffness = 500.0, damping = 1.0 }
//!     [[terrain]]
//!     kind = "plane"
//!     normal = [0.0, 1.0, 0.0]
//! "#, "inline.toml".as_ref()).unwrap();
//! let mut solver = softbody::open(&scene, Backend::Cpu, None).unwrap();
//! solver.advance(500).unwrap();
//! let lowest = solver.state().unwrap().x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
//! assert!(lowest > -1e-9); // resting on the ground, not through it
//! ```
#![warn(missing_docs)]

pub mod benchmark;
pub mod checkpoint;
pub mod compare;
mod fingerprint;
pub mod fit;
pub mod grad;
pub mod guard;
pub mod lock;
pub mod output;
mod overrides;
pub mod run;
pub mod service;
pub mod sweep;
pub mod warnings;

use std::fmt;
use std::str::FromStr;

/// The vector types of the API (`State::x` is a `Vec<glam::DVec3>`), so that an embedder uses
/// the same version.
pub use glam;
pub use overrides::{Overrides, Setting, load_scene, scene_from_toml, scene_text};
/// The CPU solver crate.
pub use softbody_cpu as cpu;
pub use softbody_cpu::CpuSolver;
/// The GPU solver crate.
pub use softbody_gpu as gpu;
pub use softbody_gpu::{GpuError, GpuSolver};
/// The scene crate: format, validation, topology, model.
pub use softbody_scene as scene;
pub use softbody_scene::{
    Controls, Energies, Instability, Integrator, Model, Preconditioner, Scene, SceneError, Solver,
    State, Statistics, StepError,
};
/// The terrain crate: point queries, the heightfield split rule, signed-distance grids.
pub use softbody_terrain as terrain;
/// The TOML crate of [`Setting`] values, so that an embedder uses the same version.
pub use toml;

// Every Rust snippet of the README and of the guide's embedding page compiles as a doc-test (and runs,
// unless it says `no_run`); docs/physics.md holds equations, no code.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
struct Readme;
#[cfg(doctest)]
#[doc = include_str!("../docs/guide/embedding.md")]
struct Embedding;

/// Which solver runs a scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Backend {
    /// The CPU reference solver (f64).
    #[default]
    Cpu,
    /// The wgpu compute-shader solver (f32).
    Gpu,
}

impl Backend {
    /// The name used on the command line and in output headers.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu => "gpu",
        }
    }
}

impl fmt::Display for Backend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Backend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(Backend::Cpu),
            "gpu" => Ok(Backend::Gpu),
            _ => Err(format!("unknown backend `{s}`; expected `cpu` or `gpu`")),
        }
    }
}

/// Why a solver could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The CPU thread pool could not be built.
    #[error("cannot start {threads} CPU threads: {source}")]
    Threads {
        /// Threads asked for.
        threads: usize,
        /// Why.
        source: softbody_cpu::ThreadPoolBuildError,
    },
    /// The GPU solver could not be opened: no usable adapter
    /// ([`GpuError::no_usable_gpu`]), or a scene beyond what it runs (adapter limits; implicit
    /// Euler on an adapter without indirect dispatch).
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// Builds the model of `scene` and opens a solver for it on `backend`; `threads` applies to
/// the CPU (all cores when `None`); the GPU takes the adapter wgpu picks (`WGPU_BACKEND`,
/// `WGPU_POWER_PREF` steer it).
///
/// The GPU when there is one, else the CPU, behind the same [`Solver`]:
///
/// ```
/// use softbody::{Backend, Scene};
/// let scene = Scene::from_file("scenes/jelly-on-ground.toml")?;
/// let mut solver = match softbody::open(&scene, Backend::Gpu, None) {
///     Ok(gpu) => gpu,
///     Err(e) => {
///         eprintln!("{e}; on the CPU instead");
///         softbody::open(&scene, Backend::Cpu, None)?
///     }
/// };
/// solver.advance(100)?;
/// assert_eq!(solver.steps_taken(), 100);
/// let x = &solver.state()?.x; // metres, one per particle
/// assert_eq!(x.len(), 216);
/// assert!(x.iter().all(|p| p.is_finite()));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn open(
    scene: &Scene,
    backend: Backend,
    threads: Option<usize>,
) -> Result<Box<dyn Solver>, OpenError> {
    let (model, state) = Model::build(scene);
    match backend {
        Backend::Cpu => {
            let solver =
                CpuSolver::new(model, state, threads).map_err(|source| OpenError::Threads {
                    threads: threads.unwrap_or(0),
                    source,
                })?;
            Ok(Box::new(solver))
        }
        Backend::Gpu => Ok(Box::new(GpuSolver::new(model, state)?)),
    }
}
