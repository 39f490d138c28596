//! Deterministic parallel sums: fixed-size chunks whose partial sums are added in chunk order,
//! so the result does not depend on the thread count (the GPU twins reduce per workgroup the
//! same way).

use rayon::prelude::*;

/// Terms per chunk.
const CHUNK: usize = 8192;

/// Σ term(i) for i in 0..n, in a fixed order of fixed chunks.
pub fn chunked_sum(n: usize, term: impl Fn(usize) -> f64 + Sync) -> f64 {
    thread_local! {
        /// The partial sums of the last call on this thread: reused, so that the sums inside
        /// a step (conjugate gradients' dot products) allocate nothing after the first.
        static PARTIAL: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let partials = |partial: &mut Vec<f64>| {
        (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| (c * CHUNK..((c + 1) * CHUNK).min(n)).map(&term).sum())
            .collect_into_vec(partial);
        partial.iter().sum()
    };
    PARTIAL.with(|cell| match cell.try_borrow_mut() {
        Ok(mut partial) => partials(&mut partial),
        // A sum started while this thread waits inside another: a buffer of its own.
        Err(_) => partials(&mut Vec::new()),
    })
}
