// neighbours.wgsl: the hashed grid of contact between bodies as its kernels share it (imported by
// broad_phase.wgsl, body_contact.wgsl and pairs_probe.wgsl): each particle's contact data, the cell
// hash, the rule that admits a pair, and the search of the 27 cells around a particle.
//
// The grid (built by broad_phase.wgsl ↔ crates/cpu/src/broad_phase.rs) hashes the cell
// c = floor(x / s) of each particle with a radius into one of `contact.buckets` (a power of two
// ≥ 2n) buckets, h(c) = (73856093 c_x ^ 19349663 c_y ^ 83492791 c_z) mod buckets (the CPU's
// hash, Teschner et al. 2003). Then `sorted` holds the particles bucket after bucket, each
// bucket's run ascending, and `counts[b]` the end of bucket b's run (its start is counts[b − 1],
// or 0). The cell s is a hair above 2·r_max, so two particles closer than r_i + r_j ≤ 2·r_max
// lie in the same or adjacent cells; s is applied as a multiplication by the f32 `inv_cell`, one
// correctly rounded operation, so every kernel puts a particle in the same cell.
//
// The grid is built from a snapshot of the state (`snapshot_x`, `snapshot_v`): particles
// [0, n) hold the step's start, [n, 2n) its end, and the searches read the positions of the
// snapshot the grid was built from.
//
// Pairs are always evaluated in the orientation (lo, hi) = (min, max), whichever of the two
// particles' threads does it: both get bit-equal decisions and values (with opposite signs).
//
// Twins: `softbody_gpu::layout::{ContactParams, ContactParticleGpu}`.

#import common

struct ContactParams {
    // 1/s, s the cell size, 1/m.
    inv_cell: f32,
    // Buckets of the hash table, a power of two.
    buckets: u32,
    // k_r of body contact.
    restitution: f32,
    // μ (Coulomb) or k_f (viscous) of body contact.
    friction: f32,
    // FRICTION_COULOMB or FRICTION_VISCOUS.
    friction_model: u32,
    // κ: the penalty stiffness in units of m_red/h².
    penalty: f32,
    // The overlap, as a fraction of R, that the response leaves to the penalty force.
    slop: f32,
    // Self-contact ignores pairs of a cuboid this close on its lattice (Chebyshev, in cells).
    exclusion: i32,
}

struct ContactParticle {
    // Lattice coordinates in its cuboid (LATTICE set), else unused.
    lattice: vec3<i32>,
    // Its body's index.
    body: u32,
    // r, m; 0 touches nothing (and the particle is not in the grid).
    radius: f32,
    // 1/m, 0 if pinned.
    inv_mass: f32,
    // SELF_CONTACT | LATTICE.
    flags: u32,
    _pad: u32,
}

// The particle's body touches itself.
const SELF_CONTACT: u32 = 1u;
// The particle belongs to a cuboid and has lattice coordinates.
const LATTICE: u32 = 2u;

@group(0) @binding(8) var<uniform> contact: ContactParams;
@group(0) @binding(9) var<storage, read> particles: array<ContactParticle>;
@group(0) @binding(10) var<storage, read_write> counts: array<u32>;
@group(0) @binding(11) var<storage, read_write> sorted: array<u32>;
@group(0) @binding(12) var<storage, read_write> snapshot_x: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read_write> snapshot_v: array<vec4<f32>>;
// For `particles` bodies with self-contact: the CSR adjacency's offsets (n + 1 words), then for
// each of its entries the particle at the spring's other end (one placeholder word otherwise).
@group(0) @binding(14) var<storage, read> rest_neighbours: array<u32>;

// The cell holding p; coordinates beyond ±2³⁰ cells are clamped (such a particle is far from
// every other, and a shared cell only adds candidates that the distance test rejects).
fn cell_of(p: vec3<f32>) -> vec3<i32> {
    let limit = vec3<f32>(1073741824.0);
    return vec3<i32>(clamp(floor(p * contact.inv_cell), -limit, limit));
}

