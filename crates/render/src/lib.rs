//! Headless pictures of `softbody` scenes: a deterministic CPU rasterizer, PNG and GIF output.
//!
//! A [`Renderer`] is built once from a [`Model`] (terrain, the bodies' outer surface, springs;
//! a mesh body's surface is its own mesh, whose vertices follow its particles) and the box the
//! bodies occupy over the frames to draw; [`Renderer::render_frame`] then draws one frame's
//! particle positions into an RGB [`Image`]:
//!
//! - a vertical background gradient, the terrain ([`terrain`]) and the bodies' surface
//!   triangles, through a pinhole [`Camera`] ([`camera`]) and a depth buffer ([`raster`]);
//! - flat Lambert shading with ambient light: c = c₀ (k_a + k_d max(0, n·l)) for a fixed light
//!   direction l ([`LIGHT`]) and the triangle's normal n turned towards the eye (two-sided, so
//!   inverted or open surfaces still read);
//! - the bodies' shadows on the terrain from that light ([`RenderOptions::shadows`]);
//! - with [`RenderOptions::springs`], every spring as a line coloured by its strain
//!   (|x_a − x_b| − r)/r on a blue–grey–red ramp ([`colormap`]) under a see-through surface,
//!   and the ramp as a legend in the bottom-left corner.
//!
//! Everything is computed in one thread in a fixed order from the inputs alone: the same
//! inputs give the same bytes, every run, on every machine with IEEE-754 doubles.
//!
//! [`animation`] draws a whole run: the camera placed once for every frame (automatically, or
//! as given) or following the bodies, the pictures written as numbered PNG files or as one GIF;
//! [`framing`] decides whether the automatic camera follows and how steeply it looks down.
//!
//! ```
//! use softbody_render::{Renderer, RenderOptions, Bounds};
//! use softbody_scene::{Model, Scene};
//! let scene = Scene::from_toml(r#"
//!     [simulation]
//!     dt = 0.001
//!     duration = 1.0
//!     [[body]]
//!     kind = "cuboid"
//!     size = [0.3, 0.3, 0.3]
//!     resolution = [3, 3, 3]
//!     center = [0.0, 0.5, 0.0]
//!     mass = 1.0
//!     structural = { stiffness = 100.0 }
//!     [[terrain]]
//!     kind = "plane"
//!     normal = [0.0, 1.0, 0.0]
//! "#, "inline.toml".as_ref()).unwrap();
//! let (model, state) = Model::build(&scene);
//! let options = RenderOptions { width: 160, height: 120, ..RenderOptions::default() };
//! let renderer = Renderer::new(&model, Bounds::of(&state.x), options).unwrap();
//! let image = renderer.render_frame(&state.x).unwrap();
//! assert_eq!((image.width(), image.height()), (160, 120));
//! let mut png = Vec::new();
//! image.write_png(&mut png).unwrap();
//! ```
#![warn(missing_docs)]

pub mod animation;
pub mod camera;
pub mod colormap;
mod encode;
pub mod framing;
pub mod raster;
pub mod terrain;
pub mod text;

use glam::DVec3;
use softbody_scene::Model;
use softbody_scene::model::Embedded;

pub use camera::Camera;
pub use colormap::strain_color;
pub use encode::{GifWriter, Image};

use raster::Buffer;

/// The largest picture side, pixels.
pub const MAX_SIZE: u32 = 8192;

/// The direction towards the light (unnormalised): above, in front, to the left, so that the
/// automatic camera (in front, to the right) sees lit, half-lit and shaded faces and the
/// shadows falling to the right and back.
pub const LIGHT: DVec3 = DVec3::new(-0.45, 1.0, 0.35);
/// The ambient share k_a of a surface's colour.
pub const AMBIENT: f64 = 0.4;
/// The diffuse share k_d of a surface's colour.
pub const DIFFUSE: f64 = 0.6;
/// The background at the top and at the bottom of the picture.
pub const SKY: [[u8; 3]; 2] = [[118, 156, 206], [224, 231, 238]];
/// The bodies' colours, by body index (repeating).
pub const BODY_COLORS: [[u8; 3]; 4] = [
    [236, 132, 58],
    [64, 160, 200],
    [150, 100, 200],
    [90, 175, 110],
];
/// How much of the surface colour covers what is behind it when springs are drawn.
pub const SURFACE_OPACITY_WITH_SPRINGS: f64 = 0.3;
/// The shadow map's side, cells.
pub const SHADOW_MAP: usize = 256;
/// What a shadow leaves of a terrain pixel's colour (about its ambient share).
pub const SHADOW: f64 = 0.6;
/// The default strain range ±s of the colormap: ±10 %.
pub const DEFAULT_STRAIN_RANGE: f64 = 0.1;
/// The colour of labels ([`label`], the colour bar's numbers): dark on the light sky.
pub const LABEL_COLOR: [u8; 3] = [20, 20, 20];

