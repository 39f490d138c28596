// stencil.wgsl ↔ crates/cpu/src/spring_forces/stencil.rs: the fused step's springs for models
// whose bodies are all lattices (cuboids, mesh bodies), found as constant offsets on the body's
// lattice; prepended to fused_step.wgsl in place of gather.wgsl and fused_gather.wgsl by
// crates/gpu/src/shaders.rs (`Stage::FusedStencil`). No spring record and no adjacency is read:
// a spring's parameters are its offset's, one table per body (`lattice_bodies`), and its
// partner is the point p ± d.
//
// gather(i) has gather.wgsl's result bit for bit. The CSR run of particle i at point p is, in
// ascending spring order, the springs ending at p (first end p − d, which ascends as the linear
// offset of d descends), then those starting at p in topology::OFFSETS order; the sum here
// takes exactly these, −f then +f, in that order, each computed by fused_gather.wgsl's call
// spring_force(spring, x_a, x_b, v_a, v_b) in the spring's own (a, b) orientation. A spring
// that does not exist is skipped, not added as a zero. Two offsets of equal linear offset
// never both end at one point (its partner would be one point at two places), so their
// relative order in `backward` does not matter.

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

// Whether point q lies in a grid of `dims` points per axis.
fn in_grid(q: vec3<i32>, dims: vec3<i32>) -> bool {
    return all(q >= vec3<i32>(0)) && all(q < dims);
}

// The point `offset` leads to from point `point` (or, with `sign` −1, comes from).
fn step_point(point: u32, offset: LatticeOffset, sign: i32) -> u32 {
    return point + bitcast<u32>(sign * offset.linear);
}

// For the spring of `offset` starting at point a (a and its end in the grid) of lattice body
// b: whether it exists, and its particle at point q (a or its end). A cuboid keeps every
// spring, and its particle is its point; a mesh body's mask says both.
fn kept(b: u32, offset: LatticeOffset, a: u32) -> bool {
    let body = &lattice_bodies[b];
    if (*body).points == NONE {
        return true;
    }
    let bits = lattice_points[(*body).points + (*body).count + 2u * a + 1u];
    return ((bits >> offset.bit) & 1u) == 1u;
}

fn particle_of_point(b: u32, q: u32) -> u32 {
    let body = &lattice_bodies[b];
    if (*body).points == NONE {
        return (*body).first + q;
    }
    return (*body).first + lattice_points[(*body).points + (*body).count + 2u * q];
}

// The spring of `offset` from particle a to particle b, as spring_force takes it.
fn lattice_spring(offset: LatticeOffset, a: u32, b: u32) -> Spring {
    return Spring(a, b, offset.rest, offset.stiffness, offset.damping);
}

// Σ of particle i's spring forces at the state (x, v), own_x and own_v being its own: the
// CSR gather's sum (above). Point p is in the grid, so a spring ending (starting) at p exists
// where its other end p − d (p + d) is in the grid and the mask, if any, keeps it: one bounds
// test per offset, and the other end's point is p's index ∓ the offset's linear step.
fn gather(i: u32) -> vec3<f32> {
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
    let n = (*body).n_offsets;
    var sum = vec3<f32>(0.0);
    for (var r = 0u; r < n; r++) {
        let offset = (*body).offsets[(*body).backward[r]];
        let q = step_point(point, offset, -1);
        if in_grid(p - offset.d, dims) && kept(b, offset, q) {
            let a = particle_of_point(b, q);
            sum -= spring_force(lattice_spring(offset, a, i), x[a].xyz, own_x, v[a].xyz, own_v);
        }
    }
    for (var r = 0u; r < n; r++) {
        let offset = (*body).offsets[r];
        if in_grid(p + offset.d, dims) && kept(b, offset, point) {
            let o = particle_of_point(b, step_point(point, offset, 1));
            sum += spring_force(lattice_spring(offset, i, o), own_x, x[o].xyz, own_v, v[o].xyz);
        }
    }
    return sum;
}
