// Terrain point queries on the GPU, in f32: the twin of crates/terrain (softbody-terrain; read
// its crate doc for the conventions; this file follows them as far as f32 allows).
//
// terrain_query(k, x) returns vec4(N, φ) for surface k: φ the signed distance (> 0 in free
// space, < 0 inside the solid) and N the outward unit normal, so that `x ← x − φ·N` puts a
// point back on the surface. terrain_query_within(k, x, reach) answers the same wherever
// φ < reach, and may stop early otherwise (it then only guarantees φ ≥ reach, and N is
// unspecified): heightfield queries far from the surface become cheap. Solvers that only care
// about contacts within a reach should call it.
//
// The surfaces and their bulk data are packed by crates/gpu/src/terrain.rs (`pack`), which
// holds the Rust mirror of SurfaceGpu; the mesh signed-distance grid, its constants and an f64
// twin of its sampler are in crates/terrain/src/sdf.rs.
//
// Per kind (field use of SurfaceGpu in brackets):
//
// - 0 plane [center.xyz point, axis.xyz unit normal]: φ = n̂·(x − point), N = n̂.
// - 1 box [center.xyz centre, center.w ε, axis.xyz half extents, rot0..rot2 the columns of
//   the box → world rotation]: outside, φ = Euclidean distance, N from the closest box point
//   to x; inside, φ = −(distance to the nearest face) (the lowest axis on ties, as parry),
//   N that face's normal. Within ε of the surface N is the face with the largest |p| − h
//   (lowest axis on ties).
// - 2 sphere, 3 bowl [center.xyz centre, center.w ε, axis.x radius]: φ = ±(|x − c| − R),
//   N radial; within ε of the centre N = +y.
// - 4 heightfield [center.xyz the world position of vertex (0, 0) at height 0, center.w ε,
//   axis = (dx, dz, min height, max height), dims = (rows, cols, offset, 0); heights at
//   terrain_data[offset + r·cols + c]]: parry's triangulation (`CellTriangle` in
//   crates/terrain/src/heightfield.rs: the cell of rows r, r+1 and columns c, c+1 is split
//   from vertex (r+1, c) to (r, c+1) into (r,c),(r+1,c),(r,c+1) and (r+1,c),(r+1,c+1),(r,c+1));
//   inside = within the footprint (edges included) and strictly below the triangle under
//   (x, z); |φ| = distance to the nearest triangle, searched over a window of cells (see
//   TERRAIN_HF_MAX_HALF_WINDOW); N from the nearest point to x (outside) or from x to it
//   (inside), or the nearest triangle's normal within ε.
// - 5 mesh [center.xyz grid origin (node (0,0,0)), center.w cell size h, dims = (nx, ny, nz,
//   offset); φ at node (i, j, k) = terrain_data[offset + i + nx·(j + ny·k)]]: the signed
//   distance grid baked on the CPU from the CPU twin's φ, sampled trilinearly; N = the
//   normalised gradient of the trilinear interpolant in the cell (+y where it vanishes).
//   Outside the grid box, with c the closest point of the box and d = |x − c|:
//   φ = φ(c) + sign(φ(c))·d (continuous, with the sign of the nearest grid value; the grid
//   is padded so that such points are at least the padding away from every triangle), and N
//   the normalised gradient of that expression. Error bounds: crates/terrain/src/sdf.rs.
// - 6 none (geometry the CPU twin refuses, e.g. a zero plane normal): φ = TERRAIN_FAR, N = +y.
//
// ε (center.w for box, ball, heightfield) is the f32 analogue of the CPU's degenerate-normal
// threshold, max(1e-4·M, 1e-9 m) with M the shape's coordinate magnitude (the CPU uses
// 1e-9·M in f64): below it the direction between x and its closest point is rounding noise.
//
// A point that is not a number gives φ = NaN (no comparison succeeds: no contact); indices
// stay in bounds whatever the input.

struct SurfaceGpu {
    kind: u32,
    // 0 coulomb, 1 viscous.
    friction_model: u32,
    restitution: f32,
    friction: f32,
    center: vec4<f32>,
    axis: vec4<f32>,
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    dims: vec4<u32>,
}

@group(1) @binding(0) var<storage, read> surfaces: array<SurfaceGpu>;
@group(1) @binding(1) var<storage, read> terrain_data: array<f32>;

const TERRAIN_PLANE: u32 = 0u;
const TERRAIN_BOX: u32 = 1u;
const TERRAIN_SPHERE: u32 = 2u;
const TERRAIN_BOWL: u32 = 3u;
const TERRAIN_HEIGHTFIELD: u32 = 4u;
const TERRAIN_MESH: u32 = 5u;
const TERRAIN_NONE: u32 = 6u;

