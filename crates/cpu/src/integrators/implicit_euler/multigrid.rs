//! Aggregation multigrid on the lattice: the preconditioner of implicit Euler's filtered CG
//! when every particle has lattice coordinates (cuboid and mesh bodies).
//!
//! **Operator.** CG runs in the free subspace of the constraints (S_i the per-particle filter
//! of [`Constraint`]), so the operator multigrid approximates is the filtered one,
//!
//! Â = S A S + (I − S),
//!
//! which equals S A S on the free directions and the identity on the prescribed ones, so the
//! coarse levels see contacts and pins. A is the step's system matrix ([`super::system`]):
//! A = M(1 + h·drag) + Σ_springs B_s ⊗ (e_a − e_b)(e_a − e_b)ᵀ + pair blocks, B_s = β uuᵀ + γ I.
//!
//! **Aggregates.** Fine particle (i, j, k) of body b belongs to coarse node (b, ⌊i/2⌋, ⌊j/2⌋,
//! ⌊k/2⌋); coarse nodes are aggregated again by halving their coordinates, until a level has
//! at most [`COARSEST_NODES`] nodes or stops shrinking (then every body is one node). Node
//! numbers follow the first appearance in the finer level's order, so the hierarchy is a
//! function of the model. P is piecewise constant (each fine value copies its node's).
//!
//! **Coarse operators.** Galerkin, Â_{l+1} = Pᵀ Â_l P, exactly. On the first coarse level, with
//! D_a the fine diagonal block (mass, springs and pairs), node A's diagonal block is
//! Σ_{a∈A} (S_a D_a S_a + I − S_a) − Σ_{springs (a,b) inside A} (S_a B_s S_b + S_b B_s S_a),
//! and a spring (a, b) from node A to node B ≠ A adds −S_a B_s S_b to block (A, B) and its
//! transpose to (B, A). Deeper levels sum the finer level's blocks: (C, D) = Σ_{A∈C, B∈D}
//! Â_l(A, B). The pairs of bodies in contact (which change every step) are lumped: their
//! diagonal blocks are in D_a, their off-diagonal blocks −β nnᵀ are left out of the coarse
//! levels (a positive semi-definite change, so the coarse operators stay SPD). Each level is a
//! block-sparse matrix (3×3 blocks, rows over its nodes) whose pattern and, per entry, the list
//! of fine springs or finer entries it sums are computed once per model; only the values are
//! computed per solve (constraints change between active-set rounds), each entry a gather in a
//! fixed order.
//!
//! **Preconditioner.** On the fine level the smoothing and the coarse correction are added,
//! not applied one after the other:
//!
//! z = S (ω D̂⁻¹ r + α P W(Pᵀ r)),
//!
//! D̂ = S D S + I − S the fine diagonal blocks (the block-Jacobi blocks of the free particles),
//! ω = [`OMEGA`], α = [`CORRECTION`], W the coarse levels' cycle. This costs no product with
//! the fine matrix, where a symmetric multiplicative cycle costs two (one per smoothing): on
//! the stiff 22³ cube the multiplicative cycle needed 24 CG iterations per solve and the
//! additive one 44, but each of its iterations costs a third. W on level l: x = ω D_l⁻¹ r, then
//! the coarse correction x += α P e_c with e_c the next level's W on Pᵀ(r − A_l x), run twice
//! (a W-cycle: e_c ← e_c + W(Pᵀ(r − A_l x) − A_{l+1} e_c)) except above the coarsest level,
//! then x += ω D_l⁻¹(r − A_l x). The coarsest level is solved by a dense Cholesky
//! factorisation (up to [`DENSE_NODES`] nodes; beyond, where coarsening stalled on many
//! bodies, by [`COARSEST_SWEEPS`] damped block-Jacobi sweeps from zero). α > 1
//! (over-correction) because piecewise-constant aggregates make the Galerkin coarse operators
//! too stiff. Both smoothings of a level are the same symmetric operator and the coarse
//! solves are symmetric, so W is symmetric; it is positive definite when each level's error
//! propagation (I − ωD⁻¹A)(I − αP W Pᵀ A)(I − ωD⁻¹A) has A-norm below 1, which holds for
//! ω ≤ 1 (the diagonal blocks bound A: A ≤ 2D) and 0 < α < 2 with an exact coarse solve, and
//! is checked by `tests/multigrid.rs` for the W-cycle. The additive sum of two SPD terms is
//! SPD, and so is S·MG·S on the free subspace: PCG stays valid. Measured iterations for one solve of the
//! deformed stiff cube (k_s = 10⁴ N/m, h = 1/60 s; `tests/multigrid.rs`): 40, 44, 46 at
//! 10³, 22³, 46³ (block Jacobi: 112, 248, 266).
//!
//! **Determinism.** Every per-node sum is a gather in a fixed order (members, pattern entries,
//! sources) and there are no reductions, so the bits do not depend on the thread count.

use std::collections::HashMap;

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use softbody_scene::Model;