/// Draws `text` ([`text`]'s glyphs) in the top-left corner of `image`, a font pixel's margin
/// from its edges: the time stamp of `softbody render --label`.
pub fn label(image: &mut Image, text: &str) {
    let scale = text::scale_for(image.height());
    let margin = 2 * scale;
    text::draw(text, margin, margin, scale, |x, y| {
        image.set_pixel(x as u32, y as u32, LABEL_COLOR)
    });
}

/// What to draw and how big.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Picture width, pixels (1 to [`MAX_SIZE`]).
    pub width: u32,
    /// Picture height, pixels (1 to [`MAX_SIZE`]).
    pub height: u32,
    /// The camera; `None` frames the bodies' box and the finite terrain automatically
    /// ([`Camera::framing`]).
    pub camera: Option<Camera>,
    /// Draw every spring as a line coloured by its strain, under a see-through surface.
    pub springs: bool,
    /// The strain s drawn in the colormap's end colours (blue at −s, red at +s); > 0.
    pub strain_range: f64,
    /// Darken the terrain where the bodies' surface hides it from the light.
    pub shadows: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 640,
            height: 480,
            camera: None,
            springs: false,
            strain_range: DEFAULT_STRAIN_RANGE,
            shadows: true,
        }
    }
}

/// Why a picture cannot be drawn.
#[derive(Debug, Clone, PartialEq)]
pub enum RenderError {
    /// A picture side is 0 or above [`MAX_SIZE`].
    Size {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
    },
    /// The camera defines no view.
    Camera(String),
    /// The strain range is not a finite number > 0.
    StrainRange(f64),
    /// A frame's positions do not match the model's particles.
    Particles {
        /// The model's particle count.
        expected: usize,
        /// The frame's.
        got: usize,
    },
}

impl std::fmt::Display for RenderError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RenderError::Size { width, height } => write!(
                f,
                "the picture must be 1 to {MAX_SIZE} pixels wide and high, not {width}×{height}"
            ),
            RenderError::Camera(m) => f.write_str(m),
            RenderError::StrainRange(s) => {
                write!(f, "the strain range must be a finite number > 0, not {s}")
            }
            RenderError::Particles { expected, got } => write!(
                f,
                "a frame has {got} particle positions but the model has {expected} particles"
            ),
        }
    }
}

impl std::error::Error for RenderError {}

/// An axis-aligned box [lo, hi] of points, empty until a finite point is added.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// The least corner (+∞ while empty).
    pub lo: DVec3,
    /// The greatest corner (−∞ while empty).
    pub hi: DVec3,
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds {
            lo: DVec3::INFINITY,
            hi: DVec3::NEG_INFINITY,
        }
    }
}

impl Bounds {
    /// The box of the finite points among `points`.
    pub fn of(points: &[DVec3]) -> Bounds {
        let mut b = Bounds::default();
        b.add(points);
        b
    }

    /// Grows the box to hold the finite points among `points`.
    pub fn add(&mut self, points: &[DVec3]) {
        for p in points.iter().filter(|p| p.is_finite()) {
            self.lo = self.lo.min(*p);
            self.hi = self.hi.max(*p);
        }
    }

    /// Whether no point has been added.
    pub fn is_empty(&self) -> bool {
        !self.lo.cmple(self.hi).all()
    }
}

/// The box the automatic camera frames: the bodies' box `bodies` and every finite terrain
/// shape (the cube [−0.5, 0.5]³ m when both are empty).
pub fn content_bounds(model: &Model, bodies: Bounds) -> Bounds {
    let mut content = bodies;
    if let Some((lo, hi)) = terrain::bounds(&model.terrain) {
        content.add(&[lo, hi]);
    }
    if content.is_empty() {
        content.add(&[DVec3::splat(-0.5), DVec3::splat(0.5)]);
    }
    content
}

