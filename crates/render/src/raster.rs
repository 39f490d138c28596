//! Triangle and line rasterization with a depth buffer.
//!
//! Triangles are clipped in camera space against the near plane z = [`NEAR`] and against the
//! four sides of the view widened by a [`GUARD`]-pixel band (Sutherland–Hodgman; every clip
//! plane is linear in camera coordinates), projected, and filled by the edge-function rule:
//! with vertices snapped to 1/[`SUBPIXEL`] pixel, E_ab(p) = (b_x − a_x)(p_y − a_y) − (b_y − a_y)(p_x − a_x)
//! is exact in integers, and a pixel is covered when its centre p has E > 0 for all three edges
//! of the (consistently oriented) triangle, or E = 0 on a top or left edge (the top-left rule:
//! two triangles sharing an edge cover each pixel centre on it exactly once). Depth is
//! w = 1/z, which is affine in screen space, interpolated with the barycentric weights E/area;
//! the larger w (the nearer point) wins, and the buffer starts at w = 0 (infinitely far).

use glam::{DVec2, DVec3};

use crate::camera::{NEAR, View};

/// Sub-pixel steps per pixel of the snapped vertex positions.
pub const SUBPIXEL: i64 = 256;

/// Pixels beyond each side of the picture to which primitives are clipped (so that snapped
/// coordinates stay small and exact).
pub const GUARD: f64 = 16.0;

/// A colour buffer with a depth buffer.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Buffer {
    pub width: usize,
    pub height: usize,
    /// RGB per pixel, rows from the top.
    pub color: Vec<[u8; 3]>,
    /// 1/z per pixel (0: nothing drawn).
    pub depth: Vec<f64>,
}

impl Buffer {
    pub fn new(width: usize, height: usize, fill: [u8; 3]) -> Buffer {
        Buffer {
            width,
            height,
            color: vec![fill; width * height],
            depth: vec![0.0; width * height],
        }
    }
}

/// A projected vertex: pixel position and w = 1/z.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ScreenVertex {
    pub x: f64,
    pub y: f64,
    pub w: f64,
}

/// The clip planes as functions of camera coordinates that are ≥ 0 inside: near, left, right,
/// top, bottom (screen x ≥ −G ⇔ (c_x + G)z + F x ≥ 0, and so on).
fn clip_planes(view: &View, width: usize, height: usize) -> [[f64; 4]; 5] {
    let (f, cx, cy) = (view.focal(), view.cx(), view.cy());
    let (w, h) = (width as f64, height as f64);
    // [a, b, c, d]: a x + b y + c z + d.
    [
        [0.0, 0.0, 1.0, -NEAR],
        [f, 0.0, cx + GUARD, 0.0],
        [-f, 0.0, w + GUARD - cx, 0.0],
        [0.0, -f, cy + GUARD, 0.0],
        [0.0, f, h + GUARD - cy, 0.0],
    ]
}

fn side(plane: &[f64; 4], c: DVec3) -> f64 {
    plane[0] * c.x + plane[1] * c.y + plane[2] * c.z + plane[3]
}

/// Draws the triangle with camera-space corners `c` in `color`.
pub(crate) fn triangle(buf: &mut Buffer, view: &View, c: [DVec3; 3], color: [u8; 3]) {
    // Sutherland–Hodgman: at most 3 + 5 vertices after five planes.
    let mut poly: Vec<DVec3> = c.to_vec();
    let mut next = Vec::with_capacity(8);
    for plane in clip_planes(view, buf.width, buf.height) {
        next.clear();
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            let (sa, sb) = (side(&plane, a), side(&plane, b));
            if sa >= 0.0 {
                next.push(a);
            }
            if (sa >= 0.0) != (sb >= 0.0) {
                next.push(a + (b - a) * (sa / (sa - sb)));
            }
        }
        std::mem::swap(&mut poly, &mut next);
        if poly.len() < 3 {
            return;
        }
    }
    let s: Vec<ScreenVertex> = poly
        .iter()
        .map(|&p| {
            let q = view.to_screen(p);
            ScreenVertex {
                x: q.x,
                y: q.y,
                w: 1.0 / p.z,
            }
        })
        .collect();
    for k in 1..s.len() - 1 {
        screen_triangle(buf, [s[0], s[k], s[k + 1]], color);
    }
}

/// Snaps a pixel coordinate to the sub-pixel grid.
fn snap(v: f64) -> i64 {
    (v * SUBPIXEL as f64).round() as i64
}

/// E_ab(p) in sub-pixel units squared.
fn edge(a: (i64, i64), b: (i64, i64), p: (i64, i64)) -> i64 {
    (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0)
}