use super::cg::Constraint;
use super::lattice::LatticeSystem;
use super::system::{System, outer};
use crate::forces::PARTICLE_CHUNK;
use crate::reduce::fill_and_sum;

/// Coarsening stops once a level has at most this many nodes.
pub const COARSEST_NODES: usize = 40;
/// The coarsest level is factorised when it has at most this many nodes.
pub const DENSE_NODES: usize = 200;
/// Damped block-Jacobi sweeps at a coarsest level too large to factorise.
pub const COARSEST_SWEEPS: usize = 20;
/// Damping of the block-Jacobi smoother.
pub const OMEGA: f64 = 0.9;
/// Scale of every coarse correction (over-correction: piecewise-constant aggregates make the
/// Galerkin coarse operator too stiff, so the plain correction falls short).
pub const CORRECTION: f64 = 1.5;
/// Rows (and, in `prepare`, entries) per parallel task on the coarse levels; smaller levels
/// run on the calling thread. With the residual's rows in AVX2 the first coarse level is
/// bound by streaming its blocks (2.6 MB at 22³), and split between two cores each half stays
/// in its core's L2: a multigrid application 7% faster at 22³ and 18% at 46³ than with 4,096
/// (the 22³ cube's 1,331 rows on one thread), on a 2-core Xeon. 256 was no
/// faster than 512.
const ROW_CHUNK: usize = 512;

/// Compressed rows of u32 items.
#[derive(Debug, Default)]
struct Rows {
    offsets: Vec<u32>,
    items: Vec<u32>,
}

