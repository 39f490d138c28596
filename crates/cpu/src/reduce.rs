//! Deterministic parallel sums: fixed-size chunks whose partial sums are added in chunk order,
//! so the result does not depend on the thread count (the GPU twins reduce per workgroup the
//! same way).

use rayon::prelude::*;

/// Terms per chunk.
const CHUNK: usize = 8192;

/// Σ term(i) for i in 0..n, in a fixed order of fixed chunks.
pub fn chunked_sum(n: usize, term: impl Fn(usize) -> f64 + Sync) -> f64 {
    let partial: Vec<f64> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| (c * CHUNK..((c + 1) * CHUNK).min(n)).map(&term).sum())
        .collect();
    partial.iter().sum()
}
