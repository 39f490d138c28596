//! Settings given beside a scene file that replace its own: one path that applies them and
//! checks the result, so that every command (and embedder) refuses a bad combination alike.

use std::fmt;
use std::path::{Path, PathBuf};

use softbody_scene::{Integrator, KeyPath, Scene};

/// Replacements for a loaded scene's settings (the CLI's `--integrator`, `--dt`, `--duration`,
/// `--fps`); `None` keeps the scene's. A new kind of override belongs here, so that it is
/// applied, checked and reported the way these are.
///
/// ```
/// use softbody::{Integrator, Overrides, Scene};
/// let scene = Scene::from_file("scenes/jelly-on-ground.toml")?;
/// let overrides = Overrides { integrator: Some(Integrator::Rk4), dt: Some(1e-4), ..Overrides::default() };
/// let scene = overrides.apply_to(scene, "scenes/jelly-on-ground.toml".as_ref())?;
/// assert_eq!(scene.simulation.integrator, Integrator::Rk4);
///
/// // 30 frames/s cannot be taken with one step per second.
/// let slow = Overrides { dt: Some(1.0), ..Overrides::default() };
/// let e = slow.apply_to(scene, "jelly.toml".as_ref()).unwrap_err();
/// assert_eq!(e.key().to_string(), "simulation.frame_rate");
/// assert!(e.to_string().ends_with("(with the overrides simulation.dt = 1)"));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Overrides {
    /// The time integrator.
    pub integrator: Option<Integrator>,
    /// The time step, seconds.
    pub dt: Option<f64>,
    /// The simulated time, seconds.
    pub duration: Option<f64>,
    /// Frames per simulated second.
    pub frame_rate: Option<f64>,
}

/// A scene that is invalid with the overrides applied: the file, the key at fault and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{}: {}: {} (with the overrides {})",
    .0.file.display(), .0.key, .0.message, .0.overrides
)]
pub struct OverrideError(Box<Details>);

/// Boxed: a `Result` of a whole scene should not grow by the size of its error.
#[derive(Debug, Clone, PartialEq)]
struct Details {
    file: PathBuf,
    key: KeyPath,
    message: String,
    overrides: Overrides,
}

impl OverrideError {
    /// The scene file.
    pub fn file(&self) -> &Path {
        &self.0.file
    }

    /// The value at fault, named as the scene file would name it (it may be one the overrides
    /// left alone, such as a frame rate that a larger dt cannot serve).
    pub fn key(&self) -> &KeyPath {
        &self.0.key
    }

    /// What is wrong with it.
    pub fn message(&self) -> &str {
        &self.0.message
    }

    /// The overrides that were applied.
    pub fn overrides(&self) -> &Overrides {
        &self.0.overrides
    }
}

impl Overrides {
    /// Whether nothing is overridden.
    pub fn is_empty(&self) -> bool {
        *self == Overrides::default()
    }

    /// The overrides as a file-name part: `rk4-dt0.0001-2s-60fps` (empty when there are none).
    /// Default output names carry it, so that a run with other settings does not replace the
    /// scene's own run's frames.
    pub fn label(&self) -> String {
        let parts = [
            self.integrator.map(|i| i.to_string()),
            self.dt.map(|x| format!("dt{x}")),
            self.duration.map(|x| format!("{x}s")),
            self.frame_rate.map(|x| format!("{x}fps")),
        ];
        parts.into_iter().flatten().collect::<Vec<_>>().join("-")
    }

    /// `scene` with the overrides in place of its own settings, validated again as a whole;
    /// `origin` names the scene file in the error.
    pub fn apply_to(&self, mut scene: Scene, origin: &Path) -> Result<Scene, OverrideError> {
        let sim = &mut scene.simulation;
        if let Some(integrator) = self.integrator {
            sim.integrator = integrator;
        }
        if let Some(dt) = self.dt {
            sim.dt = dt;
        }
        if let Some(duration) = self.duration {
            sim.duration = duration;
        }
        if let Some(frame_rate) = self.frame_rate {
            sim.frame_rate = frame_rate;
        }
        match scene.validate() {
            Ok(()) => Ok(scene),
            Err(invalid) => Err(OverrideError(Box::new(Details {
                file: origin.to_owned(),
                key: invalid.key,
                message: invalid.message,
                overrides: *self,
            }))),
        }
    }
}

