//! The broad phase of contact between particles: every pair (i, j), i < j, closer than the sum
//! of their contact radii, |x_i − x_j| < r_i + r_j, and admitted by the caller's rule (different
//! bodies, or self-contact beyond the rest neighbourhood).
//!
//! A uniform grid of cell size c = 2·r_max + s, searched for the admitted pairs closer than
//! r_i + r_j + s (s, the skin, is r_max): they lie in the same or adjacent cells. Each call
//! keeps the candidates in contact now, and searches the grid again only once some particle
//! has moved more than s/2 since the last search (a Verlet list), which a body at rest never
//! does. Cells are hashed into a table of a
//! power of two ≥ 2n buckets (a particle far from the others costs nothing), and the particles
//! are counting-sorted by bucket: a count per bucket, an exclusive prefix sum, a scatter in
//! ascending particle order. Particle i then reads the buckets of the 27 cells around its own
//! (a bucket two of them share, once) and keeps the j > i that pass the
//! distance test and the rule, in parallel over ranges of particles whose pairs are then joined
//! in range order. Pairs come out sorted by (i, j) — a function of the positions alone, the
//! order the contact forces are gathered in, whatever the thread count — and the buffers are
//! reused from step to step, so a step allocates nothing once they have grown.

use glam::{DVec3, IVec3};
use rayon::prelude::*;

/// The grid and its buffers.
#[derive(Debug, Default)]
pub struct BroadPhase {
    /// First entry of each bucket in `sorted` (exclusive prefix sum; one more than buckets).
    starts: Vec<u32>,
    /// Particle indices sorted by bucket, ascending within a bucket.
    sorted: Vec<u32>,
    /// Each particle's bucket.
    bucket_of: Vec<u32>,
    /// Each particle's cell.
    cell_of: Vec<IVec3>,
    /// Per range of particles (one rayon task each): the candidate partners of the particle
    /// being scanned, and the range's pairs.
    ranges: Vec<(Vec<u32>, Vec<[u32; 2]>)>,
    /// The admitted pairs within r_i + r_j + skin at the last search, sorted by (i, j): the
    /// ranges' pairs in range order.
    candidates: Vec<[u32; 2]>,
    /// The positions and the largest radius of the last search.
    reference: Vec<DVec3>,
    reference_radius: f64,
    /// Searches so far.
    searches: u64,
    /// The pairs in contact now, sorted by (i, j).
    pairs: Vec<[u32; 2]>,
}

/// The skin, as a fraction of the largest radius: the grid is searched again only when some
/// particle has moved more than half of it since the last search.
const SKIN: f64 = 1.0;

/// Particles per task of the pair search: about four tasks per thread, at least 256 particles.
fn range_len(n: usize) -> usize {
    n.div_ceil(4 * rayon::current_num_threads()).max(256)
}

impl BroadPhase {
    /// Empty: the buffers grow on the first call.
    pub fn new() -> BroadPhase {
        BroadPhase::default()
    }

    /// The pairs (i, j), i < j, sorted, with |x_i − x_j| < r_i + r_j and `admit(i, j)`.
    /// Particles of radius 0 touch nothing. Positions must be finite; `radius` and `admit` must
    /// be the same at every call (they are the model's).
    ///
    /// The grid is searched only when the candidates may be stale: first, or when a particle
    /// has moved more than half the skin s since the last search. A pair in contact now,
    /// d < R, was then closer than R + 2·(s/2), so it is among the candidates of that search,
    /// which kept every admitted pair within R + s; this call filters them by d < R.
    pub fn pairs(
        &mut self,
        x: &[DVec3],
        radius: &[f64],
        admit: impl Fn(usize, usize) -> bool + Sync,
    ) -> &[[u32; 2]] {
        assert_eq!(x.len(), radius.len());
        self.pairs.clear();
        let r_max = radius.iter().copied().fold(0.0, f64::max);
        if r_max <= 0.0 || x.len() < 2 {
            return &self.pairs;
        }
        let skin = SKIN * r_max;
        let moved = || {
            x.par_iter()
                .zip(&self.reference)
                .map(|(a, b)| a.distance_squared(*b))
                .reduce(|| 0.0, f64::max)
        };
        let stale = self.reference.len() != x.len()
            || self.reference_radius != r_max
            || moved() > 0.25 * skin * skin;
        if stale {
            self.search(x, radius, skin, admit);
            self.reference.clear();
            self.reference.extend_from_slice(x);
            self.reference_radius = r_max;
            self.searches += 1;
        }
        self.pairs
            .extend(self.candidates.iter().copied().filter(|&[i, j]| {
                let (i, j) = (i as usize, j as usize);
                let reach = radius[i] + radius[j];
                x[i].distance_squared(x[j]) < reach * reach
            }));
        &self.pairs
    }