impl Rows {
    fn of(&self, i: usize) -> &[u32] {
        &self.items[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    fn memory_bytes(&self) -> u64 {
        crate::vec_bytes(&self.offsets) + crate::vec_bytes(&self.items)
    }
}

/// The finer nodes of each node, ascending, from each finer node's parent.
fn members(parent: &[u32], nodes: usize) -> Rows {
    let mut offsets = vec![0u32; nodes + 1];
    for &p in parent {
        offsets[p as usize + 1] += 1;
    }
    for i in 0..nodes {
        offsets[i + 1] += offsets[i];
    }
    let mut next = offsets.clone();
    let mut items = vec![0u32; parent.len()];
    for (i, &p) in parent.iter().enumerate() {
        items[next[p as usize] as usize] = i as u32;
        next[p as usize] += 1;
    }
    Rows { offsets, items }
}

/// Aggregates nodes with keys (body, lattice coordinates) by halving the coordinates: each
/// node's parent and the parents' keys, numbered in order of first appearance.
fn aggregate(keys: &[(u32, [i32; 3])]) -> (Vec<u32>, Vec<(u32, [i32; 3])>) {
    let mut index: HashMap<(u32, [i32; 3]), u32> = HashMap::new();
    let mut coarse = Vec::new();
    let parent = keys
        .iter()
        .map(|&(body, c)| {
            let key = (body, c.map(|x| x.div_euclid(2)));
            *index.entry(key).or_insert_with(|| {
                coarse.push(key);
                (coarse.len() - 1) as u32
            })
        })
        .collect();
    (parent, coarse)
}

/// One coarse level: a block-sparse symmetric matrix over its nodes, how it comes from the
/// finer level, and its cycle's vectors.
#[derive(Debug, Default)]
struct Level {
    /// The node of this level of each node of the finer level.
    parent: Vec<u32>,
    /// The finer level's nodes of each node.
    members: Rows,
    /// Row offsets into `cols`/`values`.
    offsets: Vec<u32>,
    /// Column of each entry, ascending within a row.
    cols: Vec<u32>,
    /// Row of each entry.
    rows: Vec<u32>,
    /// The entry (column, row) of each entry (the pattern is symmetric).
    transpose: Vec<u32>,
    /// Each entry's sources: on the first coarse level `2·spring + side` (side 1 when the
    /// row's node holds the spring's second end; on a diagonal entry the springs inside the
    /// node; `spring` a [`Springs`] code), below it the finer level's entries.
    sources: Rows,
    /// The blocks.
    values: Vec<DMat3>,
    /// ω times the inverse diagonal blocks.
    smoother: Vec<DMat3>,
    rhs: Vec<DVec3>,
    x: Vec<DVec3>,
    res: Vec<DVec3>,
    acc: Vec<DVec3>,
}

impl Level {
    /// A level from (row, column, source) triples; `u32::MAX` sources only make an entry.
    fn new(parent: Vec<u32>, nodes: usize, mut triples: Vec<(u32, u32, u32)>) -> Level {
        triples.sort_unstable();
        let mut offsets = vec![0u32; nodes + 1];
        let (mut cols, mut rows) = (Vec::new(), Vec::new());
        let mut sources = Rows {
            offsets: vec![0],
            items: Vec::new(),
        };
        let mut last = None;
        for &(r, c, s) in &triples {
            if last != Some((r, c)) {
                if last.is_some() {
                    sources.offsets.push(sources.items.len() as u32);
                }
                last = Some((r, c));
                cols.push(c);
                rows.push(r);
                offsets[r as usize + 1] += 1;
            }
            if s != u32::MAX {
                sources.items.push(s);
            }
        }
        sources.offsets.push(sources.items.len() as u32);
        for i in 0..nodes {
            offsets[i + 1] += offsets[i];
        }
        let entries = cols.len();
        let transpose = (0..entries)
            .map(|e| {
                let (r, c) = (rows[e] as usize, cols[e]);
                let row = &cols[offsets[c as usize] as usize..offsets[c as usize + 1] as usize];
                let k = row.binary_search(&(r as u32)).expect("a symmetric pattern");
                offsets[c as usize] + k as u32
            })
            .collect();
        let zeros = || vec![DVec3::ZERO; nodes];
        Level {
            members: members(&parent, nodes),
            parent,
            offsets,
            cols,
            rows,
            transpose,
            sources,
            values: vec![DMat3::ZERO; entries],
            smoother: vec![DMat3::ZERO; nodes],
            rhs: zeros(),
            x: zeros(),
            res: zeros(),
            acc: zeros(),
        }
    }

    fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        vec_bytes(&self.parent)
            + self.members.memory_bytes()
            + vec_bytes(&self.offsets)
            + vec_bytes(&self.cols)
            + vec_bytes(&self.rows)
            + vec_bytes(&self.transpose)
            + self.sources.memory_bytes()
            + vec_bytes(&self.values)
            + vec_bytes(&self.smoother)
            + [&self.rhs, &self.x, &self.res, &self.acc]
                .into_iter()
                .map(vec_bytes)
                .sum::<u64>()
    }

    /// The entries of the next coarser level, from this level's pattern and `parent` (this
    /// level's node → coarser node).
    fn coarser(&self, parent: Vec<u32>, nodes: usize) -> Level {
        let triples = (0..self.cols.len())
            .map(|e| {
                let (r, c) = (self.rows[e] as usize, self.cols[e] as usize);
                (parent[r], parent[c], e as u32)
            })
            .collect();
        Level::new(parent, nodes, triples)
    }

    /// res = rhs − A x.
    fn residual(&mut self) {
        let (offsets, cols, values) = (&self.offsets, &self.cols, &self.values);
        let (rhs, x) = (&self.rhs, &self.x);
        let avx2 = crate::spring_forces::avx2();
        self.res
            .par_iter_mut()
            .enumerate()
            .with_min_len(ROW_CHUNK)
            .for_each(|(row, res)| {
                let entries = offsets[row] as usize..offsets[row + 1] as usize;
                let (values, cols) = (&values[entries.clone()], &cols[entries]);
                *res = if avx2 {
                    // SAFETY: the CPU has AVX2 (`avx2`).
                    #[cfg(target_arch = "x86_64")]
                    unsafe {
                        row_residual_avx2(rhs[row], values, cols, x)
                    }
                    #[cfg(not(target_arch = "x86_64"))]
                    unreachable!("AVX2 is detected on x86-64 only")
                } else {
                    row_residual(rhs[row], values, cols, x)
                };
            });
    }

    /// x = ω D⁻¹ rhs.
    fn smooth_from_zero(&mut self) {
        let (smoother, rhs) = (&self.smoother, &self.rhs);
        self.x
            .par_iter_mut()
            .enumerate()
            .with_min_len(ROW_CHUNK)
            .for_each(|(i, x)| *x = smoother[i] * rhs[i]);
    }

    /// x += ω D⁻¹ (rhs − A x).
    fn smooth(&mut self) {
        self.residual();
        let (smoother, res) = (&self.smoother, &self.res);
        self.x
            .par_iter_mut()
            .enumerate()
            .with_min_len(ROW_CHUNK)
            .for_each(|(i, x)| *x += smoother[i] * res[i]);
    }
}

/// rhs − Σ values[e] x[cols[e]] over one row's entries, in their order: each block's product as
/// glam's `DMat3 * DVec3`, (c₀ x + c₁ y) + c₂ z with c the block's columns, subtracted in turn.
#[inline(always)]
fn row_residual(rhs: DVec3, values: &[DMat3], cols: &[u32], x: &[DVec3]) -> DVec3 {
    values
        .iter()
        .zip(cols)
        .fold(rhs, |sum, (m, &c)| sum - *m * x[c as usize])
}

/// [`row_residual`] with each block's columns in one 256-bit vector each: the same operations
/// lane by lane, so the same bits (`avx2_rows_give_the_scalar_bits`), in a third of the
/// instructions. The coarse levels' residuals were two thirds of a multigrid application.
/// Lane 3 carries whatever the loads put there and is never read.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn row_residual_avx2(rhs: DVec3, values: &[DMat3], cols: &[u32], x: &[DVec3]) -> DVec3 {
    use std::arch::x86_64::*;
    let mut sum = _mm256_setr_pd(rhs.x, rhs.y, rhs.z, 0.0);
    for (m, &c) in values.iter().zip(cols) {
        let p = (m as *const DMat3).cast::<f64>();
        let v = x[c as usize];
        // SAFETY: `DMat3` is `repr(C)`, its nine f64 column after column; the loads read
        // elements 0–3, 3–6 and 5–8 of them.
        let (c0, c1, c2) = unsafe {
            (
                _mm256_loadu_pd(p),
                _mm256_loadu_pd(p.add(3)),
                // Elements 6, 7, 8 to lanes 0, 1, 2.
                _mm256_permute4x64_pd::<0b11_11_10_01>(_mm256_loadu_pd(p.add(5))),
            )
        };
        let product = _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(c0, _mm256_set1_pd(v.x)),
                _mm256_mul_pd(c1, _mm256_set1_pd(v.y)),
            ),
            _mm256_mul_pd(c2, _mm256_set1_pd(v.z)),
        );
        sum = _mm256_sub_pd(sum, product);
    }
    let mut lanes = [0.0; 4];
    // SAFETY: four f64 to a four-element array.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), sum) };
    DVec3::new(lanes[0], lanes[1], lanes[2])
}

