// lattice.wgsl ↔ crates/scene/src/model.rs (`Lattice::for_each_spring`): where the springs of a
// model whose bodies are all lattices (cuboids, mesh bodies) are, found as constant offsets on
// each body's lattice, with no spring record and no adjacency: a spring's parameters are its
// offset's, one table per body (`lattice_bodies`), and its partner is the point p ± d.
// Imported by the stages of the stencil route: the fused step's gather (stencil.wgsl) and the
// energies (energy.wgsl's `energy_lattices`).
//
// A particle's thread finds its body by a binary search (`lattice_body_of`) and its lattice
// point from its index (`stencil_of`); the springs starting at its point p are the offsets o
// (in topology::OFFSETS order) with `in_grid(s, p + o.d)` and `kept(s, o, point)`, each ending
// at `particle_at(s, step_point(point, o, 1))`.

#import common

// The springs of one lattice offset of a body (twin: `layout::LatticeOffsetGpu`).
struct LatticeOffset {
    // (di, dj, dk): the spring starting at point p ends at p + d.
    d: vec3<i32>,
    // Rest length r, m.
    rest: f32,
    // k_s, N/m.
    stiffness: f32,
    // k_d, N·s/m.
    damping: f32,
    // Its index in topology::OFFSETS: its bit in a masked lattice's points.
    bit: u32,
    // Its step in point index, di + nx (dj + ny dk): the spring starting at point p ends at
    // point p + linear (u32 addition, wrapping).
    linear: i32,
}

// A lattice body (twin: `layout::LatticeBodyGpu`), one per body in particle order.
struct LatticeBody {
    // Its first particle and particle count.
    first: u32,
    count: u32,
    // Points per axis.
    nx: u32,
    ny: u32,
    nz: u32,
    // Offsets with springs: `offsets[..n_offsets]`.
    n_offsets: u32,
    // A mesh body's words in `lattice_points`, NONE for a cuboid (every point a particle,
    // particle = point, every spring whose end lies in the grid).
    points: u32,
    _pad: u32,
    // In topology::OFFSETS order: the order of the springs starting at a point.
    offsets: array<LatticeOffset, 16>,
    // Indices into `offsets` by descending linear offset: the order of the springs ending at a
    // point.
    backward: array<u32, 16>,
}

@group(0) @binding(15) var<storage, read> lattice_bodies: array<LatticeBody>;
// The masked lattices of mesh bodies, from their `points` word: the point of each of the
// body's particles (`count` words), then per point its particle within the body (NONE where
// there is none) and the bits of the offsets whose springs start there (two words).
@group(0) @binding(16) var<storage, read> lattice_points: array<u32>;

// The body holding particle i: the last whose first particle is at most i.
fn lattice_body_of(i: u32) -> u32 {
    var lo = 0u;
    var hi = arrayLength(&lattice_bodies);
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if lattice_bodies[mid].first <= i {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// The springs of lattice `body`, as the thread of one particle sees them.
struct Stencil {
    body: u32,
    // The lattice's points per axis.
    dims: vec3<i32>,
    // The particle's point, as coordinates and as its index in the lattice.
    p: vec3<i32>,
    point: u32,
}

// Particle i's body and lattice point.
fn stencil_of(i: u32) -> Stencil {
    let b = lattice_body_of(i);
    let body = &lattice_bodies[b];
    let dims = vec3<i32>(i32((*body).nx), i32((*body).ny), i32((*body).nz));
    var point = i - (*body).first;
    if (*body).points != NONE {
        point = lattice_points[(*body).points + point];
    }
    let plane = (*body).nx * (*body).ny;
    let p = vec3<i32>(
        i32(point % (*body).nx),
        i32((point % plane) / (*body).nx),
        i32(point / plane),
    );
    return Stencil(b, dims, p, point);
}

// Whether point q lies in the lattice. A spring of offset d ending (starting) at the
// particle's own point exists where this holds for p − d (p + d) and `kept` says so: the
// particle's point needs no test.
fn in_grid(s: Stencil, q: vec3<i32>) -> bool {
    return all(q >= vec3<i32>(0)) && all(q < s.dims);
}

// The point `offset` leads to from point `point` (sign 1), or comes from (sign −1): no
// coordinates, one addition.
fn step_point(point: u32, offset: LatticeOffset, sign: i32) -> u32 {
    return point + bitcast<u32>(sign * offset.linear);
}

// Whether the spring of `offset` starting at point a (a and its end in the lattice) exists:
// every one of a cuboid, those of a mesh body that its mask keeps.
fn kept(s: Stencil, offset: LatticeOffset, a: u32) -> bool {
    let body = &lattice_bodies[s.body];
    if (*body).points == NONE {
        return true;
    }
    let bits = lattice_points[(*body).points + (*body).count + 2u * a + 1u];
    return ((bits >> offset.bit) & 1u) == 1u;
}

// The global particle at point q, which lies in the lattice.
fn particle_at(s: Stencil, q: u32) -> u32 {
    let body = &lattice_bodies[s.body];
    if (*body).points == NONE {
        return (*body).first + q;
    }
    return (*body).first + lattice_points[(*body).points + (*body).count + 2u * q];
}

// The spring of `offset` from particle a to particle b, as spring_force takes it.
fn lattice_spring(offset: LatticeOffset, a: u32, b: u32) -> Spring {
    return Spring(a, b, offset.rest, offset.stiffness, offset.damping);
}