    /// How many times the grid has been searched.
    pub fn searches(&self) -> u64 {
        self.searches
    }

    /// The admitted pairs closer than r_i + r_j + `margin`, into `candidates`.
    fn search(
        &mut self,
        x: &[DVec3],
        radius: &[f64],
        margin: f64,
        admit: impl Fn(usize, usize) -> bool + Sync,
    ) {
        let r_max = radius.iter().copied().fold(0.0, f64::max);
        let cell = 2.0 * r_max + margin;
        let buckets = (2 * x.len()).next_power_of_two();
        self.sort(x, cell, buckets);
        let len = range_len(x.len());
        self.ranges
            .resize_with(x.len().div_ceil(len), Default::default);
        let (starts, sorted, cell_of) = (&self.starts[..], &self.sorted[..], &self.cell_of[..]);
        self.ranges
            .par_iter_mut()
            .enumerate()
            .for_each(|(r, (partners, pairs))| {
                pairs.clear();
                for i in r * len..((r + 1) * len).min(x.len()) {
                    if radius[i] <= 0.0 {
                        continue;
                    }
                    partners.clear();
                    for d in NEIGHBOURS {
                        let b = bucket(cell_of[i] + d, buckets) as usize;
                        let run = starts[b] as usize..starts[b + 1] as usize;
                        partners.extend(sorted[run].iter().copied().filter(|&j| j as usize > i));
                    }
                    // Two of the cells may share a bucket: its particles then come twice.
                    partners.sort_unstable();
                    partners.dedup();
                    for &j in partners.iter() {
                        let j = j as usize;
                        let reach = radius[i] + radius[j] + margin;
                        if radius[j] > 0.0
                            && x[i].distance_squared(x[j]) < reach * reach
                            && admit(i, j)
                        {
                            pairs.push([i as u32, j as u32]);
                        }
                    }
                }
            });
        self.candidates.clear();
        for (_, pairs) in &self.ranges {
            self.candidates.extend_from_slice(pairs);
        }
    }

    /// The counting sort of the particles by bucket.
    fn sort(&mut self, x: &[DVec3], cell: f64, buckets: usize) {
        let n = x.len();
        self.cell_of.clear();
        self.cell_of.extend(x.iter().map(|p| cell_index(*p, cell)));
        self.bucket_of.clear();
        self.bucket_of
            .extend(self.cell_of.iter().map(|c| bucket(*c, buckets)));
        // starts[b + 1] counts bucket b, then becomes its first entry (an exclusive prefix sum
        // shifted by one); the scatter advances starts[b + 1] to the entry after b's last, the
        // first of b + 1, which leaves starts[b] the first entry of b for every b.
        self.starts.clear();
        self.starts.resize(buckets + 1, 0);
        for &b in &self.bucket_of {
            if let Some(after) = self.starts.get_mut(b as usize + 2) {
                *after += 1;
            }
        }
        for k in 1..=buckets {
            self.starts[k] += self.starts[k - 1];
        }
        self.sorted.clear();
        self.sorted.resize(n, 0);
        // In ascending particle order: each bucket's run is ascending.
        for (i, &b) in self.bucket_of.iter().enumerate() {
            let slot = &mut self.starts[b as usize + 1];
            self.sorted[*slot as usize] = i as u32;
            *slot += 1;
        }
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        (self.starts.capacity() * 4
            + self.sorted.capacity() * 4
            + self.bucket_of.capacity() * 4
            + self.cell_of.capacity() * 12
            + self.pairs.capacity() * 8
            + self.candidates.capacity() * 8
            + self.reference.capacity() * 24) as u64
            + self
                .ranges
                .iter()
                .map(|(c, p)| (c.capacity() * 4 + p.capacity() * 8) as u64)
                .sum::<u64>()
    }
}

/// The 27 cell offsets around a cell, itself included.
const NEIGHBOURS: [IVec3; 27] = {
    let mut d = [IVec3::ZERO; 27];
    let mut k = 0;
    while k < 27 {
        d[k] = IVec3::new(k as i32 % 3 - 1, (k as i32 / 3) % 3 - 1, k as i32 / 9 - 1);
        k += 1;
    }
    d
};

