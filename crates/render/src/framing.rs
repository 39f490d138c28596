//! The automatic camera's two choices, made by an [`Animator`](crate::animation::Animator)
//! once every frame of a run is known.
//!
//! - **Following.** A fixed camera frames the bodies' box over every frame. When that box's
//!   diagonal D is more than [`FOLLOW_RATIO`] = 3√3 times the diagonal d of their first-frame
//!   box, a fixed camera draws them smaller than a following one does (it frames a cube of
//!   side 3d, diagonal 3√3·d, around them), so the camera follows. A 0.3 m cube sliding 11 m
//!   down a slope has D/d ≈ 21; a cube falling into a bowl, D/d ≈ 2.
//! - **Looking down.** The camera looks from [`DEFAULT_VIEW_DIRECTION`], 35.6° above the
//!   horizontal. Where the terrain hides particles from there (the rim of a bowl), it tries
//!   the steeper views [`ELEVATIONS_DEGREES`] and takes the lowest whose worst sampled frame
//!   has no more particles hidden than the best view's plus [`HIDDEN_SLACK`]. A particle is
//!   hidden when it is outside the picture or a terrain pixel is nearer the eye than it by
//!   more than [`HIDDEN_TOLERANCE`] of the bodies' size in that frame: a particle resting on
//!   a faceted bowl may lie behind a facet's chord by up to its sagitta, R(1 − cos 11.25°)
//!   ≈ 0.02 R at a cell's far corner.

use glam::DVec3;

use crate::camera::{DEFAULT_VIEW_DIRECTION, NEAR};
use crate::{Bounds, RenderError, Renderer};

/// A fixed camera gives way to a following one when the bodies' box over every frame is this
/// many times their first-frame box (diagonals): 3√3, the diagonal of the cube, three times
/// the bodies' size, that the following camera frames.
pub const FOLLOW_RATIO: f64 = 5.196_152_422_706_632;

/// The steeper views tried after the default one, degrees above the horizontal.
pub const ELEVATIONS_DEGREES: [f64; 4] = [45.0, 55.0, 65.0, 75.0];

/// A steeper view is taken only to hide fewer than this fraction more particles than the best.
pub const HIDDEN_SLACK: f64 = 0.02;

/// How far behind a terrain pixel (a fraction of the bodies' box diagonal) a particle counts
/// as hidden.
pub const HIDDEN_TOLERANCE: f64 = 0.05;

/// The most frames (evenly spaced, the first and last among them) that judge a view.
const SAMPLES: usize = 16;

/// Whether the bodies, whose box is `first` at the first frame and `all` over every frame,
/// travel far enough that a following camera draws them bigger than a fixed one.
pub fn travels_far(first: Bounds, all: Bounds) -> bool {
    if first.is_empty() || all.is_empty() {
        return false;
    }
    // The following camera's cube has a side of 3·max(d, 0.2 m).
    let size = (first.hi - first.lo).length().max(0.2);
    (all.hi - all.lo).length() > FOLLOW_RATIO * size
}

/// The unit direction (from the content towards the eye) with the default view's heading and
/// `elevation_degrees` above the horizontal.
pub fn view_direction(elevation_degrees: f64) -> DVec3 {
    let d = DEFAULT_VIEW_DIRECTION;
    let heading = DVec3::new(d.x, 0.0, d.z).normalize();
    let e = elevation_degrees.to_radians();
    heading * e.cos() + DVec3::Y * e.sin()
}

/// The renderer, among those `place` builds for the default view direction and the steeper
/// [`ELEVATIONS_DEGREES`], through which the terrain hides the fewest particles of `frames`
/// (the lowest within [`HIDDEN_SLACK`] of the fewest); the default one when it hides none.
pub fn look_down(
    frames: &[&[DVec3]],
    mut place: impl FnMut(DVec3) -> Result<Renderer, RenderError>,
) -> Result<Renderer, RenderError> {
    let sample: Vec<&[DVec3]> = if frames.len() <= SAMPLES {
        frames.to_vec()
    } else {
        (0..SAMPLES)
            .map(|k| frames[k * (frames.len() - 1) / (SAMPLES - 1)])
            .collect()
    };
    let worst = |r: &Renderer| {
        sample
            .iter()
            .map(|f| r.hidden_by_terrain(f))
            .fold(0.0, f64::max)
    };
    let default = place(DEFAULT_VIEW_DIRECTION)?;
    let hidden = worst(&default);
    if hidden == 0.0 {
        return Ok(default);
    }
    let mut views = vec![(hidden, DEFAULT_VIEW_DIRECTION, Some(default))];
    for e in ELEVATIONS_DEGREES {
        let direction = view_direction(e);
        views.push((worst(&place(direction)?), direction, None));
    }
    let fewest = views.iter().map(|v| v.0).fold(f64::INFINITY, f64::min);
    let chosen = views
        .into_iter()
        .find(|v| v.0 <= fewest + HIDDEN_SLACK)
        .expect("the fewest is among the views");
    match chosen {
        (_, _, Some(renderer)) => Ok(renderer),
        (_, direction, None) => place(direction),
    }
}

impl Renderer {
    /// The fraction of the finite points among `positions` that this view does not show for
    /// the terrain: outside the picture, or behind a terrain pixel by more than
    /// [`HIDDEN_TOLERANCE`] of their box's diagonal (0 without finite points).
    pub fn hidden_by_terrain(&self, positions: &[DVec3]) -> f64 {
        let b = Bounds::of(positions);
        if b.is_empty() {
            return 0.0;
        }
        let tolerance = HIDDEN_TOLERANCE * (b.hi - b.lo).length();
        let (mut seen, mut hidden) = (0usize, 0usize);
        for p in positions.iter().filter(|p| p.is_finite()) {
            seen += 1;
            let c = self.view.to_camera(*p);
            let s = self.view.to_screen(c);
            let in_picture = c.z > NEAR
                && (0.0..self.base.width as f64).contains(&s.x)
                && (0.0..self.base.height as f64).contains(&s.y);
            let behind = in_picture && {
                let w = self.base.depth[s.y as usize * self.base.width + s.x as usize];
                w > 0.0 && 1.0 / w < c.z - tolerance
            };
            if !in_picture || behind {
                hidden += 1;
            }
        }
        hidden as f64 / seen as f64
    }
}
