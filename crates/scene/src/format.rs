//! The scene file as written: plain serde structs that mirror the TOML one to one.
//!
//! Every table refuses unknown keys. Bodies and terrain shapes are flat structs with optional
//! fields rather than tagged enums: serde's internally tagged enums buffer their content and lose
//! the source spans, and precise line numbers are part of the contract. `Scene::validate` checks
//! that each `kind` gets exactly the keys it needs.

#![allow(
    missing_docs,
    reason = "the fields are the TOML keys, documented in docs/scene-format.md"
)]

use serde::Deserialize;

use crate::Integrator;

/// `[simulation]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationFile {
    #[serde(default = "default_integrator")]
    pub integrator: Integrator,
    pub dt: f64,
    pub duration: f64,
    #[serde(default = "default_frame_rate")]
    pub frame_rate: f64,
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    #[serde(default)]
    pub drag: f64,
    #[serde(default = "default_contact_distance")]
    pub contact_distance: f64,
    #[serde(default)]
    pub body_restitution: f64,
    #[serde(default)]
    pub body_friction: f64,
    #[serde(default)]
    pub body_friction_model: FrictionModel,
}

fn default_integrator() -> Integrator {
    Integrator::SymplecticEuler
}
fn default_frame_rate() -> f64 {
    30.0
}
fn default_gravity() -> [f64; 3] {
    [0.0, -9.81, 0.0]
}
fn default_contact_distance() -> f64 {
    1e-3
}

/// `stiffness` and `damping` of one spring family.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpringFile {
    pub stiffness: f64,
    #[serde(default)]
    pub damping: f64,
}

/// One explicit spring of a `particles` body.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExplicitSpringFile {
    pub a: u64,
    pub b: u64,
    pub stiffness: f64,
    #[serde(default)]
    pub damping: f64,
    pub rest: Option<f64>,
}

/// The body kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BodyKind {
    Cuboid,
    Particles,
}

/// `[[body]]`: the union of the keys of every body kind.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyFile {
    pub name: Option<String>,
    pub kind: BodyKind,
    #[serde(default)]
    pub pinned: Vec<u64>,
    pub contact_radius: Option<f64>,
    #[serde(default)]
    pub self_contact: bool,
    // cuboid
    pub size: Option<[f64; 3]>,
    pub resolution: Option<[u64; 3]>,
    pub center: Option<[f64; 3]>,
    pub rotation: Option<[f64; 3]>,
    pub velocity: Option<[f64; 3]>,
    pub mass: Option<f64>,
    pub structural: Option<SpringFile>,
    pub shear: Option<SpringFile>,
    pub bending: Option<SpringFile>,
    // particles
    pub positions: Option<Vec<[f64; 3]>>,
    pub velocities: Option<Vec<[f64; 3]>>,
    pub masses: Option<Vec<f64>>,
    pub springs: Option<Vec<ExplicitSpringFile>>,
}

/// The terrain kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TerrainKind {
    Plane,
    Box,
    Sphere,
    Bowl,
    Heightfield,
    Mesh,
}

/// How a terrain shape resists sliding; see `docs/physics.md`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FrictionModel {
    /// Coulomb friction: kinetic `μ|f_n|` against the slip, static up to `μ|f_n|` below a
    /// small slip speed.
    #[default]
    Coulomb,
    /// The classic course formula `−k_f |f_n| v_t`.
    Viscous,
}

/// `[[terrain]]`: the union of the keys of every terrain kind.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TerrainFile {
    pub kind: TerrainKind,
    #[serde(default)]
    pub restitution: f64,
    #[serde(default)]
    pub friction: f64,
    #[serde(default)]
    pub friction_model: FrictionModel,
    // plane
    pub point: Option<[f64; 3]>,
    pub normal: Option<[f64; 3]>,
    // box, sphere, bowl
    pub center: Option<[f64; 3]>,
    pub half_extents: Option<[f64; 3]>,
    pub rotation: Option<[f64; 3]>,
    pub radius: Option<f64>,
    // heightfield
    pub heights: Option<Vec<Vec<f64>>>,
    pub cell_size: Option<[f64; 2]>,
    pub origin: Option<[f64; 3]>,
    // mesh
    pub path: Option<String>,
}

/// The whole file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub simulation: SimulationFile,
    #[serde(default, rename = "body")]
    pub bodies: Vec<BodyFile>,
    #[serde(default, rename = "terrain")]
    pub terrain: Vec<TerrainFile>,
}
