//! Gradients of a whole run with respect to a scene's values: the service behind
//! `softbody grad` (and `softbody fit`, and Python's `gradient`).
//!
//! A [`GradRequest`] names a scene (with `--set`s), the keys to differentiate by (the keys of
//! `--set`: [`DIFFERENTIABLE`]) and a loss ([`Target`]). The run's adjoint
//! ([`softbody_cpu::adjoint`]) gives the loss's gradient with respect to the model's values
//! (each particle's initial position, velocity and mass, each spring's stiffness and damping,
//! gravity, drag, each terrain's friction and restitution, the friction and restitution of
//! contact between bodies); the chain rule to a key goes through the scene's own building: the
//! model is affine in each of these keys (a body's masses scale with its mass, its positions
//! move with its centre, …), so building it with the key at three values, t = ¼, ½, ¾, gives
//! the model's derivative B along the key as the difference of two builds, checked against the
//! second difference (the build must be affine in the key, and change nothing the adjoint does
//! not reach). Then ∂L/∂θ = Σ ⟨∂L/∂model, B⟩.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use glam::DVec3;
use softbody_cpu::adjoint::run::{
    AdjointError, Backward, FrameBar, Loss, Options, gradient as adjoint,
};
use softbody_scene::{Controls, Instability, Model, Scene, SceneError, Solver, State, StepError};

use crate::guard::EnergyGuard;
use crate::run::RunError;

use crate::output::jsonl;
use crate::{Setting, load_scene};

/// The keys a gradient can be taken with respect to, as `--set` names them (N: an index).
pub const DIFFERENTIABLE: [&str; 16] = [
    "body[N].mass",
    "body[N].density",
    "body[N].structural.stiffness",
    "body[N].structural.damping",
    "body[N].shear.stiffness",
    "body[N].shear.damping",
    "body[N].bending.stiffness",
    "body[N].bending.damping",
    "body[N].center",
    "body[N].velocity",
    "simulation.gravity",
    "simulation.drag",
    "terrain[N].friction",
    "terrain[N].restitution",
    "simulation.body_friction",
    "simulation.body_restitution",
];

/// What the loss measures.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// L = |c − target|², c the mass-weighted centre of all particles at the last frame.
    Com(DVec3),
    /// L = (1/(F·N)) Σ_frames Σ_particles |x − x̂|² over the F frames of the run that the file
    /// (JSON Lines or NPZ written by `softbody run` for the same particles) has too.
    Frames(PathBuf),
    /// Any loss, given by its cotangents ∂L/∂x and ∂L/∂v at every frame (frame-major,
    /// `frames × particles` each; an empty one is zero). The loss itself is the caller's: the
    /// report's is 0.
    Cotangents {
        /// ∂L/∂x_{f,i} at index f·N + i.
        positions: Vec<DVec3>,
        /// ∂L/∂v_{f,i} at index f·N + i.
        velocities: Vec<DVec3>,
    },
}

/// A gradient to compute.
#[derive(Debug, Clone, Default)]
pub struct GradRequest {
    /// The scene file (the origin of `text` when that is given: messages, mesh paths).
    pub scene: PathBuf,
    /// The scene's TOML in place of the file's.
    pub text: Option<String>,
    /// Settings applied to it (`--set` and the overrides), in order.
    pub settings: Vec<Setting>,
    /// The keys, as written.
    pub wrt: Vec<String>,
    /// The loss.
    pub target: Target,
    /// Threads (all cores if `None`); the result's bits do not depend on it.
    pub threads: Option<usize>,
    /// Control forces on the particles, F × N frame-major ([`softbody_scene::controls`]): the
    /// run's, whose gradient is [`Backward::controls`].
    pub controls: Option<std::sync::Arc<[DVec3]>>,
}

impl Default for Target {
    fn default() -> Target {
        Target::Com(DVec3::ZERO)
    }
}

impl GradRequest {
    /// The scene with `settings` applied.
    fn load(&self, settings: &[Setting]) -> Result<Scene, SceneError> {
        match &self.text {
            Some(text) => crate::scene_from_toml(text, &self.scene, settings),
            None => load_scene(&self.scene, settings),
        }
    }
}