/// The cell holding `p`; coordinates beyond ±2³⁰ cells are clamped (such a particle is far
/// from every other, and a shared cell only adds candidates that the distance test rejects).
fn cell_index(p: DVec3, cell: f64) -> IVec3 {
    let limit = f64::from(1 << 30);
    let c = (p / cell)
        .floor()
        .clamp(DVec3::splat(-limit), DVec3::splat(limit));
    c.as_ivec3()
}

/// The bucket of a cell: a multiplicative hash of its coordinates (the primes of Teschner et
/// al., "Optimized Spatial Hashing for Collision Detection of Deformable Objects", 2003), modulo
/// the power-of-two table size.
fn bucket(c: IVec3, buckets: usize) -> u32 {
    let h = (c.x as u32).wrapping_mul(73_856_093)
        ^ (c.y as u32).wrapping_mul(19_349_663)
        ^ (c.z as u32).wrapping_mul(83_492_791);
    h & (buckets as u32 - 1)
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use softbody_testkit::Rng;

    use super::BroadPhase;

    /// The pairs by testing every pair.
    fn brute_force(x: &[DVec3], r: &[f64], admit: impl Fn(usize, usize) -> bool) -> Vec<[u32; 2]> {
        let mut pairs = Vec::new();
        for i in 0..x.len() {
            for j in i + 1..x.len() {
                let reach = r[i] + r[j];
                if r[i] > 0.0
                    && r[j] > 0.0
                    && x[i].distance_squared(x[j]) < reach * reach
                    && admit(i, j)
                {
                    pairs.push([i as u32, j as u32]);
                }
            }
        }
        pairs
    }

    /// A reproducible cloud in a cube of `size`; every 17th particle has radius 0.
    fn cloud(n: usize, size: f64, seed: u64) -> (Vec<DVec3>, Vec<f64>) {
        let mut rng = Rng::new(seed);
        let x = (0..n)
            .map(|_| rng.in_box(DVec3::ZERO, DVec3::splat(size)))
            .collect();
        let r = (0..n)
            .map(|k| {
                if k % 17 == 0 {
                    0.0
                } else {
                    rng.range(0.005, 0.02)
                }
            })
            .collect();
        (x, r)
    }

    #[test]
    fn the_grid_finds_exactly_the_pairs_of_the_brute_force() {
        let mut bp = BroadPhase::new();
        for (n, size, seed) in [(2000, 0.5, 1), (500, 0.1, 2), (300, 5.0, 3), (3, 0.01, 4)] {
            let (mut x, r) = cloud(n, size, seed);
            // One particle far from the rest, one at a negative cell, one on a cell boundary.
            x[1] = DVec3::new(1e9, -3e8, 7.0);
            x[2] = DVec3::new(-0.3, -0.04, -0.0);
            let admit = |i: usize, j: usize| !(i + j).is_multiple_of(5);
            let want = brute_force(&x, &r, admit);
            let got = bp.pairs(&x, &r, admit).to_vec();
            assert_eq!(got, want, "n = {n}, size = {size}");
            if n == 2000 {
                assert!(
                    want.len() > 500,
                    "the dense cloud has pairs: {}",
                    want.len()
                );
            }
        }
    }

    /// Particles moving in small random steps, some beyond half the skin: every call's pairs
    /// are the brute force's, and the grid is searched again only on some calls.
    #[test]
    fn moving_particles_keep_their_pairs_exact() {
        let mut bp = BroadPhase::new();
        let (mut x, r) = cloud(600, 0.3, 5);
        let mut rng = Rng::new(6);
        let admit = |i: usize, j: usize| !(i + j).is_multiple_of(7);
        for call in 0..60 {
            let step = if call % 20 == 19 { 0.02 } else { 0.001 };
            for p in &mut x {
                *p += rng.vec(step);
            }
            assert_eq!(
                bp.pairs(&x, &r, admit).to_vec(),
                brute_force(&x, &r, admit),
                "call {call}"
            );
        }
        let searches = bp.searches();
        assert!(
            (3..60).contains(&searches),
            "{searches} searches in 60 calls"
        );
    }

    #[test]
    fn no_radius_no_pairs() {
        let mut bp = BroadPhase::new();
        let x = vec![DVec3::ZERO; 4];
        assert!(bp.pairs(&x, &[0.0; 4], |_, _| true).is_empty());
        assert_eq!(
            bp.pairs(&x, &[0.1, 0.0, 0.1, 0.1], |_, _| true),
            &[[0, 2], [0, 3], [2, 3]]
        );
    }
}