/// Fills the projected triangle `v` (coordinates within the guard band) in `color`.
pub(crate) fn screen_triangle(buf: &mut Buffer, v: [ScreenVertex; 3], color: [u8; 3]) {
    let mut p = v.map(|s| (snap(s.x), snap(s.y)));
    let mut w = v.map(|s| s.w);
    let mut area = edge(p[0], p[1], p[2]);
    if area == 0 {
        return;
    }
    // Either winding is drawn (the shading is two-sided): orient so that the area is positive.
    if area < 0 {
        p.swap(1, 2);
        w.swap(1, 2);
        area = -area;
    }
    // Edge k is opposite vertex k; a top edge is horizontal with the inside below it (dy = 0,
    // dx > 0 with y down), a left edge goes up the screen (dy < 0).
    let edges = [(p[1], p[2]), (p[2], p[0]), (p[0], p[1])];
    let top_left = edges.map(|(a, b)| {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        dy < 0 || (dy == 0 && dx > 0)
    });
    // Pixel i's centre is at i·S + S/2: the pixels whose centres lie in [lo, hi].
    let half = SUBPIXEL / 2;
    let range = |lo: i64, hi: i64, n: usize| {
        let first = (lo - half + SUBPIXEL - 1).div_euclid(SUBPIXEL).max(0);
        let last = (hi - half).div_euclid(SUBPIXEL).min(n as i64 - 1);
        (first, last)
    };
    let (x0, x1) = range(
        p.iter().map(|q| q.0).min().unwrap_or(0),
        p.iter().map(|q| q.0).max().unwrap_or(0),
        buf.width,
    );
    let (y0, y1) = range(
        p.iter().map(|q| q.1).min().unwrap_or(0),
        p.iter().map(|q| q.1).max().unwrap_or(0),
        buf.height,
    );
    let inv_area = 1.0 / area as f64;
    for j in y0..=y1 {
        let py = j * SUBPIXEL + half;
        let start = (x0 * SUBPIXEL + half, py);
        let mut e = edges.map(|(a, b)| edge(a, b, start));
        // Moving one pixel right changes E_ab by −(b_y − a_y)·S.
        let step = edges.map(|(a, b)| -(b.1 - a.1) * SUBPIXEL);
        let row = j as usize * buf.width;
        for i in x0..=x1 {
            let inside = (0..3).all(|k| e[k] > 0 || (e[k] == 0 && top_left[k]));
            if inside {
                let depth =
                    (e[0] as f64 * w[0] + e[1] as f64 * w[1] + e[2] as f64 * w[2]) * inv_area;
                let at = row + i as usize;
                if depth > buf.depth[at] {
                    buf.depth[at] = depth;
                    buf.color[at] = color;
                }
            }
            for k in 0..3 {
                e[k] += step[k];
            }
        }
    }
}