// "No contact at any reach": φ of the none kind and the reach of terrain_query.
const TERRAIN_FAR: f32 = 3.0e38;

// Heightfield search window: the cells within max(radius, ·) of the point, where radius is
// the distance to the surface point straight above or below it (an upper bound on |φ|), but at
// most this many cells on each side of the point's own cell (so ≤ 17 × 17 cells, 578
// triangles). φ is exact (the nearest triangle is found) whenever the true |φ| ≤ this many
// times min(dx, dz); beyond, |φ| is the distance to the nearest triangle in the window, an
// upper bound that is at most the vertical distance, with the exact sign.
const TERRAIN_HF_MAX_HALF_WINDOW: u32 = 8u;

const TERRAIN_UP: vec3<f32> = vec3<f32>(0.0, 1.0, 0.0);

fn terrain_query(k: u32, x: vec3<f32>) -> vec4<f32> {
    return terrain_query_within(k, x, TERRAIN_FAR);
}

fn terrain_query_within(k: u32, x: vec3<f32>, reach: f32) -> vec4<f32> {
    let s = surfaces[k];
    switch s.kind {
        case TERRAIN_PLANE: {
            let n = s.axis.xyz;
            return vec4<f32>(n, dot(n, x - s.center.xyz));
        }
        case TERRAIN_BOX: {
            return terrain_box(s, x);
        }
        case TERRAIN_SPHERE, TERRAIN_BOWL: {
            return terrain_ball(s, x);
        }
        case TERRAIN_HEIGHTFIELD: {
            return terrain_heightfield(s, x, reach);
        }
        case TERRAIN_MESH: {
            return terrain_mesh(s, x);
        }
        default: {
            return vec4<f32>(TERRAIN_UP, TERRAIN_FAR);
        }
    }
}

fn terrain_ball(s: SurfaceGpu, x: vec3<f32>) -> vec4<f32> {
    let d = x - s.center.xyz;
    let r = length(d);
    // Within ε of the centre no direction is radial: N = +y.
    let centred = r <= s.center.w;
    var radial = TERRAIN_UP;
    if !centred {
        radial = d / r;
    }
    if s.kind == TERRAIN_BOWL {
        return vec4<f32>(select(-radial, TERRAIN_UP, centred), s.axis.x - r);
    }
    return vec4<f32>(radial, r - s.axis.x);
}

fn terrain_box(s: SurfaceGpu, x: vec3<f32>) -> vec4<f32> {
    let h = s.axis.xyz;
    let w = x - s.center.xyz;
    // Box coordinates: the transpose of the rotation, whose columns are rot0..rot2.
    let p = vec3<f32>(dot(s.rot0.xyz, w), dot(s.rot1.xyz, w), dot(s.rot2.xyz, w));
    let q = abs(p) - h;
    // The face with the largest |p| − h, the lowest axis on ties: the nearest face inside
    // (parry's choice) and the face rule on the surface.
    var k = 0u;
    if q.y > q.x {
        k = 1u;
    }
    if q.z > q[k] {
        k = 2u;
    }
    var face = vec3<f32>(0.0);
    face[k] = select(1.0, -1.0, p[k] < 0.0);
    var local = face;
    var phi: f32;
    if any(q > vec3<f32>(0.0)) {
        let diff = p - clamp(p, -h, h);
        let dist = length(diff);
        phi = dist;
        // Beyond ε the offset from the closest point is a direction, not rounding noise.
        if dist > s.center.w {
            local = diff / dist;
        }
    } else {
        phi = q[k];
    }
    let n = s.rot0.xyz * local.x + s.rot1.xyz * local.y + s.rot2.xyz * local.z;
    return vec4<f32>(n, phi);
}

// The point of triangle (a, b, c) closest to p (Ericson, Real-Time Collision Detection 5.1.5);
// in the face region it is p minus its offset along the unit normal, which keeps the distance
// exact to rounding for points near a triangle.
fn terrain_closest_on_triangle(p: vec3<f32>, a: vec3<f32>, b: vec3<f32>, c: vec3<f32>) -> vec3<f32> {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + (d1 / (d1 - d3)) * ab;
    }
    let cp = p - c;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + (d2 / (d2 - d6)) * ac;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
    }
    let n = normalize(cross(ab, ac));
    return p - dot(ap, n) * n;
}

fn terrain_height(offset: u32, cols: u32, r: u32, c: u32) -> f32 {
    return terrain_data[offset + r * cols + c];
}

