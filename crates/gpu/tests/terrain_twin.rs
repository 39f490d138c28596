//! `shaders/shared/terrain.wgsl` against its CPU twin `softbody_terrain::Surface::query`, on a
//! wgpu adapter: one probe kernel (`shaders/terrain_probe.wgsl`) evaluates every surface of a
//! terrain list holding each kind at every test point, and each test compares one surface's
//! column with the CPU's f64 answer at the same (f32-rounded) point.
//!
//! Points: uniform in a box around each shape, near its surface (random points moved onto
//! the surface by the CPU's push-back, then off it by 1e-4 … 0.3 m along the normal), and on
//! face interiors exactly (to f32 rounding). Every surface is evaluated at every point, so each
//! is also checked far from itself. Tolerances, with s = max(1 m, |x|, the shape's coordinate
//! magnitude):
//!
//! - φ: |φ_gpu − φ_cpu| ≤ 1e-5·s for the analytic kinds and the heightfield (within the
//!   window cap; beyond it the sign must agree and |φ_gpu| ≥ |φ_cpu|); for meshes
//!   |φ_gpu − φ_grid| ≤ 1e-5·s against the f64 sampler `SdfGrid::sample`, and |φ_gpu − φ_cpu| ≤
//!   h√3/2 + 1e-5·s where the CPU φ is 1-Lipschitz over the cell, 1e-5·s where it is affine.
//! - N: unit length within 1e-5; angle ≤ 1e-3 rad where |φ| ≥ 1e-3·s and at face-interior
//!   surface points, to the CPU normal or, where f32 cannot tell distances apart (within
//!   1e-6·s), to the normal of any of the tied features (box faces inside, heightfield
//!   triangles); for meshes in affine cells only.
//! - terrain_query_within(k, x, reach): the same φ where φ < reach, and φ ≥ reach otherwise.
//!
//! Without an adapter the tests are reported ignored, unless `SOFTBODY_REQUIRE_GPU=1`.

use std::process::ExitCode;
use std::sync::{Arc, OnceLock};

use glam::{DVec3, Vec4};
use softbody_gpu::Gpu;
use softbody_gpu::terrain::{
    HF_MAX_HALF_WINDOW, KIND_HEIGHTFIELD, KIND_MESH, TerrainBuffers, pack,
};
use softbody_scene::{FrictionModel, Heightfield, Terrain, TerrainShape, TriangleMesh};
use softbody_terrain::{CellTriangle, Contact, Surface};
use softbody_testkit::{Failed, Rng};

/// φ tolerance, relative to s.
const PHI_TOL: f64 = 1e-5;
/// Normal angle tolerance, radians.
const ANGLE_TOL: f64 = 1e-3;
/// Distances closer than this (relative to s) are ties to f32: either normal is right.
const TIE_TOL: f64 = 1e-6;

/// One terrain shape under test.
struct Case {
    name: &'static str,
    terrain: Terrain,
    /// Box the uniform points are drawn from.
    region: (DVec3, DVec3),
    /// Coordinate magnitude of the shape (for s).
    magnitude: f64,
    /// Points on face interiors (exact to f64; rounded to f32 later).
    surface_points: Vec<DVec3>,
}

fn terrain(shape: TerrainShape) -> Terrain {
    Terrain {
        shape,
        restitution: 0.3,
        friction: 0.4,
        friction_model: FrictionModel::Coulomb,
    }
}

fn heightfield(
    rows: usize,
    cols: usize,
    cell: [f64; 2],
    origin: DVec3,
    height: impl Fn(f64, f64) -> f64,
) -> Heightfield {
    Heightfield {
        heights: (0..rows)
            .map(|r| {
                (0..cols)
                    .map(|c| height(c as f64 * cell[0], r as f64 * cell[1]))
                    .collect()
            })
            .collect(),
        cell_size: cell,
        origin,
    }
}