/// The coarsest level's solve.
#[derive(Debug, Default)]
enum Direct {
    /// The lower Cholesky factor L (A = L Lᵀ) of the 3m×3m matrix, row-major.
    Cholesky(Vec<f64>),
    /// Sweeps of the smoother (too large to factorise, or not positive definite in floating
    /// point).
    #[default]
    Sweeps,
}

/// The multigrid hierarchy of a model and its per-solve values.
#[derive(Debug)]
pub struct Multigrid {
    /// Coarse levels, finest first.
    levels: Vec<Level>,
    direct: Direct,
    /// Fine level: (S D S + I − S)⁻¹ times ω per particle.
    fine_smoother: Vec<DMat3>,
    /// What the values were computed for, and how long they have been kept.
    prepared: Option<Prepared>,
    /// Whether the first level's sources name springs by [`LatticeSystem`] codes (else by their
    /// index in the spring list).
    lattice: bool,
}

/// How many later assemblies may keep a multigrid's values (see [`Multigrid::prepare`]).
pub const KEEP_ASSEMBLIES: u32 = 8;

/// What a multigrid's values were computed for.
#[derive(Debug)]
struct Prepared {
    /// The system's assembly ([`System::assembly`]) they were computed at.
    assembly: u64,
    /// The constraints they were computed for.
    constraints: Vec<Constraint>,
    /// The last assembly that kept them, and how many later assemblies have.
    seen: u64,
    kept: u32,
    /// CG's weight norm under them ([`Multigrid::weight_norm`]): h g, and wᵀ S MG S w for the
    /// impulse w_i = S m_i h g.
    weight: Option<(DVec3, f64)>,
}

/// The springs the first coarse level sums, by the codes of its sources: the spring list's
/// indices with the blocks of the list's assembly ([`ListBlocks`]), or the lattices' codes with
/// the blocks recomputed from the linearisation ([`LatticeSystem::spring`]: the lean route keeps
/// no per-spring block). A trait, not an enum, so that each route's entries are compiled
/// on their own.
trait SpringBlocks: Sync {
    /// The ends (a, b) of spring `code` and its block B_s.
    fn spring(&self, code: u32) -> (usize, usize, DMat3);
}

/// The spring list's blocks, as its assembly left them.
struct ListBlocks<'a> {
    springs: &'a softbody_scene::Springs,
    u: &'a [DVec3],
    beta: &'a [f64],
    gamma: &'a [f64],
}

impl SpringBlocks for ListBlocks<'_> {
    #[inline(always)]
    fn spring(&self, code: u32) -> (usize, usize, DMat3) {
        let s = code as usize;
        let block =
            outer(self.u[s], self.beta[s]) + DMat3::from_diagonal(DVec3::splat(self.gamma[s]));
        (
            self.springs.a[s] as usize,
            self.springs.b[s] as usize,
            block,
        )
    }
}

impl SpringBlocks for LatticeSystem {
    #[inline(always)]
    fn spring(&self, code: u32) -> (usize, usize, DMat3) {
        LatticeSystem::spring(self, code)
    }
}

/// S_x M S_y.
#[inline]
fn sandwich(sx: Constraint, m: DMat3, sy: Constraint) -> DMat3 {
    let projector = |s: Constraint| match s {
        Constraint::Free => None,
        Constraint::Normal(n) => Some(DMat3::IDENTITY - outer(n, 1.0)),
        Constraint::Fixed => Some(DMat3::ZERO),
    };
    match (sx, sy) {
        (Constraint::Free, Constraint::Free) => m,
        (Constraint::Fixed, _) | (_, Constraint::Fixed) => DMat3::ZERO,
        _ => {
            let left = projector(sx).map_or(m, |p| p * m);
            projector(sy).map_or(left, |p| left * p)
        }
    }
}