/// A key's gradient: a number, or three for a vector key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Derivative {
    /// ∂L/∂θ.
    Scalar(f64),
    /// (∂L/∂θ_x, ∂L/∂θ_y, ∂L/∂θ_z).
    Vector(DVec3),
}

/// What [`gradient`] computed.
#[derive(Debug, Clone)]
pub struct GradReport {
    /// The loss.
    pub loss: f64,
    /// Each key's derivative, in the order asked (keys in their canonical spelling).
    pub gradient: Vec<(String, Derivative)>,
    /// ∂L/∂m_i per particle, through m and through w = 1/m (pinned particles: through m).
    pub mass: Vec<f64>,
    /// The adjoint's own result: the per-particle and per-spring gradients, the steps, the
    /// memory and the times.
    pub backward: Backward,
}

/// Why a gradient could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum GradError {
    /// The request or the scene is not one gradients are computed for (exit status 2).
    #[error("{0}")]
    Input(String),
    /// The scene is not valid (exit status 2).
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The forward run went unstable (exit status 3).
    #[error("{0}")]
    Unstable(String),
    /// The request's stop flag was set.
    #[error("stopped")]
    Stopped,
    /// Anything else (exit status 1).
    #[error("{0}")]
    Other(String),
}

impl GradError {
    /// The exit status of the CLI for this error (docs/guide/cli.md).
    pub fn status(&self) -> u8 {
        match self {
            GradError::Input(_) | GradError::Scene(_) => 2,
            GradError::Unstable(_) => 3,
            GradError::Other(_) | GradError::Stopped => 1,
        }
    }
}

impl From<AdjointError> for GradError {
    fn from(e: AdjointError) -> GradError {
        match e {
            AdjointError::Step(StepError::Unstable(i)) => GradError::Unstable(i.to_string()),
            AdjointError::Stopped => GradError::Stopped,
            e => GradError::Other(e.to_string()),
        }
    }
}

/// A key of [`DIFFERENTIABLE`], parsed.
#[derive(Debug, Clone, PartialEq)]
struct Key {
    /// The canonical spelling (`body[0].mass`).
    name: String,
    vector: bool,
}

/// Parses `key` against [`DIFFERENTIABLE`]; refuses any other with the list.
fn parse_key(key: &str) -> Result<Key, GradError> {
    let refuse = || {
        GradError::Input(format!(
            "--wrt {key}: not a key gradients are taken with respect to; these are: {}",
            DIFFERENTIABLE.join(", ")
        ))
    };
    let (head, rest) = key.trim().split_once('.').ok_or_else(refuse)?;
    let (kind, index) = match head.split_once('[') {
        Some((kind, tail)) => {
            let digits = tail.strip_suffix(']').ok_or_else(refuse)?;
            let index: usize = digits.parse().map_err(|_| refuse())?;
            if digits.len() > 1 && digits.starts_with('0') {
                return Err(refuse());
            }
            (kind, Some(index))
        }
        None => (head, None),
    };
    let pattern = match index {
        Some(_) => format!("{kind}[N].{rest}"),
        None => format!("{kind}.{rest}"),
    };
    if !DIFFERENTIABLE.contains(&pattern.as_str()) {
        return Err(refuse());
    }
    let name = match index {
        Some(n) => format!("{kind}[{n}].{rest}"),
        None => format!("{kind}.{rest}"),
    };
    let vector = matches!(rest, "center" | "velocity" | "gravity");
    Ok(Key { name, vector })
}

/// The loss's gradient over the run of the request's scene, with respect to its keys.
pub fn gradient(request: &GradRequest) -> Result<GradReport, GradError> {
    gradient_until(request, None)
}