/// Points on the interiors of a heightfield's triangles (away from edges and the diagonal).
fn heightfield_surface_points(h: &Heightfield, rng: &mut Rng, count: usize) -> Vec<DVec3> {
    let rows = h.heights.len();
    let cols = h.heights[0].len();
    let [dx, dz] = h.cell_size;
    (0..count)
        .map(|_| {
            let r = ((rng.unit() * (rows - 1) as f64) as usize).min(rows - 2);
            let c = ((rng.unit() * (cols - 1) as f64) as usize).min(cols - 2);
            let (mut u, mut v) = (rng.range(0.02, 0.96), rng.range(0.02, 0.96));
            if (u + v - 1.0).abs() < 0.02 {
                u *= 0.9;
                v *= 0.9;
            }
            let y = [0, 1].map(|dr| [0, 1].map(|dc| h.heights[r + dr][c + dc]));
            let height = CellTriangle::at(u, v).height(u, v, y);
            h.origin + DVec3::new((c as f64 + u) * dx, height, (r as f64 + v) * dz)
        })
        .collect()
}

/// Points on the interiors of a mesh's triangles.
fn mesh_surface_points(m: &TriangleMesh, rng: &mut Rng, count: usize) -> Vec<DVec3> {
    (0..count)
        .map(|_| {
            let t = m.triangles
                [((rng.unit() * m.triangles.len() as f64) as usize).min(m.triangles.len() - 1)];
            let [a, b, c] = t.map(|k| m.vertices[k as usize]);
            let (mut u, mut v) = (rng.range(0.05, 0.9), rng.range(0.05, 0.9));
            if u + v > 0.95 {
                (u, v) = (0.95 - v, 0.95 - u);
                (u, v) = (u.max(0.05), v.max(0.05));
            }
            a + u * (b - a) + v * (c - a)
        })
        .collect()
}

fn cube_mesh(lo: DVec3, size: f64) -> TriangleMesh {
    TriangleMesh::cube(lo, size)
}