/// S D S + (I − S).
#[inline]
fn filtered(s: Constraint, d: DMat3) -> DMat3 {
    match s {
        Constraint::Free => d,
        Constraint::Fixed => DMat3::IDENTITY,
        Constraint::Normal(n) => sandwich(s, d, s) + outer(n, 1.0),
    }
}

/// Entry (row, col) of the first coarse level, from the members of the row's node and the
/// entry's sources: on the diagonal Σ_{a∈A} (S_a D_a S_a + I − S_a) − Σ (S_a B_s S_b + S_b B_s S_a)
/// over the springs inside A, off it −Σ S_x B_s S_y over the springs from A to B.
fn first_level_entry(
    (row, col): (u32, u32),
    (members, sources): (&[u32], &[u32]),
    (constraints, diag): (&[Constraint], &[DMat3]),
    springs: &impl SpringBlocks,
) -> DMat3 {
    let mut sum = DMat3::ZERO;
    if row == col {
        for &a in members {
            let a = a as usize;
            sum += filtered(constraints[a], diag[a]);
        }
        for &code in sources {
            let (a, b, block) = springs.spring(code >> 1);
            // A subtraction in each arm: a match that yields the block went through the stack.
            match (constraints[a], constraints[b]) {
                // B_s is symmetric: S B S + (S B S)ᵀ = 2B between free particles.
                (Constraint::Free, Constraint::Free) => sum -= block + block,
                (sa, sb) => {
                    let m = sandwich(sa, block, sb);
                    sum -= m + m.transpose();
                }
            }
        }
    } else {
        for &code in sources {
            let (a, b, block) = springs.spring(code >> 1);
            let (x, y) = if code & 1 == 0 { (a, b) } else { (b, a) };
            match (constraints[x], constraints[y]) {
                (Constraint::Free, Constraint::Free) => sum -= block,
                (sx, sy) => sum -= sandwich(sx, block, sy),
            }
        }
    }
    sum
}

/// A level's pattern, to compute its values: each entry above the diagonal (or on it) whose
/// value is `stale`.
struct Entries<'a, F> {
    rows: &'a [u32],
    cols: &'a [u32],
    sources: &'a Rows,
    members: &'a Rows,
    stale: &'a F,
}

impl<F: Fn(usize) -> bool + Sync> Entries<'_, F> {
    /// values[e] = value(e) for the stale entries with row ≤ column.
    fn fill(&self, values: &mut [DMat3], value: impl Fn(usize) -> DMat3 + Sync) {
        values
            .par_iter_mut()
            .enumerate()
            .with_min_len(ROW_CHUNK)
            .for_each(|(e, v)| {
                if self.rows[e] <= self.cols[e] && (self.stale)(e) {
                    *v = value(e);
                }
            });
    }

    /// The first coarse level's values ([`first_level_entry`]).
    fn first_level(
        &self,
        values: &mut [DMat3],
        fine: (&[Constraint], &[DMat3]),
        springs: &impl SpringBlocks,
    ) {
        self.fill(values, |e| {
            let (row, col) = (self.rows[e], self.cols[e]);
            first_level_entry(
                (row, col),
                (self.members.of(row as usize), self.sources.of(e)),
                fine,
                springs,
            )
        });
    }
}

impl Multigrid {
    /// The hierarchy of `model` for its step's `system` (whose route, the spring list or the
    /// lattices, names the springs), or `None` when some particle has no lattice coordinates (a
    /// `particles` body), the model is empty, or it has more particles than the lattices'
    /// spring codes hold (2²⁷).
    pub fn new(model: &Model, system: &System) -> Option<Multigrid> {
        let n = model.len();
        if n == 0 {
            return None;
        }
        let keys: Vec<(u32, [i32; 3])> = (0..n)
            .map(|i| Some((model.contact.body[i], model.contact.lattice[i]?)))
            .collect::<Option<_>>()?;
        let (parent, mut keys) = aggregate(&keys);
        let m = keys.len();
        let mut triples: Vec<(u32, u32, u32)> = (0..m as u32).map(|a| (a, a, u32::MAX)).collect();
        triples.reserve(2 * model.spring_count());
        let mut push = |spring: u32, a: usize, b: usize| {
            let (a, b) = (parent[a], parent[b]);
            let code = 2 * spring;
            if a == b {
                triples.push((a, a, code));
            } else {
                triples.push((a, b, code));
                triples.push((b, a, code + 1));
            }
        };
        match &system.lattice {
            Some(lattice) => lattice.for_each_spring(&mut push)?,
            None => {
                let springs = model.springs();
                for s in 0..springs.len() {
                    push(s as u32, springs.a[s] as usize, springs.b[s] as usize);
                }
            }
        }
        let mut levels = vec![Level::new(parent, m, triples)];
        loop {
            let last = levels.last().unwrap();
            let nodes = last.len();
            if nodes <= COARSEST_NODES {
                break;
            }
            let (parent, next) = aggregate(&keys);
            if 10 * next.len() > 9 * nodes {
                break; // stalled: every body is (nearly) one node
            }
            let level = last.coarser(parent, next.len());
            levels.push(level);
            keys = next;
        }
        Some(Multigrid {
            levels,
            direct: Direct::Sweeps,
            fine_smoother: vec![DMat3::ZERO; n],
            prepared: None,
            lattice: system.lattice.is_some(),
        })
    }