/// The overrides as `key = value` pairs, keyed as in a scene file.
impl fmt::Display for Overrides {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let pairs = [
            ("integrator", self.integrator.map(|i| i.to_string())),
            ("dt", self.dt.map(|x| x.to_string())),
            ("duration", self.duration.map(|x| x.to_string())),
            ("frame_rate", self.frame_rate.map(|x| x.to_string())),
        ];
        let mut first = true;
        for (key, value) in pairs {
            if let Some(value) = value {
                let sep = if first { "" } else { ", " };
                write!(f, "{sep}simulation.{key} = {value}")?;
                first = false;
            }
        }
        if first {
            f.write_str("(none)")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_label_names_each_override() {
        assert_eq!(Overrides::default().label(), "");
        let all = Overrides {
            integrator: Some(Integrator::Rk4),
            dt: Some(1e-4),
            duration: Some(2.0),
            frame_rate: Some(60.0),
        };
        assert_eq!(all.label(), "rk4-dt0.0001-2s-60fps");
        let dt = Overrides {
            dt: Some(1.0 / 60.0),
            ..Overrides::default()
        };
        assert_eq!(dt.label(), "dt0.016666666666666666");
    }

    fn scene() -> Scene {
        Scene::from_toml(
            "[simulation]\ndt = 0.001\nduration = 0.1\nframe_rate = 100.0\n\
             [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0]]\nmasses = [1.0]\n",
            Path::new("s.toml"),
        )
        .unwrap()
    }

    #[test]
    fn nothing_overridden_keeps_the_scene() {
        let before = scene();
        assert!(Overrides::default().is_empty());
        let after = Overrides::default()
            .apply_to(before.clone(), Path::new("s.toml"))
            .unwrap();
        assert_eq!(after.simulation, before.simulation);
    }

    #[test]
    fn every_override_replaces_its_setting() {
        let o = Overrides {
            integrator: Some(Integrator::Midpoint),
            dt: Some(0.002),
            duration: Some(0.5),
            frame_rate: Some(25.0),
        };
        assert!(!o.is_empty());
        let sim = o.apply_to(scene(), Path::new("s.toml")).unwrap().simulation;
        assert_eq!(sim.integrator, Integrator::Midpoint);
        assert_eq!((sim.dt, sim.duration, sim.frame_rate), (0.002, 0.5, 25.0));
    }

    #[test]
    fn a_bad_combination_names_the_file_the_key_and_the_overrides() {
        let o = Overrides {
            integrator: Some(Integrator::Rk4),
            frame_rate: Some(5000.0),
            ..Overrides::default()
        };
        let e = o.apply_to(scene(), Path::new("dir/s.toml")).unwrap_err();
        assert_eq!(e.file(), Path::new("dir/s.toml"));
        assert_eq!(e.key().to_string(), "simulation.frame_rate");
        assert!(e.message().contains("more than one frame per step"));
        assert_eq!(*e.overrides(), o);
        let text = e.to_string();
        assert!(
            text.starts_with("dir/s.toml: simulation.frame_rate: "),
            "{text}"
        );
        assert!(
            text.ends_with(
                "(with the overrides simulation.integrator = rk4, simulation.frame_rate = 5000)"
            ),
            "{text}"
        );
        let negative = Overrides {
            duration: Some(-1.0),
            ..Overrides::default()
        };
        let e = negative.apply_to(scene(), Path::new("s.toml")).unwrap_err();
        assert_eq!(e.key().to_string(), "simulation.duration");
    }
}