/// Draws frames of one model through one camera.
#[derive(Debug, Clone)]
pub struct Renderer {
    options: RenderOptions,
    camera: Camera,
    view: camera::View,
    /// Background and terrain, drawn once: the camera does not move.
    base: Buffer,
    /// Triangles over the particles and then the embedded vertices (number `particles + k`).
    surface: Vec<[u32; 3]>,
    /// The mesh bodies' meshes, drawn instead of their lattices.
    embedded: Embedded,
    surface_color: Vec<[u8; 3]>,
    springs: Vec<[u32; 2]>,
    rest: Vec<f64>,
    /// Particles of bodies without surface triangles (free particle sets), drawn as dots.
    dots: Vec<(u32, [u8; 3])>,
    particles: usize,
}

impl Renderer {
    /// A renderer of `model`'s frames, whose bodies stay within `bodies` (the box of their
    /// positions over every frame to draw: the automatic camera and the size of drawn planes
    /// follow from it and the finite terrain).
    pub fn new(
        model: &Model,
        bodies: Bounds,
        options: RenderOptions,
    ) -> Result<Renderer, RenderError> {
        let (w, h) = (options.width, options.height);
        if !(1..=MAX_SIZE).contains(&w) || !(1..=MAX_SIZE).contains(&h) {
            return Err(RenderError::Size {
                width: w,
                height: h,
            });
        }
        if !(options.strain_range.is_finite() && options.strain_range > 0.0) {
            return Err(RenderError::StrainRange(options.strain_range));
        }
        let content = content_bounds(model, bodies);
        let camera = options
            .camera
            .unwrap_or_else(|| Camera::framing(content.lo, content.hi, w, h));
        camera.validate().map_err(RenderError::Camera)?;
        let view = camera::View::new(&camera, w, h);

        // Planes are drawn around the bodies (else the whole content) out to three times its
        // radius, but never smaller than what the camera looks at.
        let focus = if bodies.is_empty() { content } else { bodies };
        let centre = 0.5 * (focus.lo + focus.hi);
        let radius = (0.5 * (content.hi - content.lo).length())
            .max(camera.to.distance(centre))
            .max(0.5 * camera.from.distance(camera.to));
        let mut base = Buffer::new(w as usize, h as usize, SKY[0]);
        for j in 0..base.height {
            let t = (j as f64 + 0.5) / base.height as f64;
            let c = mix(SKY[0], SKY[1], t);
            base.color[j * base.width..(j + 1) * base.width].fill(c);
        }
        for t in terrain::triangulate(&model.terrain, centre, radius) {
            draw_shaded(&mut base, &view, t.corners, t.color);
        }

        let body_of = |p: u32| {
            model
                .bodies
                .iter()
                .position(|b| (b.first..b.first + b.count).contains(&p))
                .unwrap_or(0)
        };
        // A mesh body's own mesh: its vertices are numbered after the particles.
        let n = model.len() as u32;
        let mut surface = model.surface.clone();
        let mut surface_color: Vec<[u8; 3]> = model
            .surface
            .iter()
            .map(|t| BODY_COLORS[body_of(t[0]) % BODY_COLORS.len()])
            .collect();
        for mesh in &model.embedded.meshes {
            let first = mesh.first_triangle as usize;
            let triangles = &model.embedded.triangles[first..first + mesh.triangles as usize];
            surface.extend(triangles.iter().map(|t| t.map(|i| n + i)));
            let color = BODY_COLORS[mesh.body as usize % BODY_COLORS.len()];
            surface_color.extend(std::iter::repeat_n(color, triangles.len()));
        }
        let mut dots = Vec::new();
        for (k, b) in model.bodies.iter().enumerate() {
            let range = b.first..b.first + b.count;
            if !model.surface.iter().any(|t| range.contains(&t[0]))
                && !model.embedded.has_body(k as u32)
            {
                dots.extend(range.map(|p| (p, BODY_COLORS[k % BODY_COLORS.len()])));
            }
        }
        Ok(Renderer {
            options,
            camera,
            view,
            base,
            surface,
            embedded: model.embedded.clone(),
            surface_color,
            springs: model.springs().pairs(),
            rest: model.springs().rest.clone(),
            dots,
            particles: model.len(),
        })
    }