    /// Nodes of each level, the fine one first.
    pub fn level_sizes(&self) -> Vec<usize> {
        std::iter::once(self.fine_smoother.len())
            .chain(self.levels.iter().map(Level::len))
            .collect()
    }

    /// Bytes held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        use crate::vec_bytes;
        self.levels.iter().map(Level::memory_bytes).sum::<u64>()
            + match &self.direct {
                Direct::Cholesky(l) => vec_bytes(l),
                Direct::Sweeps => 0,
            }
            + vec_bytes(&self.fine_smoother)
    }

    /// Makes the levels' values a preconditioner for the system `system` (assembled) under
    /// `constraints`.
    ///
    /// Values computed at an earlier assembly for the same constraints are kept, for up to
    /// [`KEEP_ASSEMBLIES`] later assemblies, when the system has no pairs of bodies: they are
    /// the multigrid of a system a few steps old, still symmetric positive definite, so CG's
    /// answer is the same to its tolerance; a body at rest or falling keeps nearly the same
    /// springs' blocks from step to step (the 22³ benchmark cube: 16.8 instead of 16.7
    /// iterations a step, CG ~11% faster), and the bound limits how far a body spinning free
    /// of contact turns under a kept preconditioner (at 3 rev/s, 8% more iterations).
    /// Otherwise they are computed for this assembly.
    ///
    /// An entry's value depends only on the constraints of the particles its row's and
    /// column's nodes hold, so after the first solve of a step (the same assembly) only the
    /// entries of nodes holding a particle whose constraint changed are computed again: the
    /// active set's later rounds change a few contacts. The values are the same bits as when
    /// computed afresh. Each level's entries below the diagonal are the transposes of those
    /// above it (Pᵀ Â P is symmetric), so only the upper half is summed.
    pub fn prepare(&mut self, system: &System, model: &Model, constraints: &[Constraint]) {
        let assembly = system.assembly();
        // The fine particles whose constraint changed since the values were computed (`None`:
        // every value is computed).
        let changed: Option<Vec<bool>> = match &mut self.prepared {
            Some(p) if p.assembly == assembly => {
                let changed: Vec<bool> = (p.constraints.iter().zip(constraints))
                    .map(|(a, b)| a != b)
                    .collect();
                if !changed.contains(&true) {
                    return;
                }
                Some(changed)
            }
            Some(p)
                if system.pairs.is_none()
                    && p.constraints == constraints
                    && (p.seen == assembly || p.kept < KEEP_ASSEMBLIES) =>
            {
                if p.seen != assembly {
                    (p.seen, p.kept) = (assembly, p.kept + 1);
                }
                return;
            }
            _ => None,
        };
        let (diag, inv_diag) = (&system.diag, &system.inv_diag);
        let omega = OMEGA;
        let fresh = |i: usize| changed.as_ref().is_none_or(|c| c[i]);
        self.fine_smoother
            .par_iter_mut()
            .enumerate()
            .with_min_len(PARTICLE_CHUNK)
            .for_each(|(i, m)| {
                if fresh(i) {
                    *m = omega
                        * match constraints[i] {
                            Constraint::Free => inv_diag[i],
                            s => filtered(s, diag[i]).inverse(),
                        };
                }
            });
        // Per level, its nodes holding a changed particle.
        let mut marks: Option<Vec<bool>> = changed.as_ref().map(|changed| {
            let mut marks = vec![false; self.levels[0].len()];
            for (i, _) in changed.iter().enumerate().filter(|(_, c)| **c) {
                marks[self.levels[0].parent[i] as usize] = true;
            }
            marks
        });
        assert_eq!(
            self.lattice,
            system.lattice.is_some(),
            "a multigrid prepared for a system of the other route"
        );
        for k in 0..self.levels.len() {
            let (finer, coarser) = self.levels.split_at_mut(k);
            let level = &mut coarser[0];
            if k > 0 {
                marks = marks.map(|finer_marks| {
                    let mut marks = vec![false; level.len()];
                    for (node, _) in finer_marks.iter().enumerate().filter(|(_, m)| **m) {
                        marks[level.parent[node] as usize] = true;
                    }
                    marks
                });
            }
            let (rows, cols, sources, members) =
                (&level.rows, &level.cols, &level.sources, &level.members);
            let stale = |e: usize| {
                let (r, c) = (rows[e] as usize, cols[e] as usize);
                marks.as_ref().is_none_or(|m| m[r] || m[c])
            };
            let entries = Entries {
                rows,
                cols,
                sources,
                members,
                stale: &stale,
            };
            let values = &mut level.values;
            match (finer.last(), &system.lattice) {
                (Some(finer), _) => entries.fill(values, |e| {
                    (sources.of(e).iter())
                        .fold(DMat3::ZERO, |sum, &f| sum + finer.values[f as usize])
                }),
                (None, Some(lattice)) => entries.first_level(values, (constraints, diag), lattice),
                (None, None) => {
                    let springs = ListBlocks {
                        springs: model.springs(),
                        u: &system.u,
                        beta: &system.beta,
                        gamma: &system.gamma,
                    };
                    entries.first_level(values, (constraints, diag), &springs)
                }
            }
            for e in 0..level.values.len() {
                if rows[e] > cols[e] && stale(e) {
                    level.values[e] = level.values[level.transpose[e] as usize].transpose();
                }
            }
            let (offsets, values) = (&level.offsets, &level.values);
            let marks = marks.as_ref();
            level
                .smoother
                .par_iter_mut()
                .enumerate()
                .with_min_len(ROW_CHUNK)
                .for_each(|(row, m)| {
                    if marks.is_some_and(|marks| !marks[row]) {
                        return;
                    }
                    let e = (offsets[row]..offsets[row + 1])
                        .find(|&e| cols[e as usize] as usize == row)
                        .expect("every row has its diagonal entry");
                    *m = omega * values[e as usize].inverse();
                });
        }
        if marks.is_none_or(|m| m.contains(&true)) {
            self.direct = factor(self.levels.last().unwrap());
        }
        match &mut self.prepared {
            Some(p) => {
                (p.assembly, p.seen, p.kept) = (assembly, assembly, 0);
                p.constraints.copy_from_slice(constraints);
                p.weight = None;
            }
            None => {
                self.prepared = Some(Prepared {
                    assembly,
                    constraints: constraints.to_vec(),
                    seen: assembly,
                    kept: 0,
                    weight: None,
                })
            }
        }
    }

    /// The weight norm wᵀ S MG S w that [`Multigrid::keep_weight_norm`] kept for the impulse
    /// w_i = S m_i `hg` under the current values, if it did: the constraints S are those the
    /// values were computed for, and the same values give the same bits.
    pub fn weight_norm(&self, hg: DVec3) -> Option<f64> {
        let (kept_hg, norm) = self.prepared.as_ref()?.weight?;
        (kept_hg == hg).then_some(norm)
    }

    /// Keeps `norm`, the weight norm for `hg` under the current values ([`weight_norm`]), until
    /// they change.
    ///
    /// [`weight_norm`]: Multigrid::weight_norm
    pub fn keep_weight_norm(&mut self, hg: DVec3, norm: f64) {
        if let Some(p) = self.prepared.as_mut() {
            p.weight = Some((hg, norm));
        }
    }

    /// Drops the values: the next [`Multigrid::prepare`] computes them.
    pub fn forget(&mut self) {
        self.prepared = None;
    }

    /// The assembly the values were computed at, if any.
    pub fn computed_at(&self) -> Option<u64> {
        self.prepared.as_ref().map(|p| p.assembly)
    }

    /// The constraints the values were computed for and how many later assemblies kept them.
    pub fn kept(&self) -> Option<(&[Constraint], u32)> {
        self.prepared.as_ref().map(|p| (&p.constraints[..], p.kept))
    }

    /// Computes the values for `system` (assembled at the positions the values of a run were
    /// computed at) under `constraints`, as kept by `kept` later assemblies: the state
    /// [`Multigrid::kept`] and those positions describe (a resumed run's).
    pub fn restore(
        &mut self,
        system: &System,
        model: &Model,
        constraints: &[Constraint],
        kept: u32,
    ) {
        self.forget();
        self.prepare(system, model, constraints);
        if let Some(p) = self.prepared.as_mut() {
            p.kept = kept;
        }
    }

    /// z = S·MG·S r for a filtered r (the preconditioner of the filtered CG):
    /// z = S(ω D̂⁻¹ r + α P cycle(Pᵀ r)). Returns rᵀz ([`fill_and_sum`]'s bits).
    pub fn apply(&mut self, constraints: &[Constraint], r: &[DVec3], z: &mut [DVec3]) -> f64 {
        let Multigrid {
            levels,
            direct,
            fine_smoother,
            ..
        } = self;
        let first = &mut levels[0];
        restrict(&first.members, r, &mut first.rhs);
        cycle(levels, direct);
        let (parent, x) = (&levels[0].parent, &levels[0].x);
        let smoother = &*fine_smoother;
        fill_and_sum(z, |i| {
            let z = constraints[i].filter(smoother[i] * r[i] + CORRECTION * x[parent[i] as usize]);
            (z, r[i].dot(z))
        })
    }
}