/// [`gradient`], ending at the next checkpoint segment once `stop` is set
/// ([`GradError::Stopped`]).
pub fn gradient_until(
    request: &GradRequest,
    stop: Option<&std::sync::atomic::AtomicBool>,
) -> Result<GradReport, GradError> {
    let keys: Vec<Key> = request
        .wrt
        .iter()
        .map(|k| parse_key(k))
        .collect::<Result<_, _>>()?;
    let scene = request.load(&request.settings)?;
    for key in &keys {
        check_index(&scene, &key.name)?;
    }
    let (model, state) = Model::build(&scene);
    let mut loss = TargetLoss::new(&request.target, &model)?;
    if let TargetLoss::Frames { matched: 0, .. } = loss {
        return Err(GradError::Input(format!(
            "--target-frames {}: none of its frames is a frame of this run",
            display(&request.target)
        )));
    }
    let controls = request
        .controls
        .as_ref()
        .map(|u| Controls::new(&model, u.clone()))
        .transpose()
        .map_err(|e| GradError::Input(e.to_string()))?;
    // `run`'s energy guard on the forward pass: what `run` calls unstable has no gradient.
    let mut guard: Option<EnergyGuard> = None;
    let frames = model.simulation.frame_count();
    let mut check = |k: u64, solver: &mut dyn Solver| -> Result<(), StepError> {
        let step_error = |e: RunError| match e {
            RunError::Unstable(i) => StepError::Unstable(i),
            e => StepError::Invalid(e.to_string()),
        };
        if k == 0 {
            guard = Some(EnergyGuard::start(solver).map_err(step_error)?);
        }
        let checked = guard
            .as_mut()
            .expect("frame 0 is checked first")
            .frame(k, solver)
            .map(|_| ())
            .map_err(step_error);
        // Its copy of the last frame checked is not held into the backward pass.
        if k + 1 == frames {
            guard = None;
        }
        checked
    };
    let options = Options {
        threads: request.threads,
        controls: controls.as_ref(),
        stop,
        check: Some(&mut check),
    };
    // An instability says what to try next, as `run`'s does.
    let integrator = model.simulation.integrator;
    let backward = adjoint(&model, &state, &mut loss, options).map_err(|e| match e.into() {
        GradError::Unstable(why) => {
            GradError::Unstable(format!("{why}; {}", Instability::advice(integrator)))
        }
        e => e,
    })?;
    let values = Values::of(&model, &state);
    let mut gradient = Vec::new();
    for key in &keys {
        let derivative = if key.vector {
            let mut g = [0.0; 3];
            for (k, g) in g.iter_mut().enumerate() {
                let b = direction(request, &values, key, |t| {
                    let mut v = [0.0; 3];
                    v[k] = t;
                    toml::Value::Array(v.iter().map(|&x| toml::Value::Float(x)).collect())
                })?;
                *g = b.dot(&backward, &model);
            }
            Derivative::Vector(DVec3::from_array(g))
        } else {
            let b = direction(request, &values, key, toml::Value::Float)?;
            Derivative::Scalar(b.dot(&backward, &model))
        };
        gradient.push((key.name.clone(), derivative));
    }
    let g = &backward.gradient;
    let mass = (0..model.len())
        .map(|i| {
            let w = model.inv_mass[i];
            g.mass[i] - g.inv_mass[i] * w * w
        })
        .collect();
    Ok(GradReport {
        loss: backward.loss,
        gradient,
        mass,
        backward,
    })
}

fn display(target: &Target) -> String {
    match target {
        Target::Frames(p) => p.display().to_string(),
        Target::Com(c) => format!("{},{},{}", c.x, c.y, c.z),
        Target::Cotangents { .. } => "the cotangents".to_owned(),
    }
}

/// Refuses a key whose index is past the scene's bodies or terrain.
fn check_index(scene: &Scene, key: &str) -> Result<(), GradError> {
    let index = |prefix: &str| -> Option<usize> {
        key.strip_prefix(prefix)?.split(']').next()?.parse().ok()
    };
    let (what, count, n) = if let Some(n) = index("body[") {
        ("bodies", scene.bodies.len(), n)
    } else if let Some(n) = index("terrain[") {
        ("terrain shapes", scene.terrain.len(), n)
    } else {
        return Ok(());
    };
    if n >= count {
        return Err(GradError::Input(format!(
            "--wrt {key}: the scene has {count} {what}"
        )));
    }
    Ok(())
}

