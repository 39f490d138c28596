//! Deterministic parallel sums: fixed-size chunks whose partial sums are added in chunk order,
//! so the result does not depend on the thread count (the GPU twins reduce per workgroup the
//! same way).

use rayon::prelude::*;

/// Terms per chunk: small enough that a CG vector of a 22³ cube (10,648 particles) gives each
/// of a few threads several chunks.
const CHUNK: usize = 2048;
/// Running sums per chunk: term i goes to sum i mod `LANES`, and the sums are added in a fixed
/// tree at the chunk's end. One running sum waits on each addition's latency; eight
/// independent ones run side by side (and in vector registers), in an order that is still
/// fixed.
const LANES: usize = 8;

/// Σ term(i) for i in 0..n, in a fixed order of fixed chunks.
pub fn chunked_sum(n: usize, term: impl Fn(usize) -> f64 + Sync) -> f64 {
    in_chunk_order(
        (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| chunk_sum(c * CHUNK, ((c + 1) * CHUNK).min(n), &mut &term)),
    )
}

/// Writes `out[i] = value(i).0` and returns Σ `value(i).1`, the same bits as [`chunked_sum`] of
/// those terms: one pass that fills a vector and sums a product with it (a preconditioner's
/// output and CG's rᵀz), where two passes would read the vector back.
pub fn fill_and_sum<T: Send>(out: &mut [T], value: impl Fn(usize) -> (T, f64) + Sync) -> f64 {
    in_chunk_order(out.par_chunks_mut(CHUNK).enumerate().map(|(c, chunk)| {
        let start = c * CHUNK;
        chunk_sum(start, start + chunk.len(), &mut |i| {
            let (v, term) = value(i);
            chunk[i - start] = v;
            term
        })
    }))
}

/// The sum of the chunks' partial sums, added in chunk order.
fn in_chunk_order(partials: impl IndexedParallelIterator<Item = f64>) -> f64 {
    thread_local! {
        /// The partial sums of the last call on this thread: reused, so that the sums inside
        /// a step (conjugate gradients' dot products) allocate nothing after the first.
        static PARTIAL: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let sum = |partial: &mut Vec<f64>| {
        partials.collect_into_vec(partial);
        partial.iter().sum()
    };
    PARTIAL.with(|cell| match cell.try_borrow_mut() {
        Ok(mut partial) => sum(&mut partial),
        // A sum started while this thread waits inside another: a buffer of its own.
        Err(_) => sum(&mut Vec::new()),
    })
}

/// Σ term(i) for i in start..end (start a multiple of [`LANES`]) in [`LANES`] running sums.
#[inline(always)]
fn chunk_sum(start: usize, end: usize, term: &mut impl FnMut(usize) -> f64) -> f64 {
    let mut sums = [0.0; LANES];
    let mut i = start;
    while i + LANES <= end {
        for (l, s) in sums.iter_mut().enumerate() {
            *s += term(i + l);
        }
        i += LANES;
    }
    for (s, j) in sums.iter_mut().zip(i..end) {
        *s += term(j);
    }
    let [a, b, c, d, e, f, g, h] = sums;
    ((a + b) + (c + d)) + ((e + f) + (g + h))
}

#[cfg(test)]
mod tests {
    use super::{chunked_sum, fill_and_sum};

    /// Exact where every partial sum is exact, and the same bits for any thread count where
    /// the order matters (terms of very different sizes, on either side of a chunk's and a
    /// lane's boundary).
    #[test]
    fn chunked_sums_are_exact_and_do_not_depend_on_threads() {
        for n in [0, 1, 7, 8, 9, 2047, 2048, 2049, 10_648] {
            let exact = chunked_sum(n, |i| i as f64);
            assert_eq!(exact, (n * n.saturating_sub(1) / 2) as f64, "{n}");
            let term = |i: usize| (i as f64 * 0.37).sin() * 10f64.powi((i % 23) as i32 - 11);
            let sums: Vec<u64> = (1..=5)
                .map(|threads| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .expect("thread pool");
                    pool.install(|| chunked_sum(n, term)).to_bits()
                })
                .collect();
            assert!(sums.iter().all(|&s| s == sums[0]), "{n}: {sums:?}");
            let plain: f64 = (0..n).map(term).sum();
            assert!((f64::from_bits(sums[0]) - plain).abs() <= 1e-12 * (1.0 + plain.abs()));
        }
    }

    /// A filled vector's values and its sum's bits are the same as those of the values and
    /// the chunked sum computed apart, for any thread count.
    #[test]
    fn fill_and_sum_gives_the_chunked_sums_bits() {
        let term = |i: usize| (i as f64 * 0.61).cos() * 10f64.powi((i % 19) as i32 - 9);
        for n in [0, 5, 2047, 2048, 2049, 10_648] {
            for threads in 1..=4 {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("thread pool");
                let mut out = vec![0.0; n];
                let sum = pool.install(|| fill_and_sum(&mut out, |i| (2.0 * term(i), term(i))));
                assert_eq!(
                    sum.to_bits(),
                    chunked_sum(n, term).to_bits(),
                    "{n}, {threads}"
                );
                assert!((0..n).all(|i| out[i] == 2.0 * term(i)), "{n}, {threads}");
            }
        }
    }
}