// Vertex (r, c) of a heightfield in its local coordinates (vertex (0, 0) at height 0 is the
// origin).
fn terrain_hf_vertex(offset: u32, cols: u32, dx: f32, dz: f32, r: u32, c: u32) -> vec3<f32> {
    return vec3<f32>(f32(c) * dx, terrain_height(offset, cols, r, c), f32(r) * dz);
}

// Triangle `second` (0 or 1) of cell (r, c), as parry orders its vertices.
fn terrain_hf_triangle_normal(offset: u32, cols: u32, dx: f32, dz: f32, r: u32, c: u32, second: bool) -> vec3<f32> {
    let v10 = terrain_hf_vertex(offset, cols, dx, dz, r + 1u, c);
    let v01 = terrain_hf_vertex(offset, cols, dx, dz, r, c + 1u);
    var a = terrain_hf_vertex(offset, cols, dx, dz, r, c);
    var b = v10;
    if second {
        a = v10;
        b = terrain_hf_vertex(offset, cols, dx, dz, r + 1u, c + 1u);
    }
    // Cells have positive width and depth: the normal exists and points up.
    return normalize(cross(b - a, v01 - a));
}

fn terrain_heightfield(s: SurfaceGpu, x: vec3<f32>, reach: f32) -> vec4<f32> {
    let dx = s.axis.x;
    let dz = s.axis.y;
    let rows = s.dims.x;
    let cols = s.dims.y;
    let offset = s.dims.z;
    let p = x - s.center.xyz;
    let width = dx * f32(cols - 1u);
    let depth = dz * f32(rows - 1u);

    // The surface point straight above or below p (p clamped into the footprint): it decides
    // inside/outside, and its distance bounds the search for the nearest triangle.
    let in_footprint = p.x >= 0.0 && p.x <= width && p.z >= 0.0 && p.z <= depth;
    let xc = clamp(p.x, 0.0, width);
    let zc = clamp(p.z, 0.0, depth);
    let c = min(u32(floor(xc / dx)), cols - 2u);
    let r = min(u32(floor(zc / dz)), rows - 2u);
    let u = clamp((xc - f32(c) * dx) / dx, 0.0, 1.0);
    let v = clamp((zc - f32(r) * dz) / dz, 0.0, 1.0);
    let y00 = terrain_height(offset, cols, r, c);
    let y10 = terrain_height(offset, cols, r + 1u, c);
    let y01 = terrain_height(offset, cols, r, c + 1u);
    let y11 = terrain_height(offset, cols, r + 1u, c + 1u);
    let first = u + v <= 1.0;
    var height: f32;
    if first {
        height = y00 + u * (y01 - y00) + v * (y10 - y00);
    } else {
        height = y11 + (1.0 - u) * (y10 - y11) + (1.0 - v) * (y01 - y11);
    }
    let inside = in_footprint && p.y < height;

    var radius: f32;
    let below = vec3<f32>(xc, height, zc);
    var best_sq = dot(p - below, p - below);
    if inside {
        radius = sqrt(best_sq);
    } else {
        // Outside, φ ≥ the distance to the box around the surface: cheap refusals far away.
        let lo = vec3<f32>(0.0, s.axis.z, 0.0);
        let hi = vec3<f32>(width, s.axis.w, depth);
        let aabb_dist = length(p - clamp(p, lo, hi));
        if reach <= 0.0 || aabb_dist >= reach {
            return vec4<f32>(TERRAIN_UP, aabb_dist);
        }
        radius = min(sqrt(best_sq), reach);
    }

    var best_point = below;
    var best_r = r;
    var best_c = c;
    var best_second = !first;

    // Cells overlapping the square of half-size `radius` around p, capped around p's cell.
    let c_lo = max(u32(clamp(floor((p.x - radius) / dx), 0.0, f32(cols - 2u))),
                   c - min(c, TERRAIN_HF_MAX_HALF_WINDOW));
    let c_hi = min(u32(clamp(floor((p.x + radius) / dx), 0.0, f32(cols - 2u))),
                   c + TERRAIN_HF_MAX_HALF_WINDOW);
    let r_lo = max(u32(clamp(floor((p.z - radius) / dz), 0.0, f32(rows - 2u))),
                   r - min(r, TERRAIN_HF_MAX_HALF_WINDOW));
    let r_hi = min(u32(clamp(floor((p.z + radius) / dz), 0.0, f32(rows - 2u))),
                   r + TERRAIN_HF_MAX_HALF_WINDOW);
    // Columns outer, rows inner, first triangle then second: parry's order. Strict
    // comparisons: on ties the triangle under the point keeps its place, for a stable normal.
    for (var cc = c_lo; cc <= c_hi; cc++) {
        for (var rr = r_lo; rr <= r_hi; rr++) {
            let v00 = terrain_hf_vertex(offset, cols, dx, dz, rr, cc);
            let v10 = terrain_hf_vertex(offset, cols, dx, dz, rr + 1u, cc);
            let v01 = terrain_hf_vertex(offset, cols, dx, dz, rr, cc + 1u);
            let v11 = terrain_hf_vertex(offset, cols, dx, dz, rr + 1u, cc + 1u);
            let q1 = terrain_closest_on_triangle(p, v00, v10, v01);
            let sq1 = dot(p - q1, p - q1);
            if sq1 < best_sq {
                best_sq = sq1;
                best_point = q1;
                best_r = rr;
                best_c = cc;
                best_second = false;
            }
            let q2 = terrain_closest_on_triangle(p, v10, v11, v01);
            let sq2 = dot(p - q2, p - q2);
            if sq2 < best_sq {
                best_sq = sq2;
                best_point = q2;
                best_r = rr;
                best_c = cc;
                best_second = true;
            }
        }
    }

    let dist = sqrt(best_sq);
    var n: vec3<f32>;
    if dist > s.center.w {
        n = (p - best_point) / dist;
        if inside {
            n = -n;
        }
    } else {
        n = terrain_hf_triangle_normal(offset, cols, dx, dz, best_r, best_c, best_second);
    }
    return vec4<f32>(n, select(dist, -dist, inside));
}