/// The model's values the adjoint differentiates, flattened in a fixed order, and what else
/// the model holds that a key must not change.
#[derive(Debug, Clone, PartialEq)]
struct Values {
    x: Vec<DVec3>,
    v: Vec<DVec3>,
    mass: Vec<f64>,
    stiffness: Vec<f64>,
    damping: Vec<f64>,
    gravity: DVec3,
    drag: f64,
    friction: Vec<f64>,
    restitution: Vec<f64>,
    /// μ and k_r of contact between bodies.
    body_laws: [f64; 2],
    /// Rest lengths, step, contact distance, pinned particles, contact radii: fixed along every
    /// key.
    fixed: Vec<f64>,
}

impl Values {
    fn of(model: &Model, state: &State) -> Values {
        let springs = model.springs();
        let sim = &model.simulation;
        let mut fixed = springs.rest.clone();
        fixed.extend([sim.dt, sim.duration, sim.frame_rate, sim.contact_distance]);
        fixed.extend(
            model
                .inv_mass
                .iter()
                .map(|&w| f64::from(u8::from(w == 0.0))),
        );
        fixed.extend(springs.a.iter().chain(&springs.b).map(|&p| f64::from(p)));
        fixed.extend(&model.contact.radius);
        Values {
            x: state.x.clone(),
            v: state.v.clone(),
            mass: model.mass.clone(),
            stiffness: springs.stiffness.clone(),
            damping: springs.damping.clone(),
            gravity: sim.gravity,
            drag: sim.drag,
            friction: model.terrain.iter().map(|t| t.friction).collect(),
            restitution: model.terrain.iter().map(|t| t.restitution).collect(),
            body_laws: [model.contact.laws.friction, model.contact.laws.restitution],
            fixed,
        }
    }

    /// (self − other)/by, value by value (the fixed part left as it is).
    fn difference(&self, other: &Values, by: f64) -> Values {
        let d3 = |a: &[DVec3], b: &[DVec3]| a.iter().zip(b).map(|(a, b)| (*a - *b) / by).collect();
        let d1 = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| (a - b) / by).collect();
        Values {
            x: d3(&self.x, &other.x),
            v: d3(&self.v, &other.v),
            mass: d1(&self.mass, &other.mass),
            stiffness: d1(&self.stiffness, &other.stiffness),
            damping: d1(&self.damping, &other.damping),
            gravity: (self.gravity - other.gravity) / by,
            drag: (self.drag - other.drag) / by,
            friction: d1(&self.friction, &other.friction),
            restitution: d1(&self.restitution, &other.restitution),
            body_laws: [0, 1].map(|k| (self.body_laws[k] - other.body_laws[k]) / by),
            fixed: self.fixed.clone(),
        }
    }

    /// Every value flattened (for comparing two derivatives).
    fn flat(&self) -> Vec<f64> {
        let mut out: Vec<f64> = self
            .x
            .iter()
            .chain(&self.v)
            .flat_map(|p| p.to_array())
            .collect();
        out.extend(&self.mass);
        out.extend(&self.stiffness);
        out.extend(&self.damping);
        out.extend(self.gravity.to_array());
        out.push(self.drag);
        out.extend(&self.friction);
        out.extend(&self.restitution);
        out.extend(self.body_laws);
        out
    }

    /// ⟨∂L/∂model, self⟩ for the derivative `self` of the model along a key, with `model` the
    /// model at the scene's own values (w = 1/m: ∂w/∂θ = −w² ∂m/∂θ; pinned particles keep
    /// w = 0).
    fn dot(&self, back: &Backward, model: &Model) -> f64 {
        let g = &back.gradient;
        let mut sum = 0.0;
        for i in 0..self.x.len() {
            sum += back.x0[i].dot(self.x[i]) + back.v0[i].dot(self.v[i]);
            let w = model.inv_mass[i];
            sum += (g.mass[i] - g.inv_mass[i] * w * w) * self.mass[i];
        }
        for s in 0..self.stiffness.len() {
            sum += g.stiffness[s] * self.stiffness[s] + g.damping[s] * self.damping[s];
        }
        sum += g.gravity_total().dot(self.gravity) + g.drag_total() * self.drag;
        for k in 0..self.friction.len() {
            sum += g.friction_of(k) * self.friction[k] + g.restitution_of(k) * self.restitution[k];
        }
        sum += g.body_friction_total() * self.body_laws[0]
            + g.body_restitution_total() * self.body_laws[1];
        sum
    }
}

