//! Energies of a state: kinetic ½Σm|v|², gravitational −Σm g·x, elastic ½Σk_s(|d| − r)².
//!
//! Sums are [`chunked_sum`]s, and a cuboid's springs (which the model keeps as a stencil, not
//! a list) are summed plane by plane in parallel and the planes' sums added in plane order:
//! the same bits for any thread count.

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Energies, Model, State};

use crate::reduce::chunked_sum;

/// The three energies of `state`.
pub fn energies(model: &Model, state: &State) -> Energies {
    let g: DVec3 = model.simulation.gravity;
    let (m, x, v) = (&model.mass, &state.x, &state.v);
    let stretch2 = |a: u32, b: u32, rest: f64, stiffness: f64| {
        let stretch = x[a as usize].distance(x[b as usize]) - rest;
        stiffness * stretch * stretch
    };
    let lattices: f64 = (model.lattices().iter())
        .map(|l| {
            let planes: Vec<f64> = (0..l.dims[2])
                .into_par_iter()
                .map(|k| {
                    let mut sum = 0.0;
                    l.for_each_spring(k..k + 1, |a, b, s| {
                        sum += stretch2(a, b, s.rest, s.stiffness)
                    });
                    sum
                })
                .collect();
            planes.iter().sum::<f64>()
        })
        .sum();
    let s = model.listed_springs();
    Energies {
        kinetic: 0.5 * chunked_sum(m.len(), |i| m[i] * v[i].length_squared()),
        gravitational: -chunked_sum(m.len(), |i| m[i] * g.dot(x[i])),
        elastic: 0.5
            * (chunked_sum(s.len(), |k| {
                stretch2(s.a[k], s.b[k], s.rest[k], s.stiffness[k])
            }) + lattices),
    }
}
