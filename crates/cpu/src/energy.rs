//! Energies of a state: kinetic ½Σm|v|², gravitational −Σm g·x, elastic ½Σk_s(|d| − r)².
//!
//! Sums are [`chunked_sum`]s, and a lattice body's springs (which the model keeps as a stencil,
//! not a list) are summed plane by plane in parallel and the planes' sums added in plane order
//! ([`energy_lattices`]): the same bits for any thread count.
//!
//! Twin of `crates/gpu/shaders/energy.wgsl`: `energy_particles` (kinetic and gravitational terms),
//! `energy_springs` (a spring list) and `energy_lattices` (the lattices, on the GPU's stencil
//! route).

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Energies, Lattice, Model, State};

use crate::reduce::chunked_sum;

/// The three energies of `state`.
pub fn energies(model: &Model, state: &State) -> Energies {
    let g: DVec3 = model.simulation.gravity;
    let (m, x, v) = (&model.mass, &state.x, &state.v);
    let s = model.listed_springs();
    Energies {
        kinetic: 0.5 * chunked_sum(m.len(), |i| m[i] * v[i].length_squared()),
        gravitational: -chunked_sum(m.len(), |i| m[i] * g.dot(x[i])),
        elastic: 0.5
            * (chunked_sum(s.len(), |k| {
                stretch2(x, s.a[k], s.b[k], s.rest[k], s.stiffness[k])
            }) + energy_lattices(model.lattices(), x)),
    }
}

/// Σ k_s(|x_a − x_b| − r)² over the springs of `lattices` at positions `x`: twice their
/// elastic energy. Each lattice's z-planes in parallel, their sums added in plane order.
pub fn energy_lattices(lattices: &[Lattice], x: &[DVec3]) -> f64 {
    (lattices.iter())
        .map(|l| {
            let planes: Vec<f64> = (0..l.dims[2])
                .into_par_iter()
                .map(|k| {
                    let mut sum = 0.0;
                    l.for_each_spring(k..k + 1, |a, b, s| {
                        sum += stretch2(x, a, b, s.rest, s.stiffness)
                    });
                    sum
                })
                .collect();
            planes.iter().sum::<f64>()
        })
        .sum()
}

/// k_s(|x_a − x_b| − r)² of one spring.
fn stretch2(x: &[DVec3], a: u32, b: u32, rest: f64, stiffness: f64) -> f64 {
    let stretch = x[a as usize].distance(x[b as usize]) - rest;
    stiffness * stretch * stretch
}