    /// The camera in use (the automatic one unless the options gave one).
    pub fn camera(&self) -> Camera {
        self.camera
    }

    /// The options it draws with.
    pub fn options(&self) -> RenderOptions {
        self.options
    }

    /// Draws the frame with particle positions `positions` (metres, one per particle).
    pub fn render_frame(&self, positions: &[DVec3]) -> Result<Image, RenderError> {
        if positions.len() != self.particles {
            return Err(RenderError::Particles {
                expected: self.particles,
                got: positions.len(),
            });
        }
        let mut scene = self.base.clone();
        // The surface's vertices: the particles, then the embedded vertices.
        let vertices: std::borrow::Cow<[DVec3]> = if self.embedded.is_empty() {
            positions.into()
        } else {
            let mut all = positions.to_vec();
            self.embedded.apply_into(positions, &mut all);
            all.into()
        };
        if self.options.shadows {
            self.shadow(&mut scene, &vertices);
        }
        let mut body = Buffer::new(scene.width, scene.height, [0; 3]);
        for (t, &color) in self.surface.iter().zip(&self.surface_color) {
            let corners = t.map(|p| vertices[p as usize]);
            draw_shaded(&mut body, &self.view, corners, color);
        }
        if self.options.springs {
            for (s, &rest) in self.springs.iter().zip(&self.rest) {
                let (a, b) = (positions[s[0] as usize], positions[s[1] as usize]);
                if !(a.is_finite() && b.is_finite()) {
                    continue;
                }
                let strain = (a.distance(b) - rest) / rest;
                let color = strain_color(strain, self.options.strain_range);
                raster::line(
                    &mut scene,
                    &self.view,
                    self.view.to_camera(a),
                    self.view.to_camera(b),
                    color,
                );
            }
        }
        for &(p, color) in &self.dots {
            self.dot(&mut scene, positions[p as usize], color);
        }
        // The surface over what is behind it: opaque, or see-through over the springs.
        let opacity = if self.options.springs {
            SURFACE_OPACITY_WITH_SPRINGS
        } else {
            1.0
        };
        for k in 0..scene.color.len() {
            if body.depth[k] > scene.depth[k] {
                scene.color[k] = mix(scene.color[k], body.color[k], opacity);
            }
        }
        if self.options.springs {
            self.legend(&mut scene);
        }
        Ok(Image::from_rows(
            self.options.width,
            self.options.height,
            scene.color.iter().flatten().copied().collect(),
        ))
    }

    /// Darkens the terrain pixels of `scene` that the bodies' surface (over `positions`: the
    /// particles, then the embedded vertices) hides from the light.
    ///
    /// A shadow map: the surface is rasterized orthographically along the light direction l
    /// into a [`SHADOW_MAP`]² grid over its extent across l, keeping the largest height p·l
    /// (the point nearest the light). A terrain pixel's world point q (rebuilt from its pixel
    /// position and depth) is in shadow when the map holds a height above q·l + bias there; the
    /// bias (1 % of the bodies' size) keeps a resting face from shadowing the ground it touches.
    fn shadow(&self, scene: &mut Buffer, positions: &[DVec3]) {
        let l = LIGHT.normalize();
        let u = l.any_orthonormal_vector();
        let v = l.cross(u);
        let mut lo = glam::DVec2::INFINITY;
        let mut hi = glam::DVec2::NEG_INFINITY;
        let mut seen = Bounds::default();
        for t in &self.surface {
            for &p in t {
                let x = positions[p as usize];
                if x.is_finite() {
                    let q = glam::DVec2::new(x.dot(u), x.dot(v));
                    lo = lo.min(q);
                    hi = hi.max(q);
                    seen.add(&[x]);
                }
            }
        }
        if seen.is_empty() {
            return;
        }
        let size = (hi - lo).max_element().max(1e-6);
        let scale = (SHADOW_MAP - 2) as f64 / size;
        // One cell of margin on each side.
        let origin = lo - glam::DVec2::splat(1.0 / scale);
        let to_map = |x: DVec3| {
            let q = (glam::DVec2::new(x.dot(u), x.dot(v)) - origin) * scale;
            raster::ScreenVertex {
                x: q.x,
                y: q.y,
                w: x.dot(l),
            }
        };
        let mut map = Buffer::new(SHADOW_MAP, SHADOW_MAP, [0; 3]);
        map.depth.fill(f64::NEG_INFINITY);
        for t in &self.surface {
            let c = t.map(|p| positions[p as usize]);
            if c.iter().all(|x| x.is_finite()) {
                raster::screen_triangle(&mut map, c.map(to_map), [0; 3]);
            }
        }
        let bias = 0.01 * (seen.hi - seen.lo).length();
        let (f, cx, cy) = (self.view.focal(), self.view.cx(), self.view.cy());
        for j in 0..scene.height {
            for i in 0..scene.width {
                let at = j * scene.width + i;
                let w = scene.depth[at];
                if w <= 0.0 {
                    continue;
                }
                let z = 1.0 / w;
                let c = DVec3::new(
                    (i as f64 + 0.5 - cx) * z / f,
                    -(j as f64 + 0.5 - cy) * z / f,
                    z,
                );
                let m = to_map(self.view.to_world(c));
                let (mi, mj) = (m.x.floor(), m.y.floor());
                if mi < 0.0 || mj < 0.0 || mi >= SHADOW_MAP as f64 || mj >= SHADOW_MAP as f64 {
                    continue;
                }
                if map.depth[mj as usize * SHADOW_MAP + mi as usize] > m.w + bias {
                    scene.color[at] =
                        scene.color[at].map(|ch| (f64::from(ch) * SHADOW).round() as u8);
                }
            }
        }
    }