fn cases() -> Vec<Case> {
    let mut rng = Rng::new(0x5eed);
    let mut cases = Vec::new();

    // Planes: points on the plane from two tangents.
    for (name, point, normal) in [
        ("plane", DVec3::new(0.0, -0.5, 0.0), DVec3::Y),
        (
            "tilted_plane",
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::new(0.3, 1.0, -0.2).normalize(),
        ),
    ] {
        let t1 = normal.any_orthonormal_vector();
        let t2 = normal.cross(t1);
        let surface_points = (0..300)
            .map(|_| point + rng.range(-2.0, 2.0) * t1 + rng.range(-2.0, 2.0) * t2)
            .collect();
        cases.push(Case {
            name,
            terrain: terrain(TerrainShape::Plane { point, normal }),
            region: (point - 2.0, point + 2.0),
            magnitude: point.length(),
            surface_points,
        });
    }

    // A rotated box: points on face interiors.
    let (center, half, deg) = (
        DVec3::new(0.5, 1.0, -0.3),
        DVec3::new(0.7, 0.4, 0.9),
        DVec3::new(20.0, 35.0, -50.0),
    );
    let rot = glam::DMat3::from_quat(softbody_scene::rotation_from_degrees(deg));
    let surface_points = (0..300)
        .map(|_| {
            let axis = (rng.unit() * 3.0) as usize % 3;
            let mut p = DVec3::new(
                rng.range(-0.95, 0.95) * half.x,
                rng.range(-0.95, 0.95) * half.y,
                rng.range(-0.95, 0.95) * half.z,
            );
            p[axis] = if rng.unit() < 0.5 {
                -half[axis]
            } else {
                half[axis]
            };
            center + rot * p
        })
        .collect();
    cases.push(Case {
        name: "rotated_box",
        terrain: terrain(TerrainShape::Box {
            center,
            half_extents: half,
            rotation: deg,
        }),
        region: (center - 1.6, center + 1.6),
        magnitude: center.length() + half.length(),
        surface_points,
    });

    // Sphere and bowl.
    for (name, center, radius) in [
        ("sphere", DVec3::new(-1.0, 0.5, 2.0), 0.8),
        ("bowl", DVec3::new(0.2, 1.5, -0.7), 1.3),
    ] {
        let surface_points = (0..300)
            .map(|_| center + radius * rng.direction())
            .collect();
        let shape = if name == "sphere" {
            TerrainShape::Sphere { center, radius }
        } else {
            TerrainShape::Bowl { center, radius }
        };
        cases.push(Case {
            name,
            terrain: terrain(shape),
            region: (center - radius - 0.5, center + radius + 0.5),
            magnitude: center.length() + radius,
            surface_points,
        });
    }

    // Heightfields: bumps with noise on 0.25 × 0.2 m cells; a fine rough one (0.05 × 0.04 m
    // cells) whose points 1 m above lie beyond the search window cap (8 cells = 0.32 m).
    let noise = std::cell::RefCell::new(Rng::new(17));
    let bumps = heightfield(13, 17, [0.25, 0.2], DVec3::new(-1.5, 0.3, -1.7), |x, z| {
        0.12 * (std::f64::consts::TAU * x / 1.5).cos() * (std::f64::consts::TAU * z / 1.2).cos()
            + noise.borrow_mut().range(-0.05, 0.05)
    });
    let noise = std::cell::RefCell::new(Rng::new(23));
    let fine = heightfield(50, 40, [0.05, 0.04], DVec3::new(2.0, -0.5, 1.0), |_, _| {
        noise.borrow_mut().range(-0.1, 0.1)
    });
    for (name, h) in [("heightfield_bumps", bumps), ("heightfield_fine", fine)] {
        let rows = h.heights.len();
        let cols = h.heights[0].len();
        let extent = DVec3::new(
            h.cell_size[0] * (cols - 1) as f64,
            0.0,
            h.cell_size[1] * (rows - 1) as f64,
        );
        let surface_points = heightfield_surface_points(&h, &mut rng, 400);
        let lo = h.origin + DVec3::new(-0.3, -0.6, -0.3);
        let hi = h.origin + extent + DVec3::new(0.3, 1.0, 0.3);
        cases.push(Case {
            name,
            magnitude: lo.abs().max(hi.abs()).length(),
            terrain: terrain(TerrainShape::Heightfield(h)),
            region: (lo, hi),
            surface_points,
        });
    }

    // Meshes: the ramp of scenes/terrain.obj (open) and a closed cube.
    let obj = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/terrain.obj");
    let ramp = softbody_scene::mesh::load_obj(&obj).expect("scenes/terrain.obj");
    let cube = cube_mesh(DVec3::new(-3.0, 0.2, -2.5), 1.2);
    for (name, m, lo, hi) in [
        (
            "mesh_terrain_obj",
            ramp,
            DVec3::new(-1.6, -0.4, -0.8),
            DVec3::new(2.6, 0.8, 0.8),
        ),
        (
            "mesh_cube",
            cube,
            DVec3::new(-3.5, -0.3, -3.0),
            DVec3::new(-1.3, 1.9, -0.8),
        ),
    ] {
        let surface_points = mesh_surface_points(&m, &mut rng, 400);
        cases.push(Case {
            name,
            magnitude: lo.abs().max(hi.abs()).length(),
            terrain: terrain(TerrainShape::Mesh(m)),
            region: (lo, hi),
            surface_points,
        });
    }

    // Geometry the CPU refuses: touches nothing.
    cases.push(Case {
        name: "none_zero_normal_plane",
        terrain: terrain(TerrainShape::Plane {
            point: DVec3::ZERO,
            normal: DVec3::ZERO,
        }),
        region: (DVec3::splat(-1.0), DVec3::ONE),
        magnitude: 1.0,
        surface_points: Vec::new(),
    });
    cases
}

