//! Animations: a run's frames drawn one after the other by an [`Animator`], which places the
//! camera once for all of them or moves it with the bodies, and written by an [`Animation`] as
//! numbered PNG files or as one looping GIF.
//!
//! The automatic camera frames the bodies' box over every frame, which is known only at the
//! last one: until then the animator keeps the frames' positions (N particles × 24 bytes per
//! frame) and draws them at [`Animator::finish`]. A camera given whole, or one that follows
//! the bodies, draws each frame as it comes.
//!
//! ```
//! use softbody_render::animation::{Animation, Animator, CameraPlan};
//! use softbody_render::RenderOptions;
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
//! "#, "inline.toml".as_ref()).unwrap();
//! let (model, state) = Model::build(&scene);
//! let options = RenderOptions { width: 64, height: 48, ..RenderOptions::default() };
//! let mut animator = Animator::new(&model, options, CameraPlan::default()).unwrap();
//! let mut gif = Animation::Gif(softbody_render::GifWriter::new(Vec::new(), 64, 48, 30.0)?);
//! for k in 0..3 {
//!     let positions = state.x.iter().map(|x| *x - glam::DVec3::Y * (0.1 * k as f64)).collect();
//!     // The automatic camera waits for the last frame.
//!     assert!(animator.frame(k, positions).unwrap().is_none());
//! }
//! for picture in animator.finish().unwrap() {
//!     let (index, image) = picture.unwrap();
//!     gif.add(index, &image)?;
//! }
//! gif.finish()?;
//! # Ok::<(), std::io::Error>(())
//! ```

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use glam::DVec3;
use softbody_scene::Model;

use crate::{Bounds, Camera, GifWriter, Image, RenderError, RenderOptions, Renderer, framing};

/// The stem of the PNG files' names: `frame_000000.png`, `frame_000001.png`, …
pub const PNG_STEM: &str = "frame";

/// The name of frame `index`'s PNG file: `frame_<index, 6 digits or more>.png`, so that the
/// files sort in frame order.
pub fn png_name(index: u64) -> String {
    format!("{PNG_STEM}_{index:06}.png")
}

/// Where an animation's pictures go.
#[derive(Debug)]
pub enum Animation<W: Write> {
    /// One PNG file per picture in this directory, named by [`png_name`] after its frame.
    Pngs(PathBuf),
    /// One looping GIF, at the frame rate it was made with.
    Gif(GifWriter<W>),
}

impl<W: Write> Animation<W> {
    /// Writes the picture of frame `index` (pictures come in frame order).
    pub fn add(&mut self, index: u64, image: &Image) -> io::Result<()> {
        match self {
            Animation::Pngs(dir) => {
                let mut out = BufWriter::new(File::create(dir.join(png_name(index)))?);
                image.write_png(&mut out)?;
                out.flush()
            }
            Animation::Gif(gif) => gif.add(image),
        }
    }

    /// Completes the files (the GIF's trailer) and flushes them.
    pub fn finish(self) -> io::Result<()> {
        match self {
            Animation::Pngs(_) => Ok(()),
            Animation::Gif(gif) => gif.finish()?.flush(),
        }
    }
}

/// How an [`Animator`] places its camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPlan {
    /// The eye, metres; `None`: the automatic camera's (in front of, right of and above what
    /// is drawn, far enough to see all of it).
    pub from: Option<DVec3>,
    /// The point looked at, metres; `None`: the automatic camera's (the centre of what is
    /// drawn).
    pub to: Option<DVec3>,
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_y_degrees: f64,
    /// Whether the camera moves with the bodies.
    pub follow: Follow,
}

/// Whether an [`Animator`]'s camera moves with the bodies' centroid (the mean finite particle
/// position), keeping the offset it has at the first frame; the points not given then frame a
/// box three times the bodies' first-frame size around it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Follow {
    /// Follow when neither point is given and the bodies travel far
    /// ([`crate::framing::travels_far`]); else stay.
    #[default]
    Automatic,
    /// Always follow.
    Always,
    /// Never follow.
    Never,
}