    /// A 3 × 3 pixel dot at `p`, depth-tested.
    fn dot(&self, buf: &mut Buffer, p: DVec3, color: [u8; 3]) {
        let c = self.view.to_camera(p);
        if !(c.is_finite() && c.z > camera::NEAR) {
            return;
        }
        let s = self.view.to_screen(c);
        let (ci, cj) = (s.x.floor(), s.y.floor());
        for dj in -1..=1 {
            for di in -1..=1 {
                let (i, j) = (ci + f64::from(di), cj + f64::from(dj));
                if i < 0.0 || j < 0.0 || i >= buf.width as f64 || j >= buf.height as f64 {
                    continue;
                }
                let at = j as usize * buf.width + i as usize;
                if 1.0 / c.z > buf.depth[at] {
                    buf.depth[at] = 1.0 / c.z;
                    buf.color[at] = color;
                }
            }
        }
    }

    /// The colormap as a bar along the bottom-left corner: −s at its left end, 0 at the middle
    /// tick, +s at its right end.
    fn legend(&self, buf: &mut Buffer) {
        let (w, h) = (buf.width, buf.height);
        let bar_w = (w / 4).max(8).min(w);
        let bar_h = (h / 40).max(4).min(h);
        let (x0, y0) = ((w / 60).min(w - bar_w), h - bar_h - (h / 60).min(h - bar_h));
        let s = self.options.strain_range;
        for i in 0..bar_w {
            let strain = -s + 2.0 * s * (i as f64 + 0.5) / bar_w as f64;
            let c = strain_color(strain, s);
            for j in 0..bar_h {
                buf.color[(y0 + j) * w + x0 + i] = c;
            }
        }
        // Ticks at both ends and at zero strain, in dark grey.
        for i in [0, bar_w / 2, bar_w - 1] {
            for j in 0..bar_h {
                buf.color[(y0 + j) * w + x0 + i] = [40, 40, 40];
            }
        }
        // The strains of its ends above them: −s over the left end, +s ending over the right.
        let scale = text::scale_for(h as u32);
        let top = y0.checked_sub((text::GLYPH_HEIGHT + 2) * scale);
        let (low, high) = (text::percent(-s), text::percent(s));
        let mut put = |x: usize, y: usize| {
            if x < w && y < h {
                buf.color[y * w + x] = LABEL_COLOR;
            }
        };
        if let Some(top) = top {
            text::draw(&low, x0, top, scale, &mut put);
            let right = (x0 + bar_w).saturating_sub(text::width(&high, scale));
            text::draw(&high, right, top, scale, &mut put);
        }
    }
}