/// A test point: f32-exact position, reach, and whether it lies on a face interior of
/// surface `on_surface` (normals compared there whatever φ).
#[derive(Clone, Copy)]
struct Point {
    x: DVec3,
    reach: f64,
    on_surface: Option<usize>,
}

struct Probe {
    adapter: String,
    cases: Vec<Case>,
    cpu: Vec<Surface>,
    packed: TerrainBuffers,
    points: Vec<Point>,
    /// Per point and surface: [terrain_query, terrain_query_within].
    out: Vec<[Vec4; 2]>,
}

fn round32(x: DVec3) -> DVec3 {
    x.as_vec3().as_dvec3()
}

fn make_points(cases: &[Case], cpu: &[Surface]) -> Vec<Point> {
    let mut rng = Rng::new(99);
    let mut points = Vec::new();
    let mut push = |x: DVec3, on_surface: Option<usize>, rng: &mut Rng| {
        points.push(Point {
            x: round32(x),
            reach: f64::from(rng.range(-0.2, 0.6) as f32),
            on_surface,
        });
    };
    for (k, case) in cases.iter().enumerate() {
        let (lo, hi) = case.region;
        for _ in 0..1500 {
            let x = rng.in_box(lo, hi);
            push(x, None, &mut rng);
        }
        // Near the surface: onto it by the push-back, then off along the normal.
        for _ in 0..1500 {
            let x = rng.in_box(lo, hi);
            let Some(c) = cpu[k].query(x, f64::INFINITY) else {
                continue;
            };
            let on = x - c.phi * c.normal;
            let offset =
                10f64.powf(rng.range(-4.0, -0.5)) * if rng.unit() < 0.5 { -1.0 } else { 1.0 };
            let y = on
                + offset
                    * cpu[k]
                        .query(on, f64::INFINITY)
                        .map_or(c.normal, |c| c.normal);
            push(y, None, &mut rng);
        }
        for &x in &case.surface_points {
            push(x, Some(k), &mut rng);
        }
    }
    points
}

/// The probe's output for `points` on `gpu`: (N, φ) of `terrain_query` and
/// `terrain_query_within` per point and surface.
fn run_probe(
    gpu: &Arc<Gpu>,
    packed: &TerrainBuffers,
    points: &[Point],
) -> Result<Vec<[Vec4; 2]>, String> {
    let input: Vec<Vec4> = points
        .iter()
        .map(|p| p.x.as_vec3().extend(p.reach as f32))
        .collect();
    softbody_gpu::debug::terrain_probe(gpu, packed, &input).map_err(|e| e.to_string())
}

fn probe(dev: &Arc<Gpu>) -> Result<Probe, String> {
    let cases = cases();
    let terrains: Vec<Terrain> = cases.iter().map(|c| c.terrain.clone()).collect();
    let cpu: Vec<Surface> = terrains.iter().map(Surface::new).collect();
    let packed = pack(&terrains);
    let points = make_points(&cases, &cpu);
    let t = std::time::Instant::now();
    let out = run_probe(dev, &packed, &points)?;
    eprintln!(
        "terrain_twin: {} points × {} surfaces on {} in {:.2} s",
        points.len(),
        cases.len(),
        dev.name(),
        t.elapsed().as_secs_f64()
    );
    Ok(Probe {
        adapter: dev.name(),
        cases,
        cpu,
        packed,
        points,
        out,
    })
}

fn angle(a: DVec3, b: DVec3) -> f64 {
    a.normalize_or_zero().angle_between(b.normalize_or_zero())
}

fn d3(v: Vec4) -> DVec3 {
    v.truncate().as_dvec3()
}

/// The point of triangle (a, b, c) closest to p (Ericson, Real-Time Collision Detection 5.1.5).
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + d1 / (d1 - d3) * ab;
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + d2 / (d2 - d6) * ac;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
    }
    let denom = 1.0 / (va + vb + vc);
    a + vb * denom * ab + vc * denom * ac
}