fn bucket_of(c: vec3<i32>) -> u32 {
    let u = bitcast<vec3<u32>>(c);
    let h = (u.x * 73856093u) ^ (u.y * 19349663u) ^ (u.z * 83492791u);
    return h & (contact.buckets - 1u);
}

// Whether lo and hi (lo < hi, both with a radius) may touch (`Contacts::admits`): different
// bodies, or one body with self-contact where they are not rest neighbours — on a cuboid's
// lattice more than `exclusion` cells apart along some axis, in a `particles` body not joined
// by a spring.
fn admits(lo: u32, hi: u32, a: ContactParticle, b: ContactParticle) -> bool {
    if a.body != b.body {
        return true;
    }
    if (a.flags & SELF_CONTACT) == 0u {
        return false;
    }
    if (a.flags & LATTICE) != 0u {
        return any(abs(a.lattice - b.lattice) > vec3<i32>(contact.exclusion));
    }
    let ends = params.n_particles + 1u;
    let end = rest_neighbours[lo + 1u];
    for (var k = rest_neighbours[lo]; k < end; k++) {
        if rest_neighbours[ends + k] == hi {
            return false;
        }
    }
    return true;
}

// The search of the 27 cells around a cell: the cells still to read and the run being read.
//
// Two of the 27 cells may hash to one bucket, and a bucket holds other cells' particles too:
// a candidate counts only where its own cell is the cell being read (`current`), so each
// particle of the 27 cells comes out once, at its own cell's offset, and no other does. (A
// list of the buckets already read would do the same at 351 comparisons per search and a
// 27-word array per thread, which costs software adapters half the contact step.)
struct Neighbours {
    cell: vec3<i32>,
    // The next of the 27 cell offsets.
    next: u32,
    // The cell being read, and its bucket's run [at, end) of `sorted`.
    current: vec3<i32>,
    at: u32,
    end: u32,
}

fn neighbours_of(p: vec3<f32>) -> Neighbours {
    var it: Neighbours;
    it.cell = cell_of(p);
    it.next = 0u;
    it.at = 0u;
    it.end = 0u;
    return it;
}

// The next particle of the 27 cells around the cell (i itself included) in the snapshot at
// `base`, whose grid `it` searches, or NONE at the end.
fn next_candidate(it: ptr<function, Neighbours>, base: u32) -> u32 {
    var j = NONE;
    loop {
        if (*it).at < (*it).end {
            let q = sorted[(*it).at];
            (*it).at += 1u;
            if all(cell_of(snapshot_x[base + q].xyz) == (*it).current) {
                j = q;
                break;
            }
            continue;
        }
        let k = (*it).next;
        if k == 27u {
            break;
        }
        (*it).next = k + 1u;
        let offset = vec3<i32>(i32(k % 3u), i32(k / 3u % 3u), i32(k / 9u)) - vec3<i32>(1);
        (*it).current = (*it).cell + offset;
        let b = bucket_of((*it).current);
        if b == 0u {
            (*it).at = 0u;
        } else {
            (*it).at = counts[b - 1u];
        }
        (*it).end = counts[b];
    }
    return j;
}

// Whether lo and hi (lo < hi) are an admitted pair in contact in the snapshot at `base`:
// |x_lo − x_hi| < r_lo + r_hi.
fn in_contact(lo: u32, hi: u32, base: u32) -> bool {
    let a = particles[lo];
    let b = particles[hi];
    let reach = a.radius + b.radius;
    let d = snapshot_x[base + lo].xyz - snapshot_x[base + hi].xyz;
    return dot(d, d) < reach * reach && admits(lo, hi, a, b);
}

// The next partner j ≠ i of particle i in the snapshot at `base` (whose grid `it` searches), or
// NONE at the end.
fn next_partner(i: u32, it: ptr<function, Neighbours>, base: u32) -> u32 {
    var j = next_candidate(it, base);
    while j != NONE && (j == i || !in_contact(min(i, j), max(i, j), base)) {
        j = next_candidate(it, base);
    }
    return j;
}
