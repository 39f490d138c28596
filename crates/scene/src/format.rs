//! The scene file as written: plain serde structs that mirror the TOML one to one.
//!
//! Every table refuses unknown keys. Bodies and terrain shapes are flat structs with optional
//! fields rather than tagged enums: serde's internally tagged enums buffer their content and lose
//! the source spans, and precise line numbers are part of the contract. `Scene::validate` checks
//! that each `kind` gets exactly the keys it needs.

#![allow(
    missing_docs,
    reason = "the fields are the TOML keys, documented in docs/guide/scene-format.md"
)]

use serde::Deserialize;

use crate::{Integrator, Preconditioner};

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
    #[serde(default)]
    pub preconditioner: Preconditioner,
    #[serde(default = "default_cg_tolerance")]
    pub cg_tolerance: f64,
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
fn default_cg_tolerance() -> f64 {
    crate::implicit::CG_TOLERANCE
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
    Mesh,
}

/// What a mesh body's surface is in the exports and pictures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SurfaceKind {
    /// The input mesh, carried by the lattice (trilinear weights in its cells).
    #[default]
    Mesh,
    /// The lattice's own outer faces.
    Lattice,
}

/// A value written either as one number or as three (`resolution = 12` or
/// `resolution = [4, 5, 6]`; `scale = 2.0` or `scale = [1.0, 2.0, 1.0]`). Deserialised by a
/// visitor on the value itself (not an untagged enum, which buffers and loses the spans).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OneOrThree<T> {
    One(T),
    Three([T; 3]),
}

impl<T: Copy> OneOrThree<T> {
    /// The three values (the one repeated).
    pub fn three(self) -> [T; 3] {
        match self {
            OneOrThree::One(x) => [x; 3],
            OneOrThree::Three(v) => v,
        }
    }
}

/// Numbers `OneOrThree` takes: TOML integers and floats, each converted or refused.
pub trait Number: Copy + for<'de> Deserialize<'de> {
    /// What the visitor expects, in serde's words.
    const EXPECTING: &'static str;
    fn from_i64(x: i64) -> Option<Self>;
    fn from_f64(x: f64) -> Option<Self>;
}

impl Number for u64 {
    const EXPECTING: &'static str = "a non-negative integer or an array of three";
    fn from_i64(x: i64) -> Option<u64> {
        u64::try_from(x).ok()
    }
    fn from_f64(_: f64) -> Option<u64> {
        None
    }
}

impl Number for f64 {
    const EXPECTING: &'static str = "a number or an array of three numbers";
    fn from_i64(x: i64) -> Option<f64> {
        Some(x as f64)
    }
    fn from_f64(x: f64) -> Option<f64> {
        Some(x)
    }
}

impl<'de, T: Number> Deserialize<'de> for OneOrThree<T> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::{Error, SeqAccess, Unexpected, Visitor};
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: Number> Visitor<'de> for V<T> {
            type Value = OneOrThree<T>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(T::EXPECTING)
            }
            fn visit_i64<E: Error>(self, x: i64) -> Result<Self::Value, E> {
                T::from_i64(x)
                    .map(OneOrThree::One)
                    .ok_or_else(|| E::invalid_value(Unexpected::Signed(x), &self))
            }
            fn visit_u64<E: Error>(self, x: u64) -> Result<Self::Value, E> {
                match i64::try_from(x) {
                    Ok(x) => self.visit_i64(x),
                    Err(_) => Err(E::invalid_value(Unexpected::Unsigned(x), &self)),
                }
            }
            fn visit_f64<E: Error>(self, x: f64) -> Result<Self::Value, E> {
                T::from_f64(x)
                    .map(OneOrThree::One)
                    .ok_or_else(|| E::invalid_type(Unexpected::Float(x), &self))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut v = Vec::with_capacity(3);
                while let Some(x) = seq.next_element::<T>()? {
                    if v.len() == 3 {
                        return Err(A::Error::invalid_length(4, &"an array of three"));
                    }
                    v.push(x);
                }
                match v[..] {
                    [a, b, c] => Ok(OneOrThree::Three([a, b, c])),
                    _ => Err(A::Error::invalid_length(v.len(), &"an array of three")),
                }
            }
        }
        d.deserialize_any(V(std::marker::PhantomData))
    }
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
    // cuboid (and mesh: resolution, center, rotation, velocity, mass, the spring families)
    pub size: Option<[f64; 3]>,
    pub resolution: Option<OneOrThree<u64>>,
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
    // mesh (`file` or `path`: a mesh terrain's key too)
    pub file: Option<String>,
    pub path: Option<String>,
    pub cell: Option<f64>,
    pub scale: Option<OneOrThree<f64>>,
    pub density: Option<f64>,
    pub surface: Option<SurfaceKind>,
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
    // mesh (`path` or `file`: a mesh body's key too)
    pub path: Option<String>,
    pub file: Option<String>,
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