/// The model's derivative along `key`, from its builds with the key set to `value(t)` for
/// t = ¼, ½, ¾ (after the request's own settings).
fn direction(
    request: &GradRequest,
    nominal: &Values,
    key: &Key,
    value: impl Fn(f64) -> toml::Value,
) -> Result<Values, GradError> {
    let build = |t: f64| -> Result<Values, GradError> {
        let mut settings = request.settings.clone();
        let setting = Setting::new(&key.name, value(t))
            .map_err(|m| GradError::Input(format!("--wrt {}: {m}", key.name)))?;
        settings.push(setting);
        let scene = request.load(&settings).map_err(|e| {
            GradError::Input(format!(
                "--wrt {}: the scene cannot be built with the key varied ({e})",
                key.name
            ))
        })?;
        let (model, state) = Model::build(&scene);
        Ok(Values::of(&model, &state))
    };
    let (a, b, c) = (build(0.25)?, build(0.5)?, build(0.75)?);
    let first = b.difference(&a, 0.25);
    let second = c.difference(&b, 0.25);
    let (f, s) = (first.flat(), second.flat());
    let same_shape = a.fixed == nominal.fixed
        && b.fixed == nominal.fixed
        && c.fixed == nominal.fixed
        && f.len() == nominal.flat().len();
    let scale = f.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(1.0);
    let affine = f.iter().zip(&s).all(|(p, q)| (p - q).abs() <= 1e-9 * scale);
    if !(same_shape && affine) {
        return Err(GradError::Input(format!(
            "--wrt {}: this scene's model does not depend on the key affinely, or the key \
             changes what gradients do not reach (rest lengths, the step, which particles are \
             pinned)",
            key.name
        )));
    }
    Ok(first)
}

/// The built-in losses.
enum TargetLoss {
    Com {
        target: DVec3,
        last: u64,
        masses: Vec<f64>,
    },
    Cotangents {
        positions: Vec<DVec3>,
        velocities: Vec<DVec3>,
        particles: usize,
    },
    Frames {
        /// The recorded positions by frame number.
        recorded: BTreeMap<u64, Vec<DVec3>>,
        /// F·N of the frames both have.
        weight: f64,
        matched: u64,
    },
}

impl TargetLoss {
    fn new(target: &Target, model: &Model) -> Result<TargetLoss, GradError> {
        let frames = model.simulation.frame_count();
        match target {
            Target::Com(target) => Ok(TargetLoss::Com {
                target: *target,
                last: frames.saturating_sub(1),
                masses: model.mass.clone(),
            }),
            Target::Cotangents {
                positions,
                velocities,
            } => {
                let expected = frames as usize * model.len();
                for (what, given) in [("positions", positions), ("velocities", velocities)] {
                    if !given.is_empty() && given.len() != expected {
                        return Err(GradError::Input(format!(
                            "the cotangents of the {what} are {} vectors; this run has {frames} \
                             frames of {} particles: {expected}",
                            given.len(),
                            model.len()
                        )));
                    }
                }
                Ok(TargetLoss::Cotangents {
                    positions: positions.clone(),
                    velocities: velocities.clone(),
                    particles: model.len(),
                })
            }
            Target::Frames(path) => {
                let recorded = read_frames(path, model.len())?;
                let common = recorded.keys().filter(|&&f| f < frames).count();
                Ok(TargetLoss::Frames {
                    recorded,
                    weight: (common * model.len()).max(1) as f64,
                    matched: common as u64,
                })
            }
        }
    }
}

