//! What several subcommands take alike: the overrides of a scene's settings, and the parsers of
//! numbers.

use clap::Args;
use softbody::{Integrator, Overrides, Setting};

/// The overrides every command that simulates a scene file takes (`run`, `check`, `render`,
/// `compare`), flattened
/// into each. They become one [`Overrides`], which applies and checks them for all commands
/// alike: a new kind of override goes there and here.
#[derive(Args)]
pub struct SceneOverrides {
    /// Set a value of the scene file by its key path, as if the file said so (repeatable; a
    /// later one wins): body[0].structural.stiffness=5000, terrain[0].friction=0.8,
    /// simulation.integrator=rk4. The value is TOML; other text is taken as a string.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<Setting>,
    /// Simulated time, seconds.
    #[arg(long, value_parser = non_negative, allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Frames per simulated second.
    #[arg(long, value_parser = positive, allow_negative_numbers = true)]
    fps: Option<f64>,
}

impl SceneOverrides {
    /// The `--set`s, in the order given.
    pub fn settings(&self) -> &[Setting] {
        &self.set
    }

    /// Everything that changes the scene, in order: the `--set`s, then the overrides.
    pub fn all_settings(&self) -> Vec<Setting> {
        let mut all = self.set.clone();
        all.extend(Overrides::from(self).to_settings());
        all
    }
}

impl From<&SceneOverrides> for Overrides {
    fn from(args: &SceneOverrides) -> Overrides {
        Overrides {
            duration: args.duration,
            frame_rate: args.fps,
            ..Overrides::default()
        }
    }
}

/// `--integrator` and `--dt` besides the [`SceneOverrides`]: what `run` overrides.
#[derive(Args)]
pub struct StepOverrides {
    /// Integrator: explicit-euler, symplectic-euler, midpoint, rk4 or implicit-euler.
    #[arg(long)]
    integrator: Option<Integrator>,
    /// Time step, seconds, e.g. 0.001 or 1/60.
    #[arg(long, value_parser = time_step, allow_negative_numbers = true)]
    dt: Option<f64>,
    #[command(flatten)]
    scene: SceneOverrides,
}

impl StepOverrides {
    /// The `--set`s alone (default output names label them apart from the overrides).
    pub fn sets(&self) -> &[Setting] {
        self.scene.settings()
    }

    /// Everything that changes the scene, in order: the `--set`s, then the overrides.
    pub fn settings(&self) -> Vec<Setting> {
        let mut all = self.sets().to_vec();
        all.extend(Overrides::from(self).to_settings());
        all
    }
}

impl From<&StepOverrides> for Overrides {
    fn from(args: &StepOverrides) -> Overrides {
        Overrides {
            integrator: args.integrator,
            dt: args.dt,
            ..Overrides::from(&args.scene)
        }
    }
}

/// A time step: a positive number, or a fraction of two (`1/60`), for every `--dt`.
pub fn time_step(s: &str) -> Result<f64, String> {
    let Some((a, b)) = s.split_once('/') else {
        return positive(s);
    };
    let x = positive(a.trim())? / positive(b.trim())?;
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err(format!("`{s}` is not a usable fraction"))
    }
}

pub fn positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("`{s}` is not a finite number greater than zero")),
    }
}

pub fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("`{s}` is not a finite number of at least zero")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_steps_are_numbers_or_fractions() {
        assert_eq!(time_step("0.001"), Ok(0.001));
        assert_eq!(time_step("1/60"), Ok(1.0 / 60.0));
        assert_eq!(time_step(" 1 / 2000 "), Ok(1.0 / 2000.0));
        for bad in [
            "0",
            "-1",
            "nan",
            "inf",
            "1/0",
            "1/",
            "/2",
            "a/b",
            "1e-300/1e300",
        ] {
            assert!(time_step(bad).is_err(), "{bad}");
        }
    }
}