fn terrain_sdf_node(offset: u32, nx: u32, ny: u32, i: u32, j: u32, k: u32) -> f32 {
    return terrain_data[offset + i + nx * (j + ny * k)];
}

fn terrain_mesh(s: SurfaceGpu, x: vec3<f32>) -> vec4<f32> {
    let lo = s.center.xyz;
    let h = s.center.w;
    let n = s.dims.xyz;
    let offset = s.dims.w;
    let hi = lo + h * vec3<f32>(n - vec3<u32>(1u));
    let c = clamp(x, lo, hi);
    let g = (c - lo) / h;
    let cell = min(vec3<u32>(floor(g)), n - vec3<u32>(2u));
    let t = clamp(g - vec3<f32>(cell), vec3<f32>(0.0), vec3<f32>(1.0));
    let i = cell.x;
    let j = cell.y;
    let k = cell.z;
    let c000 = terrain_sdf_node(offset, n.x, n.y, i, j, k);
    let c100 = terrain_sdf_node(offset, n.x, n.y, i + 1u, j, k);
    let c010 = terrain_sdf_node(offset, n.x, n.y, i, j + 1u, k);
    let c110 = terrain_sdf_node(offset, n.x, n.y, i + 1u, j + 1u, k);
    let c001 = terrain_sdf_node(offset, n.x, n.y, i, j, k + 1u);
    let c101 = terrain_sdf_node(offset, n.x, n.y, i + 1u, j, k + 1u);
    let c011 = terrain_sdf_node(offset, n.x, n.y, i, j + 1u, k + 1u);
    let c111 = terrain_sdf_node(offset, n.x, n.y, i + 1u, j + 1u, k + 1u);
    // Along x first, then y, then z.
    let c00 = mix(c000, c100, t.x);
    let c10 = mix(c010, c110, t.x);
    let c01 = mix(c001, c101, t.x);
    let c11 = mix(c011, c111, t.x);
    let c0 = mix(c00, c10, t.y);
    let c1 = mix(c01, c11, t.y);
    var phi = mix(c0, c1, t.z);
    // The analytic gradient of the trilinear interpolant, per unit length.
    let gx = mix(mix(c100 - c000, c110 - c010, t.y), mix(c101 - c001, c111 - c011, t.y), t.z);
    let gy = mix(c10 - c00, c11 - c01, t.z);
    let gz = c1 - c0;
    var grad = vec3<f32>(gx, gy, gz) / h;

    let d = x - c;
    let dist = length(d);
    if dist > 0.0 {
        let sgn = select(-1.0, 1.0, phi >= 0.0);
        phi = phi + sgn * dist;
        let outside_axis = d != vec3<f32>(0.0);
        grad = select(grad, sgn * d / dist, outside_axis);
    }
    let len = length(grad);
    var normal = TERRAIN_UP;
    if len > 0.0 {
        normal = grad / len;
    }
    return vec4<f32>(normal, phi);
}