/// The normals an exact answer could give at x when distances within `eta` count as ties
/// (f32 cannot tell them apart): the CPU normal, plus, for a box inside, every face within
/// `eta` of the nearest, and for a heightfield, the normal towards every triangle within
/// `eta` of the nearest (its own normal where that distance is within the GPU's ε).
fn tie_normals(shape: &TerrainShape, x: DVec3, c: Contact, eta: f64, gpu_eps: f64) -> Vec<DVec3> {
    let mut out = vec![c.normal];
    match shape {
        TerrainShape::Box {
            center,
            half_extents,
            rotation,
        } if c.phi < 0.0 => {
            let r = glam::DMat3::from_quat(softbody_scene::rotation_from_degrees(*rotation));
            let p = r.transpose() * (x - *center);
            let q = p.abs() - *half_extents;
            for a in 0..3 {
                if q[a] >= q.max_element() - eta {
                    let mut n = DVec3::ZERO;
                    n[a] = if p[a] < 0.0 { -1.0 } else { 1.0 };
                    out.push(r * n);
                }
            }
        }
        TerrainShape::Heightfield(h) => {
            let rows = h.heights.len();
            let cols = h.heights[0].len();
            let [dx, dz] = h.cell_size;
            let v = |r: usize, c: usize| {
                h.origin + DVec3::new(c as f64 * dx, h.heights[r][c], r as f64 * dz)
            };
            let reach = c.phi.abs() + eta;
            let p = x - h.origin;
            let range = |lo: f64, hi: f64, cell: f64, n: usize| {
                let a = ((lo / cell).floor().max(0.0) as usize).min(n - 2);
                let b = ((hi / cell).floor().max(0.0) as usize).min(n - 2);
                a..=b
            };
            for r in range(p.z - reach, p.z + reach, dz, rows) {
                for cc in range(p.x - reach, p.x + reach, dx, cols) {
                    for half in CellTriangle::BOTH {
                        let [a, b, t] = half.corners().map(|[dr, dc]| v(r + dr, cc + dc));
                        let q = closest_on_triangle(x, a, b, t);
                        let d = (x - q).length();
                        if d <= c.phi.abs() + eta {
                            if d > 0.0 {
                                let n = (x - q) / d;
                                out.push(if c.phi < 0.0 { -n } else { n });
                            }
                            if d <= 2.0 * gpu_eps {
                                out.push((b - a).cross(t - a).normalize());
                            }
                        }
                    }
                }
            }
        }
        _ => {}
    }
    out
}

#[derive(Default, Debug)]
struct Stats {
    compared_phi: usize,
    max_phi_err: f64,
    compared_normals: usize,
    max_angle: f64,
    beyond_window: usize,
    max_within_err: f64,
    /// Meshes: GPU vs the f64 sampler.
    max_grid_err: f64,
    lipschitz: usize,
    max_err_lipschitz: f64,
    affine: usize,
    /// Normals that matched a tie's rather than the CPU's.
    ties: usize,
}

