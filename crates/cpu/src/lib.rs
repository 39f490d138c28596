//! The CPU reference solver of `softbody`: f64 throughout, parallel with rayon, and the same bits
//! for any thread count.
//!
//! The pipeline of one step reads top to bottom:
//! [`spring_forces`] (one force per spring, gathered per particle) → [`forces`] (gravity, drag,
//! springs, then [`contact`] and friction against each terrain [`Surface`](softbody_terrain::Surface)) → an
//! [`integrators`] step → [`collision_response`] (explicit family) → a finiteness check.
//! Implicit Euler replaces the last four with a linearised backward-Euler solve that treats
//! contacts as velocity constraints.
//!
//! ```
//! use softbody_cpu::CpuSolver;
//! use softbody_scene::{Model, Scene, Solver};
//! let scene = Scene::from_toml(r#"
//!     [simulation]
//!     integrator = "rk4"
//!     dt = 0.001
//!     duration = 0.1
//!     [[body]]
//!     kind = "particles"
//!     positions = [[0.0, 1.0, 0.0]]
//!     masses = [1.0]
//! "#, "inline.toml".as_ref()).unwrap();
//! let (model, state) = Model::build(&scene);
//! let mut solver = CpuSolver::new(model, state, Some(1)).unwrap();
//! solver.advance(100).unwrap();
//! let y = solver.state().unwrap().x[0].y;
//! assert!((y - (1.0 - 0.5 * 9.81 * 0.1 * 0.1)).abs() < 1e-12); // RK4 is exact for free fall
//! ```
#![warn(missing_docs)]

pub mod adjoint;
pub mod body_contact;
pub mod broad_phase;
pub mod collision_response;
pub mod contact;
pub mod energy;
pub mod forces;
pub mod integrators;
mod pipeline;
pub mod reduce;
mod solver;
pub mod spring_forces;
pub mod stable_step;

use rayon::prelude::*;
use softbody_scene::State;

pub use rayon::ThreadPoolBuildError;
pub use solver::CpuSolver;

pub(crate) use softbody_scene::model::vec_bytes;

/// The first particle with a non-finite position or velocity, and which it is.
pub fn first_non_finite(state: &State) -> Option<(usize, &'static str)> {
    let i = state
        .x
        .par_iter()
        .zip(state.v.par_iter())
        .with_min_len(forces::PARTICLE_CHUNK)
        .position_first(|(x, v)| !x.is_finite() || !v.is_finite())?;
    Some((i, non_finite_what(state, i)))
}

fn non_finite_what(state: &State, i: usize) -> &'static str {
    if state.x[i].is_finite() {
        "has a non-finite velocity"
    } else {
        "has a non-finite position"
    }
}

// Solvers move between threads (a batch of runs, a Python binding releasing the GIL).
const _: fn() = || {
    fn send<T: Send>() {}
    send::<CpuSolver>();
};