/// coarse = Pᵀ fine: each node's members summed in ascending order.
fn restrict(members: &Rows, fine: &[DVec3], coarse: &mut [DVec3]) {
    coarse
        .par_iter_mut()
        .enumerate()
        .with_min_len(ROW_CHUNK)
        .for_each(|(c, v)| {
            *v = members
                .of(c)
                .iter()
                .fold(DVec3::ZERO, |sum, &f| sum + fine[f as usize]);
        });
}

/// levels[0].x ≈ A₀⁻¹ levels[0].rhs by the cycle of the module doc.
fn cycle(levels: &mut [Level], direct: &Direct) {
    let (this, rest) = levels.split_first_mut().unwrap();
    if rest.is_empty() {
        solve_coarsest(this, direct);
        return;
    }
    this.smooth_from_zero();
    this.residual();
    let next = &mut rest[0];
    restrict(&next.members, &this.res, &mut next.rhs);
    cycle(rest, direct);
    let correction = if rest.len() > 1 {
        // W-cycle: a second cycle on the residual the first left.
        let next = &mut rest[0];
        next.residual();
        next.acc.copy_from_slice(&next.x);
        std::mem::swap(&mut next.rhs, &mut next.res);
        cycle(rest, direct);
        let next = &mut rest[0];
        next.acc
            .par_iter_mut()
            .zip(next.x.par_iter())
            .with_min_len(ROW_CHUNK)
            .for_each(|(a, x)| *a += *x);
        &rest[0].acc
    } else {
        &rest[0].x
    };
    let parent = &rest[0].parent;
    this.x
        .par_iter_mut()
        .enumerate()
        .with_min_len(ROW_CHUNK)
        .for_each(|(i, x)| *x += CORRECTION * correction[parent[i] as usize]);
    this.smooth();
}