fn check(p: &Probe, k: usize) -> Result<String, Failed> {
    let case = &p.cases[k];
    let cpu = &p.cpu[k];
    let gs = &p.packed.surfaces[k];
    let count = p.cases.len();
    let mut st = Stats::default();
    let mut fail = Vec::new();
    let mut fail_at = |msg: String| {
        if fail.len() < 10 {
            fail.push(msg);
        }
    };
    for (i, pt) in p.points.iter().enumerate() {
        let x = pt.x;
        let [full, within] = p.out[i * count + k];
        let (g_phi, g_n) = (f64::from(full.w), d3(full));
        let s = 1f64.max(x.length()).max(case.magnitude);
        let tol = PHI_TOL * s;
        let Some(c) = cpu.query(x, f64::INFINITY) else {
            // Geometry that touches nothing.
            st.compared_phi += 1;
            if !(g_phi >= 1e38 && within.w >= 1e38) {
                fail_at(format!("{x}: CPU none, GPU φ {g_phi}"));
            }
            continue;
        };
        if (g_n.length() - 1.0).abs() > 1e-5 {
            fail_at(format!("{x}: |N| = {}", g_n.length()));
        }

        // The reach variant.
        let reach = pt.reach;
        let w_phi = f64::from(within.w);
        if c.phi < reach - tol {
            st.max_within_err = st.max_within_err.max((w_phi - g_phi).abs());
            if (w_phi - g_phi).abs() > tol {
                fail_at(format!("{x}: within reach {reach}: φ {w_phi} vs {g_phi}"));
            }
        } else if c.phi > reach + tol && w_phi < reach && (w_phi - g_phi).abs() > tol {
            fail_at(format!(
                "{x}: beyond reach {reach} (φ {}) but within gives {w_phi}",
                c.phi
            ));
        }

        let mut compare_normal = false;
        if gs.kind == KIND_MESH {
            let (grid, values) = p.packed.sdf(k).expect("a mesh has a grid");
            let (grid_phi, grid_n) = grid.sample(values, x);
            let err = (g_phi - grid_phi).abs();
            st.max_grid_err = st.max_grid_err.max(err);
            if err > tol {
                fail_at(format!("{x}: GPU φ {g_phi} vs f64 sampler {grid_phi}"));
            }
            // Normals of the sampler, away from cell faces (the gradient jumps there).
            let h = f64::from(gs.center[3]);
            let origin = DVec3::new(
                gs.center[0].into(),
                gs.center[1].into(),
                gs.center[2].into(),
            );
            let g = (x - origin) / h;
            let frac = g - g.floor();
            if frac.min_element() > 1e-3
                && frac.max_element() < 1.0 - 1e-3
                && angle(g_n, grid_n) > ANGLE_TOL
            {
                fail_at(format!("{x}: GPU N {g_n} vs f64 sampler {grid_n}"));
            }
            // Against the CPU: Lipschitz and affine cells of the node grid.
            let cell = g.floor();
            let inside = g.cmpge(DVec3::ZERO).all()
                && g.cmplt(
                    DVec3::new(gs.dims[0] as f64, gs.dims[1] as f64, gs.dims[2] as f64) - 1.0,
                )
                .all();
            if inside {
                let corners: Vec<DVec3> = (0..8)
                    .map(|m| {
                        origin
                            + h * (cell
                                + DVec3::new((m & 1) as f64, (m >> 1 & 1) as f64, (m >> 2) as f64))
                    })
                    .collect();
                let values: Vec<_> = corners
                    .iter()
                    .map(|&y| cpu.query(y, f64::INFINITY).unwrap())
                    .collect();
                let lipschitz = (0..8).all(|a| {
                    (0..8).all(|b| {
                        (values[a].phi - values[b].phi).abs()
                            <= (corners[a] - corners[b]).length() * (1.0 + 1e-9) + 1e-12
                    })
                });
                let err = (g_phi - c.phi).abs();
                if lipschitz {
                    st.lipschitz += 1;
                    st.max_err_lipschitz = st.max_err_lipschitz.max(err);
                    if err > h * 3f64.sqrt() / 2.0 + tol {
                        fail_at(format!(
                            "{x}: φ {g_phi} vs CPU {} beyond the grid bound",
                            c.phi
                        ));
                    }
                }
                let plane = c.phi - c.normal.dot(x);
                let affine = values.iter().zip(&corners).all(|(v, y)| {
                    (v.normal - c.normal).length() < 1e-9
                        && (v.phi - v.normal.dot(*y) - plane).abs() < 1e-9
                });
                if affine {
                    st.affine += 1;
                    st.compared_phi += 1;
                    st.max_phi_err = st.max_phi_err.max(err);
                    if err > tol {
                        fail_at(format!("{x}: affine cell, φ {g_phi} vs CPU {}", c.phi));
                    }
                    compare_normal = true;
                }
            }
        } else {
            let err = (g_phi - c.phi).abs();
            let window = f64::from(HF_MAX_HALF_WINDOW) * f64::from(gs.axis[0].min(gs.axis[1]));
            if gs.kind == KIND_HEIGHTFIELD && c.phi.abs() > window {
                // Beyond the cap: exact sign, never closer than the truth.
                st.beyond_window += 1;
                if g_phi.signum() != c.phi.signum() || g_phi.abs() < c.phi.abs() - tol {
                    fail_at(format!(
                        "{x}: beyond the window, φ {g_phi} vs CPU {}",
                        c.phi
                    ));
                }
            } else {
                st.compared_phi += 1;
                st.max_phi_err = st.max_phi_err.max(err / s);
                if err > tol {
                    fail_at(format!(
                        "{x}: φ {g_phi} vs CPU {} (Δ {err:.3e}, s {s})",
                        c.phi
                    ));
                }
                compare_normal = pt.on_surface == Some(k) || c.phi.abs() >= 1e-3 * s;
            }
        }
        if compare_normal {
            let a = if gs.kind == KIND_MESH {
                angle(g_n, c.normal)
            } else {
                tie_normals(
                    &case.terrain.shape,
                    x,
                    c,
                    TIE_TOL * s,
                    f64::from(gs.center[3]),
                )
                .into_iter()
                .map(|n| angle(g_n, n))
                .fold(f64::INFINITY, f64::min)
            };
            st.compared_normals += 1;
            if angle(g_n, c.normal) > ANGLE_TOL {
                st.ties += 1;
            }
            st.max_angle = st.max_angle.max(a);
            if a > ANGLE_TOL {
                fail_at(format!(
                    "{x}: N {g_n} vs CPU {} ({a:.3e} rad, φ {})",
                    c.normal, c.phi
                ));
            }
        }
    }
    let summary = format!(
        "{} on {}: φ compared at {} points, max |Δφ| {:.3e}{}; normals at {} ({} ties), max angle {:.3e} rad; \
         reach variant max |Δφ| {:.3e}{}{}",
        case.name,
        p.adapter,
        st.compared_phi,
        st.max_phi_err,
        if gs.kind == KIND_MESH {
            " m (affine cells)"
        } else {
            "·s"
        },
        st.compared_normals,
        st.ties,
        st.max_angle,
        st.max_within_err,
        if st.beyond_window > 0 {
            format!(
                "; {} points beyond the window cap (sign and bound checked)",
                st.beyond_window
            )
        } else {
            String::new()
        },
        if gs.kind == KIND_MESH {
            format!(
                "; GPU vs f64 sampler max |Δφ| {:.3e} m; {} points in Lipschitz cells, max |φ − φ_cpu| {:.3e} m (bound h√3/2 = {:.3e} m)",
                st.max_grid_err,
                st.lipschitz,
                st.max_err_lipschitz,
                f64::from(gs.center[3]) * 3f64.sqrt() / 2.0
            )
        } else {
            String::new()
        }
    );
    if fail.is_empty() {
        Ok(summary)
    } else {
        Err(format!("{summary}\n{}", fail.join("\n")).into())
    }
}

/// The probe runs once, on the binary's device; every test checks one surface's column.
static PROBE: OnceLock<Result<Probe, String>> = OnceLock::new();

/// One surface's column of the probe against the CPU.
fn surface(gpu: &Arc<Gpu>, k: usize) -> Result<(), Failed> {
    let p = PROBE.get_or_init(|| probe(gpu)).as_ref()?;
    let summary = check(p, k)?;
    println!("{summary}");
    Ok(())
}

fn main() -> ExitCode {
    let tests = cases()
        .into_iter()
        .enumerate()
        .map(|(k, case)| (case.name, move |gpu: &Arc<Gpu>| surface(gpu, k)));
    softbody_testkit::run_gpu("terrain twin tests", tests)
}