impl Loss for TargetLoss {
    fn frame(&mut self, frame: u64, state: &State, bar: FrameBar<'_>) -> f64 {
        match self {
            TargetLoss::Com {
                target,
                last,
                masses,
            } => {
                if frame != *last {
                    return 0.0;
                }
                // c = Σ m x / M: ∂c/∂x_i = m_i/M, ∂c/∂m_i = (x_i − c)/M.
                let total = masses.iter().sum::<f64>();
                let c = state
                    .x
                    .iter()
                    .zip(masses.iter())
                    .fold(DVec3::ZERO, |s, (x, m)| s + *m * *x)
                    / total;
                let d = c - *target;
                for (i, x) in state.x.iter().enumerate() {
                    bar.x[i] += 2.0 * masses[i] / total * d;
                    bar.mass[i] += 2.0 * d.dot(*x - c) / total;
                }
                d.length_squared()
            }
            TargetLoss::Cotangents {
                positions,
                velocities,
                particles,
            } => {
                let at = frame as usize * *particles;
                for (given, bar) in [(&*positions, &mut *bar.x), (&*velocities, &mut *bar.v)] {
                    if let Some(given) = given.get(at..at + *particles) {
                        bar.iter_mut().zip(given).for_each(|(b, g)| *b += *g);
                    }
                }
                0.0
            }
            TargetLoss::Frames {
                recorded, weight, ..
            } => {
                let Some(x_hat) = recorded.get(&frame) else {
                    return 0.0;
                };
                let mut sum = 0.0;
                for (i, (x, y)) in state.x.iter().zip(x_hat).enumerate() {
                    let d = *x - *y;
                    sum += d.length_squared();
                    bar.x[i] += 2.0 * d / *weight;
                }
                sum / *weight
            }
        }
    }
}

/// The positions by frame number of a run's frames file (JSON Lines or NPZ) of `particles`
/// particles.
fn read_frames(path: &Path, particles: usize) -> Result<BTreeMap<u64, Vec<DVec3>>, GradError> {
    let bad = |m: String| GradError::Input(format!("--target-frames {}: {m}", path.display()));
    let npz = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npz"));
    let mut out = BTreeMap::new();
    if npz {
        let file = std::fs::File::open(path).map_err(|e| bad(format!("cannot read: {e}")))?;
        let mut zip =
            zip::ZipArchive::new(file).map_err(|e| bad(format!("not an NPZ archive: {e}")))?;
        let array = |zip: &mut zip::ZipArchive<std::fs::File>,
                     name: &str|
         -> Result<(Vec<u64>, Vec<f64>), GradError> {
            let mut entry = zip
                .by_name(&format!("{name}.npy"))
                .map_err(|_| bad(format!("no array {name}")))?;
            let mut bytes = Vec::new();
            entry
                .read_to_end(&mut bytes)
                .map_err(|e| bad(format!("cannot read {name}: {e}")))?;
            let npy = npyz::NpyFile::new(&bytes[..]).map_err(|e| bad(format!("{name}: {e}")))?;
            let shape = npy.shape().to_vec();
            let data: Vec<f64> = npy.into_vec().map_err(|e| bad(format!("{name}: {e}")))?;
            Ok((shape, data))
        };
        let (shape, positions) = array(&mut zip, "positions")?;
        let (_, time) = array(&mut zip, "time")?;
        let (_, rate) = array(&mut zip, "frame_rate")?;
        if shape.len() != 3 || shape[1] as usize != particles || shape[2] != 3 {
            return Err(bad(format!(
                "positions has shape {shape:?}; this scene has {particles} particles: [F, {particles}, 3]"
            )));
        }
        if time.len() as u64 != shape[0] {
            return Err(bad(format!(
                "time has {} entries for {} frames of positions",
                time.len(),
                shape[0]
            )));
        }
        let rate = rate.first().copied().unwrap_or(f64::NAN);
        for (f, t) in time.iter().enumerate() {
            let index = (t * rate).round();
            if !(index.is_finite() && index >= 0.0) {
                return Err(bad(format!("frame {f}'s time {t} s is not a frame time")));
            }
            let at = f * particles * 3;
            let x = (0..particles)
                .map(|i| DVec3::from_slice(&positions[at + 3 * i..at + 3 * i + 3]))
                .collect();
            out.insert(index as u64, x);
        }
    } else {
        let reader = jsonl::Reader::open(path)
            .map_err(|e| GradError::Input(format!("--target-frames: {e}")))?;
        if reader.header().particles != particles {
            return Err(bad(format!(
                "its frames have {} particles; this scene has {particles}",
                reader.header().particles
            )));
        }
        for frame in reader {
            let frame = frame.map_err(|e| GradError::Input(format!("--target-frames: {e}")))?;
            out.insert(frame.index, frame.positions);
        }
    }
    Ok(out)
}