/// The coarsest level's solve.
fn solve_coarsest(level: &mut Level, direct: &Direct) {
    match direct {
        Direct::Cholesky(l) => {
            let n = 3 * level.len();
            let mut y: Vec<f64> = level.rhs.iter().flat_map(|v| v.to_array()).collect();
            for i in 0..n {
                let row = &l[i * n..i * n + i];
                let s = row.iter().zip(&y[..i]).fold(y[i], |s, (l, y)| s - l * y);
                y[i] = s / l[i * n + i];
            }
            for i in (0..n).rev() {
                let mut s = y[i];
                for j in i + 1..n {
                    s -= l[j * n + i] * y[j];
                }
                y[i] = s / l[i * n + i];
            }
            for (x, c) in level.x.iter_mut().zip(y.chunks_exact(3)) {
                *x = DVec3::new(c[0], c[1], c[2]);
            }
        }
        Direct::Sweeps => {
            level.smooth_from_zero();
            for _ in 1..COARSEST_SWEEPS {
                level.smooth();
            }
        }
    }
}

/// The Cholesky factor of the coarsest level's matrix, where it is small enough and positive
/// definite.
fn factor(level: &Level) -> Direct {
    let m = level.len();
    if m > DENSE_NODES {
        return Direct::Sweeps;
    }
    let n = 3 * m;
    let mut a = vec![0.0; n * n];
    for e in 0..level.cols.len() {
        let (r, c) = (level.rows[e] as usize, level.cols[e] as usize);
        let block = level.values[e];
        for j in 0..3 {
            let col = block.col(j);
            for i in 0..3 {
                a[(3 * r + i) * n + 3 * c + j] = col[i];
            }
        }
    }
    // In place: the lower triangle becomes L.
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0 && d.is_finite()) {
            return Direct::Sweeps;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    Direct::Cholesky(a)
}

// The vector row exists on x86-64 only.
#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use glam::{DMat3, DVec3};
    use softbody_testkit::Rng;

    use super::row_residual;

    /// The AVX2 row gives the scalar row's bits: blocks and vectors over twelve orders of
    /// magnitude, rows of 0 to 40 entries with repeated columns.
    #[test]
    fn avx2_rows_give_the_scalar_bits() {
        if !crate::spring_forces::avx2() {
            eprintln!("skipped: this CPU has no AVX2, so the multigrid never runs the AVX2 rows");
            return;
        }
        let mut rng = Rng::new(11);
        let mut value = || (rng.unit() - 0.5) * 10f64.powi((12.0 * rng.unit()) as i32 - 6);
        let x: Vec<DVec3> = (0..50)
            .map(|_| DVec3::new(value(), value(), value()))
            .collect();
        for len in 0..=40 {
            let values: Vec<DMat3> = (0..len)
                .map(|_| DMat3::from_cols_array(&std::array::from_fn(|_| value())))
                .collect();
            let cols: Vec<u32> = (0..len).map(|e| ((e * 7 + len) % 50) as u32).collect();
            let rhs = DVec3::new(value(), value(), value());
            let scalar = row_residual(rhs, &values, &cols, &x);
            // SAFETY: the CPU has AVX2.
            let vector = unsafe { super::row_residual_avx2(rhs, &values, &cols, &x) };
            assert_eq!(
                scalar.to_array().map(f64::to_bits),
                vector.to_array().map(f64::to_bits),
                "{len} entries"
            );
        }
    }
}