/// (1 − t)·a + t·b per channel, rounded.
fn mix(a: [u8; 3], b: [u8; 3], t: f64) -> [u8; 3] {
    std::array::from_fn(|k| {
        (f64::from(a[k]) + (f64::from(b[k]) - f64::from(a[k])) * t).round() as u8
    })
}

/// Shades the world-space triangle `corners` of base colour `color` and draws it.
fn draw_shaded(buf: &mut Buffer, view: &camera::View, corners: [DVec3; 3], color: [u8; 3]) {
    if !corners.iter().all(|c| c.is_finite()) {
        return;
    }
    let [a, b, c] = corners;
    let mut n = (b - a).cross(c - a);
    if n.length_squared() == 0.0 {
        return;
    }
    n = n.normalize();
    // Two-sided: the side facing the eye is lit.
    if n.dot(view.eye - a) < 0.0 {
        n = -n;
    }
    let light = AMBIENT + DIFFUSE * n.dot(LIGHT.normalize()).max(0.0);
    let shaded = color.map(|ch| (f64::from(ch) * light).round().min(255.0) as u8);
    raster::triangle(buf, view, corners.map(|p| view.to_camera(p)), shaded);
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::Scene;

    fn model(springs: bool) -> (Model, Vec<DVec3>) {
        let text = format!(
            r#"
            [simulation]
            dt = 0.001
            duration = 1.0
            [[body]]
            kind = "cuboid"
            size = [0.4, 0.4, 0.4]
            resolution = [3, 3, 3]
            center = [0.0, 0.5, 0.0]
            mass = 1.0
            structural = {{ stiffness = 100.0 }}
            {}
            [[terrain]]
            kind = "plane"
            normal = [0.0, 1.0, 0.0]
            [[terrain]]
            kind = "box"
            center = [1.0, 0.2, 0.0]
            half_extents = [0.2, 0.2, 0.2]
            "#,
            if springs {
                "shear = { stiffness = 100.0 }"
            } else {
                ""
            }
        );
        let scene = Scene::from_toml(&text, "t.toml".as_ref()).unwrap();
        let (model, state) = Model::build(&scene);
        (model, state.x)
    }

    #[test]
    fn the_same_frame_gives_the_same_bytes() {
        let (model, x) = model(true);
        for springs in [false, true] {
            let options = RenderOptions {
                width: 200,
                height: 150,
                springs,
                ..RenderOptions::default()
            };
            let a = Renderer::new(&model, Bounds::of(&x), options).unwrap();
            let b = Renderer::new(&model, Bounds::of(&x), options).unwrap();
            let (ia, ib) = (a.render_frame(&x).unwrap(), b.render_frame(&x).unwrap());
            assert_eq!(ia, ib);
            let (mut pa, mut pb) = (Vec::new(), Vec::new());
            ia.write_png(&mut pa).unwrap();
            ib.write_png(&mut pb).unwrap();
            assert_eq!(pa, pb);
            // The body is drawn: the picture's centre (the camera looks between the body and
            // the box) is not the background.
            let centre = a
                .camera()
                .project(DVec3::new(0.0, 0.5, 0.0), 200, 150)
                .unwrap();
            let px = ia.pixel(centre.x as u32, centre.y as u32);
            assert_ne!(px, mix(SKY[0], SKY[1], (centre.y.floor() + 0.5) / 150.0));
        }
    }

    #[test]
    fn the_body_is_drawn_in_its_colour_and_shaded() {
        let (model, x) = model(false);
        let camera = Camera::look_at(DVec3::new(0.0, 0.5, 3.0), DVec3::new(0.0, 0.5, 0.0));
        let options = RenderOptions {
            width: 100,
            height: 100,
            camera: Some(camera),
            ..RenderOptions::default()
        };
        let r = Renderer::new(&model, Bounds::of(&x), options).unwrap();
        let image = r.render_frame(&x).unwrap();
        // Looking at the +z face (normal (0, 0, 1)) head on: ambient + diffuse·(n·l).
        let l = LIGHT.normalize();
        let k = AMBIENT + DIFFUSE * l.z;
        let expect = BODY_COLORS[0].map(|c| (f64::from(c) * k).round() as u8);
        assert_eq!(image.pixel(50, 50), expect);
        // The cube spans ±0.2 m at 2.8 m: F = 50/tan 20° px, half side F·0.2/2.8 ≈ 9.8 px.
        assert_eq!(image.pixel(50, 50 - 9), expect);
        assert_ne!(image.pixel(50, 50 - 11), expect);
        // Wrong particle count: refused.
        assert_eq!(
            r.render_frame(&x[1..]),
            Err(RenderError::Particles {
                expected: 27,
                got: 26
            })
        );
    }

    #[test]
    fn the_body_shadows_the_ground_along_the_light() {
        let (model, x) = model(false);
        // The cube's centre (0, 0.5, 0) casts its shadow along −l onto y = 0 at q.
        let c = DVec3::new(0.0, 0.5, 0.0);
        let q = c - (c.y / LIGHT.y) * LIGHT;
        let camera = Camera::look_at(q + DVec3::new(0.0, 3.0, 3.0), q);
        let draw = |shadows| {
            let options = RenderOptions {
                width: 64,
                height: 64,
                camera: Some(camera),
                shadows,
                ..RenderOptions::default()
            };
            Renderer::new(&model, Bounds::of(&x), options)
                .unwrap()
                .render_frame(&x)
                .unwrap()
        };
        let (lit, shaded) = (draw(false), draw(true));
        // q is seen at the centre: darkened by SHADOW there, and the sky is untouched.
        let expect = lit
            .pixel(32, 32)
            .map(|ch| (f64::from(ch) * SHADOW).round() as u8);
        assert_eq!(shaded.pixel(32, 32), expect);
        assert_eq!(shaded.pixel(0, 0), lit.pixel(0, 0));
        assert_ne!(lit, shaded);
    }

    /// The colour bar's ends are labelled with their strains: the labels' pixels sit above
    /// the bar's ends, and another strain range draws other numbers there.
    #[test]
    fn the_colour_bar_shows_its_range() {
        let (model, x) = model(true);
        let draw = |strain_range| {
            let options = RenderOptions {
                width: 200,
                height: 150,
                springs: true,
                strain_range,
                ..RenderOptions::default()
            };
            Renderer::new(&model, Bounds::of(&x), options)
                .unwrap()
                .render_frame(&x)
                .unwrap()
        };
        let labelled = |image: &Image| -> Vec<(u32, u32)> {
            let mut at = Vec::new();
            for y in 0..image.height() {
                for x in 0..image.width() {
                    if image.pixel(x, y) == LABEL_COLOR {
                        at.push((x, y));
                    }
                }
            }
            at
        };
        let (wide, narrow) = (draw(0.1), draw(0.05));
        // The bar: 50 × 4 pixels from (3, 143); its labels, 7 rows, end a glyph's row above.
        let (bar_left, bar_right, bar_top) = (3, 3 + 200 / 4, 150 - 4 - 150 / 60);
        let (a, b) = (labelled(&wide), labelled(&narrow));
        for &(x, y) in a.iter().chain(&b) {
            assert!((bar_left..bar_right).contains(&x), "({x}, {y})");
            assert!((bar_top - 9..bar_top - 2).contains(&y), "({x}, {y})");
        }
        // "-10%" and "+10%" each have pixels over their ends of the bar.
        let half = (bar_left + bar_right) / 2;
        assert!(a.iter().any(|p| p.0 < half) && a.iter().any(|p| p.0 >= half));
        assert_ne!(a, b, "-5% and +5% are other numbers");
    }

    #[test]
    fn bad_options_are_refused() {
        let (model, x) = model(false);
        let bounds = Bounds::of(&x);
        for (w, h) in [(0, 10), (10, 0), (MAX_SIZE + 1, 10)] {
            let options = RenderOptions {
                width: w,
                height: h,
                ..RenderOptions::default()
            };
            assert!(matches!(
                Renderer::new(&model, bounds, options),
                Err(RenderError::Size { .. })
            ));
        }
        let options = RenderOptions {
            camera: Some(Camera::look_at(DVec3::ONE, DVec3::ONE)),
            ..RenderOptions::default()
        };
        assert!(matches!(
            Renderer::new(&model, bounds, options),
            Err(RenderError::Camera(_))
        ));
        let options = RenderOptions {
            strain_range: 0.0,
            ..RenderOptions::default()
        };
        assert!(matches!(
            Renderer::new(&model, bounds, options),
            Err(RenderError::StrainRange(_))
        ));
    }
}