/// Draws the segment between camera-space points `a` and `b`, one pixel wide, in `color`.
pub(crate) fn line(buf: &mut Buffer, view: &View, a: DVec3, b: DVec3, color: [u8; 3]) {
    // Parametric clipping: keep t ∈ [t0, t1] where every plane's side is ≥ 0.
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    for plane in clip_planes(view, buf.width, buf.height) {
        let (sa, sb) = (side(&plane, a), side(&plane, b));
        if sa < 0.0 && sb < 0.0 {
            return;
        }
        if sa < 0.0 {
            t0 = t0.max(sa / (sa - sb));
        } else if sb < 0.0 {
            t1 = t1.min(sa / (sa - sb));
        }
    }
    if t0 > t1 {
        return;
    }
    let (ca, cb) = (a + (b - a) * t0, a + (b - a) * t1);
    let (sa, sb) = (view.to_screen(ca), view.to_screen(cb));
    let (wa, wb) = (1.0 / ca.z, 1.0 / cb.z);
    let d: DVec2 = sb - sa;
    let n = d.x.abs().max(d.y.abs()).ceil().max(1.0) as u64;
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let q = sa + d * t;
        let (i, j) = (q.x.floor(), q.y.floor());
        if i < 0.0 || j < 0.0 || i >= buf.width as f64 || j >= buf.height as f64 {
            continue;
        }
        let at = j as usize * buf.width + i as usize;
        // 1/z is affine along the projected segment too.
        let depth = wa + (wb - wa) * t;
        if depth > buf.depth[at] {
            buf.depth[at] = depth;
            buf.color[at] = color;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: [u8; 3] = [255, 0, 0];
    const GREEN: [u8; 3] = [0, 255, 0];
    const BLACK: [u8; 3] = [0, 0, 0];

    fn sv(x: f64, y: f64, w: f64) -> ScreenVertex {
        ScreenVertex { x, y, w }
    }

    /// Strictly inside by barycentric coordinates computed independently in floating point.
    fn centre_inside(v: [ScreenVertex; 3], px: f64, py: f64) -> bool {
        let e =
            |a: ScreenVertex, b: ScreenVertex| (b.x - a.x) * (py - a.y) - (b.y - a.y) * (px - a.x);
        let (e0, e1, e2) = (e(v[1], v[2]), e(v[2], v[0]), e(v[0], v[1]));
        (e0 > 0.0 && e1 > 0.0 && e2 > 0.0) || (e0 < 0.0 && e1 < 0.0 && e2 < 0.0)
    }

    #[test]
    fn a_triangle_covers_exactly_the_pixels_whose_centres_are_inside() {
        // Vertices on the 1/256 grid but off the pixel-centre lattice, so no centre is on an
        // edge: coverage must equal the exact inside test. Both windings.
        for v in [
            [sv(2.1, 1.3, 1.0), sv(27.7, 9.9, 1.0), sv(8.05, 22.6, 1.0)],
            [sv(2.1, 1.3, 1.0), sv(8.05, 22.6, 1.0), sv(27.7, 9.9, 1.0)],
        ] {
            let mut buf = Buffer::new(32, 24, BLACK);
            screen_triangle(&mut buf, v, RED);
            let mut covered = 0;
            for j in 0..24 {
                for i in 0..32 {
                    let expect = centre_inside(v, i as f64 + 0.5, j as f64 + 0.5);
                    let got = buf.color[j * 32 + i] == RED;
                    assert_eq!(got, expect, "pixel ({i}, {j})");
                    covered += usize::from(got);
                }
            }
            // The area is 239.35 px²; the covered count is close to it.
            assert!((220..260).contains(&covered), "{covered}");
        }
    }

    #[test]
    fn the_top_left_rule_covers_a_shared_edge_once() {
        // A square [2, 10]² split along its diagonal: centres at half-integers, so the
        // diagonal through (2.5, 2.5), … and the square's sides pass through none, but the
        // diagonal y = x passes through every pixel centre (i + ½, i + ½).
        let (a, b, c, d) = (
            sv(2.0, 2.0, 1.0),
            sv(10.0, 2.0, 1.0),
            sv(10.0, 10.0, 1.0),
            sv(2.0, 10.0, 1.0),
        );
        let mut count = vec![0u8; 16 * 16];
        for tri in [[a, b, c], [a, c, d]] {
            let mut buf = Buffer::new(16, 16, BLACK);
            screen_triangle(&mut buf, tri, RED);
            for (n, px) in count.iter_mut().zip(&buf.color) {
                *n += u8::from(*px == RED);
            }
        }
        for j in 0..16 {
            for i in 0..16 {
                let inside = (2..10).contains(&i) && (2..10).contains(&j);
                assert_eq!(count[j * 16 + i], u8::from(inside), "pixel ({i}, {j})");
            }
        }
        // Pixel centres exactly on the left side x = 2.5 of a thin triangle are drawn, on its
        // right side x = 5.5 they are not.
        let mut buf = Buffer::new(8, 8, BLACK);
        screen_triangle(
            &mut buf,
            [sv(2.5, 0.0, 1.0), sv(5.5, 0.0, 1.0), sv(2.5, 8.0, 1.0)],
            RED,
        );
        assert_eq!(buf.color[3 * 8 + 2], RED);
        assert_eq!(buf.color[8 + 5], BLACK);
    }

    #[test]
    fn the_depth_buffer_keeps_the_nearer_triangle() {
        let big = |w| [sv(0.0, 0.0, w), sv(40.0, 0.0, w), sv(0.0, 40.0, w)];
        for order in [[0.5, 0.25], [0.25, 0.5]] {
            let mut buf = Buffer::new(16, 16, BLACK);
            // w = 1/z: 0.5 is 2 m away, 0.25 is 4 m away; the nearer one is green.
            for w in order {
                screen_triangle(&mut buf, big(w), if w == 0.5 { GREEN } else { RED });
            }
            assert!(buf.color.iter().all(|&c| c == GREEN));
            assert!(buf.depth.iter().all(|&d| d == 0.5));
        }
        // Interpolated depth: a triangle tilted in depth is drawn over a flat one only where
        // it is nearer. Left corner w = 1 (z = 1), right corners w = 1/3 (z = 3); the flat
        // one is at z = 2 (w = ½), crossed where 1/z = ½ at screen x = 12 (w = 1 − x/24).
        let mut buf = Buffer::new(16, 16, BLACK);
        screen_triangle(&mut buf, big(0.5), RED);
        screen_triangle(
            &mut buf,
            [
                sv(0.0, 8.0, 1.0),
                sv(16.0, -40.0, 1.0 / 3.0),
                sv(16.0, 56.0, 1.0 / 3.0),
            ],
            GREEN,
        );
        // Along row 8 the tilted triangle's w falls linearly from 1 at x = 0 to 1/3 at x = 16.
        for i in 0..16 {
            let w = 1.0 - (i as f64 + 0.5) / 24.0;
            let expect = if w > 0.5 { GREEN } else { RED };
            assert_eq!(buf.color[8 * 16 + i], expect, "pixel ({i}, 8)");
        }
    }
}