impl Default for CameraPlan {
    fn default() -> Self {
        CameraPlan {
            from: None,
            to: None,
            fov_y_degrees: crate::camera::DEFAULT_FOV_Y_DEGREES,
            follow: Follow::Automatic,
        }
    }
}

/// Draws a run's frames through the camera a [`CameraPlan`] places.
#[derive(Debug)]
pub struct Animator<'m> {
    model: &'m Model,
    options: RenderOptions,
    plan: CameraPlan,
    renderer: Option<Renderer>,
    /// While following: the eye minus the target, and the target minus the bodies' centroid,
    /// fixed at the first frame.
    follow: Option<(DVec3, DVec3)>,
    /// Frames waiting for the automatic camera (index, positions).
    pending: Vec<(u64, Vec<DVec3>)>,
    /// The bodies' box at the first frame and over every frame so far.
    first: Bounds,
    bodies: Bounds,
}

impl<'m> Animator<'m> {
    /// An animator of `model`'s frames drawn with `options` (whose `camera` the plan replaces).
    /// A camera given whole (both points) is checked here, before any frame.
    pub fn new(
        model: &'m Model,
        options: RenderOptions,
        plan: CameraPlan,
    ) -> Result<Animator<'m>, RenderError> {
        if let (Some(from), Some(to)) = (plan.from, plan.to) {
            let camera = Camera {
                fov_y_degrees: plan.fov_y_degrees,
                ..Camera::look_at(from, to)
            };
            camera.validate().map_err(RenderError::Camera)?;
        }
        Ok(Animator {
            model,
            options,
            plan,
            renderer: None,
            follow: None,
            pending: Vec::new(),
            first: Bounds::default(),
            bodies: Bounds::default(),
        })
    }

    /// Takes frame `index` (particle positions, metres): its picture when the camera is known
    /// (given whole, or following the bodies), else `None`, the frame kept for
    /// [`Animator::finish`].
    pub fn frame(
        &mut self,
        index: u64,
        positions: Vec<DVec3>,
    ) -> Result<Option<Image>, RenderError> {
        if self.plan.follow == Follow::Always {
            return self.follow_frame(&positions).map(Some);
        }
        if self.first.is_empty() {
            self.first = Bounds::of(&positions);
        }
        if self.renderer.is_none() && self.plan.from.is_some() && self.plan.to.is_some() {
            // The camera is known: the first frame sizes the ground planes.
            self.bodies.add(&positions);
            self.renderer = Some(self.placed(crate::camera::DEFAULT_VIEW_DIRECTION)?);
        }
        match &self.renderer {
            Some(renderer) => renderer.render_frame(&positions).map(Some),
            None => {
                self.bodies.add(&positions);
                self.pending.push((index, positions));
                Ok(None)
            }
        }
    }

    /// Places the automatic camera now that every frame is known ([`crate::framing`]: it
    /// follows bodies that travel far, and looks down past terrain that hides them), and
    /// returns the pictures of the frames kept for it, drawn one by one as the iterator is
    /// advanced (empty when every frame was drawn as it came).
    pub fn finish(
        mut self,
    ) -> Result<impl ExactSizeIterator<Item = Result<(u64, Image), RenderError>>, RenderError> {
        let pending = std::mem::take(&mut self.pending);
        let follow = self.renderer.is_none()
            && self.plan.follow == Follow::Automatic
            && self.plan.from.is_none()
            && self.plan.to.is_none()
            && framing::travels_far(self.first, self.bodies);
        let fixed = match self.renderer.take() {
            _ if follow => None,
            Some(renderer) => Some(renderer),
            None => {
                let frames: Vec<&[DVec3]> = pending.iter().map(|(_, x)| x.as_slice()).collect();
                Some(framing::look_down(&frames, |d| self.placed(d))?)
            }
        };
        Ok(pending.into_iter().map(move |(index, positions)| {
            let image = match &fixed {
                Some(renderer) => renderer.render_frame(&positions)?,
                None => self.follow_frame(&positions)?,
            };
            Ok((index, image))
        }))
    }

    /// The renderer for the plan's camera: the automatic one for the bodies' box so far, seen
    /// from `direction`, with the given points in place of its own.
    fn placed(&self, direction: DVec3) -> Result<Renderer, RenderError> {
        let content = crate::content_bounds(self.model, self.bodies);
        let auto = Camera::framing_along(
            direction,
            content.lo,
            content.hi,
            self.options.width,
            self.options.height,
        );
        let camera = Camera {
            from: self.plan.from.unwrap_or(auto.from),
            to: self.plan.to.unwrap_or(auto.to),
            up: auto.up,
            fov_y_degrees: self.plan.fov_y_degrees,
        };
        let options = RenderOptions {
            camera: Some(camera),
            ..self.options
        };
        Renderer::new(self.model, self.bodies, options)
    }

    /// Draws a frame with the camera moved along with the bodies' centroid.
    fn follow_frame(&mut self, positions: &[DVec3]) -> Result<Image, RenderError> {
        let finite: Vec<DVec3> = positions
            .iter()
            .copied()
            .filter(|p| p.is_finite())
            .collect();
        let centroid = finite.iter().sum::<DVec3>() / finite.len().max(1) as f64;
        let (offset, shift) = match self.follow {
            Some(f) => f,
            None => {
                // The first frame: the camera given, or one framing a box three times the
                // bodies' size around them.
                let b = Bounds::of(&finite);
                let r = if b.is_empty() {
                    0.5
                } else {
                    (0.5 * (b.hi - b.lo).length()).max(0.1)
                };
                let auto = Camera::framing(
                    centroid - DVec3::splat(3.0 * r),
                    centroid + DVec3::splat(3.0 * r),
                    self.options.width,
                    self.options.height,
                );
                let to = self.plan.to.unwrap_or(auto.to);
                let from = self.plan.from.unwrap_or(auto.from);
                let f = (from - to, to - centroid);
                self.follow = Some(f);
                f
            }
        };
        let to = centroid + shift;
        let camera = Camera {
            fov_y_degrees: self.plan.fov_y_degrees,
            ..Camera::look_at(to + offset, to)
        };
        let options = RenderOptions {
            camera: Some(camera),
            ..self.options
        };
        Renderer::new(self.model, Bounds::of(positions), options)?.render_frame(positions)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use softbody_scene::Scene;

    fn cube() -> (Model, Vec<DVec3>) {
        let scene = Scene::from_toml(
            "[simulation]\ndt = 0.001\nduration = 1.0\n\
             [[body]]\nkind = \"cuboid\"\nsize = [0.3, 0.3, 0.3]\nresolution = [3, 3, 3]\n\
             center = [0.0, 0.5, 0.0]\nmass = 1.0\nstructural = { stiffness = 100.0 }\n\
             [[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\n",
            "inline.toml".as_ref(),
        )
        .unwrap();
        let (model, state) = Model::build(&scene);
        (model, state.x)
    }

    const OPTIONS: RenderOptions = RenderOptions {
        width: 48,
        height: 32,
        camera: None,
        springs: false,
        strain_range: crate::DEFAULT_STRAIN_RANGE,
        shadows: true,
    };

    fn moved(x: &[DVec3], by: DVec3) -> Vec<DVec3> {
        x.iter().map(|p| *p + by).collect()
    }

    #[test]
    fn the_automatic_camera_draws_at_the_end_what_one_renderer_draws() {
        let (model, x) = cube();
        let frames = [moved(&x, DVec3::ZERO), moved(&x, DVec3::X)];
        let mut animator = Animator::new(&model, OPTIONS, CameraPlan::default()).unwrap();
        for (k, f) in frames.iter().enumerate() {
            assert!(animator.frame(k as u64, f.clone()).unwrap().is_none());
        }
        let pictures: Vec<(u64, Image)> = animator.finish().unwrap().map(Result::unwrap).collect();
        let mut bodies = Bounds::default();
        frames.iter().for_each(|f| bodies.add(f));
        let renderer = Renderer::new(&model, bodies, OPTIONS).unwrap();
        for (k, (index, image)) in pictures.iter().enumerate() {
            assert_eq!(*index, k as u64);
            assert_eq!(*image, renderer.render_frame(&frames[k]).unwrap());
        }
    }

    #[test]
    fn a_camera_given_whole_draws_as_frames_come_and_is_checked_first() {
        let (model, x) = cube();
        let plan = CameraPlan {
            from: Some(DVec3::new(0.0, 1.0, 3.0)),
            to: Some(DVec3::new(0.0, 0.5, 0.0)),
            ..CameraPlan::default()
        };
        let mut animator = Animator::new(&model, OPTIONS, plan).unwrap();
        assert!(animator.frame(0, x.clone()).unwrap().is_some());
        assert!(animator.frame(1, moved(&x, DVec3::Y)).unwrap().is_some());
        assert_eq!(animator.finish().unwrap().len(), 0);

        let up = CameraPlan {
            from: Some(DVec3::new(0.0, 5.0, 0.0)),
            to: Some(DVec3::new(0.0, 1.0, 0.0)),
            ..CameraPlan::default()
        };
        assert!(matches!(
            Animator::new(&model, OPTIONS, up),
            Err(RenderError::Camera(_))
        ));
    }

    #[test]
    fn following_keeps_the_picture_as_the_bodies_move() {
        let (model, x) = cube();
        let plan = CameraPlan {
            follow: Follow::Always,
            ..CameraPlan::default()
        };
        let mut animator = Animator::new(&model, OPTIONS, plan).unwrap();
        // The body (orange: red well above blue) stays in the middle of the picture.
        for (k, by) in [DVec3::ZERO, DVec3::X * 10.0, DVec3::new(-5.0, 0.0, 7.0)]
            .into_iter()
            .enumerate()
        {
            let image = animator.frame(k as u64, moved(&x, by)).unwrap().unwrap();
            let [r, _, b] = image.pixel(24, 16);
            assert!(r > b + 60, "frame {k}: {:?}", image.pixel(24, 16));
        }
        assert_eq!(animator.finish().unwrap().len(), 0);
    }

    /// The pixels of body 0's colour (orange: red well above blue) and, of those, the ones on
    /// the outline (a 4-neighbour of another colour or the picture's edge).
    fn body_pixels(image: &Image) -> (usize, usize) {
        let (w, h) = (image.width() as i64, image.height() as i64);
        let body = |i: i64, j: i64| {
            (0..w).contains(&i) && (0..h).contains(&j) && {
                let [r, _, b] = image.pixel(i as u32, j as u32);
                i32::from(r) > i32::from(b) + 60
            }
        };
        let (mut inside, mut outline) = (0, 0);
        for j in 0..h {
            for i in 0..w {
                if body(i, j) {
                    inside += 1;
                    if [(1, 0), (-1, 0), (0, 1), (0, -1)]
                        .iter()
                        .any(|(di, dj)| !body(i + di, j + dj))
                    {
                        outline += 1;
                    }
                }
            }
        }
        (inside, outline)
    }

    /// A body sliding 10 m (19 times its diagonal) is followed: translating the camera with
    /// it draws it the same at the last frame as at the first, up to the pixels on its
    /// outline. A still camera on the whole path draws it smaller.
    #[test]
    fn the_automatic_camera_follows_a_body_that_travels_far() {
        let (model, x) = cube();
        let options = RenderOptions {
            width: 96,
            height: 64,
            ..OPTIONS
        };
        let frames: Vec<Vec<DVec3>> = (0..=4)
            .map(|k| moved(&x, DVec3::X * (2.5 * k as f64)))
            .collect();
        let draw = |follow| {
            let plan = CameraPlan {
                follow,
                ..CameraPlan::default()
            };
            let mut animator = Animator::new(&model, options, plan).unwrap();
            for (k, f) in frames.iter().enumerate() {
                assert!(animator.frame(k as u64, f.clone()).unwrap().is_none());
            }
            let pictures: Vec<Image> = animator.finish().unwrap().map(|p| p.unwrap().1).collect();
            pictures
        };
        let pictures = draw(Follow::Automatic);
        let (first, outline) = body_pixels(&pictures[0]);
        let (last, _) = body_pixels(&pictures[4]);
        assert!(
            first.abs_diff(last) <= outline,
            "{first} → {last} (outline {outline})"
        );

        // Told not to follow, it frames the whole path, as one renderer on every frame's box.
        let still = draw(Follow::Never);
        let mut bodies = Bounds::default();
        frames.iter().for_each(|f| bodies.add(f));
        let renderer = Renderer::new(&model, bodies, options).unwrap();
        assert_eq!(still[4], renderer.render_frame(&frames[4]).unwrap());
        // …which draws it smaller: the reason to follow.
        assert!(body_pixels(&still[4]).0 < first);
    }

    /// A cube resting at the bottom of a bowl is hidden by the rim from the default view; the
    /// automatic camera looks down steeply enough to see all of it.
    #[test]
    fn the_automatic_camera_looks_down_into_a_bowl() {
        let scene = Scene::from_toml(
            "[simulation]\ndt = 0.001\nduration = 1.0\n\
             [[body]]\nkind = \"cuboid\"\nsize = [0.3, 0.3, 0.3]\nresolution = [3, 3, 3]\n\
             center = [0.0, 0.18, 0.0]\nmass = 1.0\nstructural = { stiffness = 100.0 }\n\
             [[terrain]]\nkind = \"bowl\"\ncenter = [0.0, 1.0, 0.0]\nradius = 1.0\n",
            "inline.toml".as_ref(),
        )
        .unwrap();
        let (model, state) = Model::build(&scene);
        let options = RenderOptions {
            width: 96,
            height: 64,
            ..OPTIONS
        };
        let bodies = Bounds::of(&state.x);
        let content = crate::content_bounds(&model, bodies);
        let place = |direction| {
            let camera = Camera::framing_along(direction, content.lo, content.hi, 96, 64);
            Renderer::new(
                &model,
                bodies,
                RenderOptions {
                    camera: Some(camera),
                    ..options
                },
            )
        };
        let default = place(crate::camera::DEFAULT_VIEW_DIRECTION).unwrap();
        assert!(default.hidden_by_terrain(&state.x) > 0.5);
        let chosen = framing::look_down(&[&state.x], place).unwrap();
        assert_eq!(chosen.hidden_by_terrain(&state.x), 0.0);
        assert!(chosen.camera().from.y > default.camera().from.y);

        let mut animator = Animator::new(&model, options, CameraPlan::default()).unwrap();
        assert!(animator.frame(0, state.x.clone()).unwrap().is_none());
        let picture = animator.finish().unwrap().next().unwrap().unwrap().1;
        assert_eq!(picture, chosen.render_frame(&state.x).unwrap());
    }

    #[test]
    fn pngs_are_numbered_by_frame() {
        assert_eq!(png_name(7), "frame_000007.png");
        assert_eq!(png_name(1_234_567), "frame_1234567.png");
        let dir = std::env::temp_dir().join(format!("softbody-animation-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut pngs: Animation<Vec<u8>> = Animation::Pngs(dir.clone());
        pngs.add(3, &Image::from_rows(2, 1, vec![0, 1, 2, 3, 4, 5]))
            .unwrap();
        pngs.finish().unwrap();
        assert!(dir.join("frame_000003.png").is_file());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
