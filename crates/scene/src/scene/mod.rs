//! The validated scene: what the solvers build a [`crate::Model`] from.
//!
//! A scene comes from a TOML file ([`Scene::from_file`]) or is built in code; either way
//! [`Scene::validate`] runs the same checks, and reports each failure by the key path the file
//! would use (`body[0].mass`), so a file's errors can be located on their line.

mod convert;

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3, EulerRot};

use crate::error::{Invalid, SceneError};
use crate::format::{FrictionModel, SceneFile, SurfaceKind};
use crate::voxel::Voxels;
use crate::{Integrator, Preconditioner, topology};

/// `[simulation]`, validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Simulation {
    /// The time integrator.
    pub integrator: Integrator,
    /// Time step h, seconds.
    pub dt: f64,
    /// Simulated time, seconds; the run takes `round(duration / dt)` steps.
    pub duration: f64,
    /// Frames per simulated second; frame 0 is the initial state.
    pub frame_rate: f64,
    /// Gravitational acceleration, m/s².
    pub gravity: DVec3,
    /// Linear drag coefficient, 1/s: force `−drag·m·v`.
    pub drag: f64,
    /// Contact distance ε, metres: a particle closer than this to a surface is in contact.
    pub contact_distance: f64,
    /// The laws of contact between particles of bodies (`body_restitution`, `body_friction`,
    /// `body_friction_model`).
    pub body_contact: BodyContact,
    /// Implicit Euler's CG preconditioner on the CPU (the GPU always runs block Jacobi).
    pub preconditioner: Preconditioner,
    /// Implicit Euler's CG stops at this relative residual, in (0, 1)
    /// ([`crate::implicit::CG_TOLERANCE`] by default; the GPU at no less than its f32 floor).
    pub cg_tolerance: f64,
}

/// The laws of contact between particles of bodies: the same as a terrain surface's, one set for
/// every pair of bodies (and a body with `self_contact`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BodyContact {
    /// k_r in [0, 1]: the fraction of the relative normal approach speed kept on a fresh impact.
    pub restitution: f64,
    /// μ (Coulomb) or k_f (viscous), ≥ 0.
    pub friction: f64,
    /// How the pair resists sliding.
    pub friction_model: FrictionModel,
}

impl Simulation {
    /// Number of steps of the run: `round(duration / dt)`.
    pub fn steps(&self) -> u64 {
        (self.duration / self.dt).round() as u64
    }

    /// The step at which frame `k` is taken: `round(k / (frame_rate·dt))`.
    pub fn frame_step(&self, k: u64) -> u64 {
        (k as f64 / (self.frame_rate * self.dt)).round() as u64
    }

    /// Number of frames of the run: every `k` with `frame_step(k) <= steps()`.
    pub fn frame_count(&self) -> u64 {
        let steps = self.steps();
        let mut k = (steps as f64 * self.frame_rate * self.dt).floor() as u64;
        while self.frame_step(k + 1) <= steps {
            k += 1;
        }
        while k > 0 && self.frame_step(k) > steps {
            k -= 1;
        }
        k + 1
    }
}

/// Stiffness and damping of one spring family.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpringParams {
    /// k_s, N/m.
    pub stiffness: f64,
    /// k_d, N·s/m.
    pub damping: f64,
}

/// A box of particles on a regular grid, joined by structural, shear and bending springs.
#[derive(Debug, Clone, PartialEq)]
pub struct Cuboid {
    /// Edge lengths, metres.
    pub size: DVec3,
    /// Particles per axis, each >= 2.
    pub resolution: [u32; 3],
    /// Centre of the box, metres.
    pub center: DVec3,
    /// Rotation, degrees about x, then y, then z (extrinsic).
    pub rotation: DVec3,
    /// Initial velocity of every particle, m/s.
    pub velocity: DVec3,
    /// Total mass, kg, spread evenly.
    pub mass: f64,
    /// Axis neighbours one cell apart; `None` leaves the family out.
    pub structural: Option<SpringParams>,
    /// Face and body diagonals of each cell.
    pub shear: Option<SpringParams>,
    /// Axis neighbours two cells apart.
    pub bending: Option<SpringParams>,
}

impl Cuboid {
    /// The smallest distance between lattice neighbours along an axis, metres (resolutions are
    /// at least 2 in a valid scene).
    pub fn smallest_spacing(&self) -> f64 {
        (0..3)
            .map(|axis| self.size[axis] / f64::from(self.resolution[axis].max(2) - 1))
            .fold(f64::INFINITY, f64::min)
    }
}

/// One spring of a [`ParticleSet`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExplicitSpring {
    /// First particle, index within the body.
    pub a: u32,
    /// Second particle, index within the body.
    pub b: u32,
    /// k_s, N/m.
    pub stiffness: f64,
    /// k_d, N·s/m.
    pub damping: f64,
    /// Rest length, metres; `None` takes the initial distance.
    pub rest: Option<f64>,
}

/// Free particles and explicit springs.
#[derive(Debug, Clone, PartialEq)]
pub struct ParticleSet {
    /// Positions, metres.
    pub positions: Vec<DVec3>,
    /// Velocities, m/s (same length as positions).
    pub velocities: Vec<DVec3>,
    /// Masses, kg.
    pub masses: Vec<f64>,
    /// Springs between them.
    pub springs: Vec<ExplicitSpring>,
}

/// How a mesh body's mass is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MeshMass {
    /// Total mass, kg.
    Mass(f64),
    /// Density, kg/m³, of the volume the mesh encloses ([`Voxels::enclosed_volume`]); of the
    /// lattice's (kept cells × h³) for a mesh that is not closed.
    Density(f64),
}

/// A closed triangle mesh voxelised into a lattice of particles (`kind = "mesh"`): the
/// particles are the corners of the kept cells ([`crate::voxel`]), joined by the cuboid's
/// spring families, and the mesh rides on the lattice (each vertex a trilinear combination of
/// its cell's corners).
///
/// The file's coordinates p are placed at `center + R·(s ⊙ p − o)`: scaled by `s`, rotated by
/// R (`rotation`, as a cuboid's), and translated so that the centre o of the scaled mesh's
/// bounding box lands on `center`. The lattice is aligned with the mesh's own axes (it turns
/// with the body, as a cuboid's does).
#[derive(Debug, Clone, PartialEq)]
pub struct MeshBody {
    /// The mesh, its scale and its lattice, voxelised once ([`Voxels::new`]).
    pub voxels: std::sync::Arc<Voxels>,
    /// Where the centre of the scaled mesh's bounding box goes, metres.
    pub center: DVec3,
    /// Rotation, degrees about x, then y, then z (extrinsic), as a cuboid's.
    pub rotation: DVec3,
    /// Initial velocity of every particle, m/s.
    pub velocity: DVec3,
    /// Total mass or density; spread evenly over the particles.
    pub mass: MeshMass,
    /// Axis neighbours one cell apart; `None` leaves the family out.
    pub structural: Option<SpringParams>,
    /// Face and body diagonals of each cell.
    pub shear: Option<SpringParams>,
    /// Axis neighbours two cells apart.
    pub bending: Option<SpringParams>,
    /// What the exports and pictures show of it: the mesh (default) or the lattice's faces.
    pub surface: SurfaceKind,
}

impl MeshBody {
    /// The total mass, kg: the given one, or density × the volume the mesh encloses (the
    /// lattice's where the mesh is not closed).
    pub fn total_mass(&self) -> f64 {
        match self.mass {
            MeshMass::Mass(m) => m,
            MeshMass::Density(rho) => rho * self.solid_volume(),
        }
    }

    /// The volume a density applies to, m³: the one the mesh encloses, or the lattice's where
    /// the mesh is not closed.
    pub fn solid_volume(&self) -> f64 {
        self.voxels
            .enclosed_volume()
            .unwrap_or_else(|| self.voxels.volume())
    }

    /// Where file coordinates `p` of the mesh are at rest, metres.
    pub fn place(&self, p: DVec3) -> DVec3 {
        self.center
            + rotation_from_degrees(self.rotation)
                * (p * self.voxels.scale() - self.voxels.offset())
    }
}

/// What a body is made of.
#[derive(Debug, Clone, PartialEq)]
pub enum BodyShape {
    /// `kind = "cuboid"`.
    Cuboid(Cuboid),
    /// `kind = "particles"`.
    Particles(ParticleSet),
    /// `kind = "mesh"`.
    Mesh(MeshBody),
}

/// One `[[body]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Body {
    /// Name, unique in the scene.
    pub name: String,
    /// Shape and springs.
    pub shape: BodyShape,
    /// Indices (within the body) of particles that never move.
    pub pinned: Vec<u32>,
    /// Contact radius r of each particle, metres: two particles of different bodies (or of a
    /// body with `self_contact`) closer than r_a + r_b touch. `None`: half the smallest lattice
    /// spacing of a cuboid, half the cell of a mesh body, 0 (no body contact) for a `particles`
    /// body.
    pub contact_radius: Option<f64>,
    /// Whether the body's own particles touch each other (beyond the rest neighbourhood: see
    /// docs/physics.md, "Contact between bodies").
    pub self_contact: bool,
}

impl Body {
    /// The body's mass, kg: a cuboid's or mesh body's total, a particle set's sum.
    pub fn mass(&self) -> f64 {
        match &self.shape {
            BodyShape::Cuboid(c) => c.mass,
            BodyShape::Particles(p) => p.masses.iter().sum(),
            BodyShape::Mesh(m) => m.total_mass(),
        }
    }

    /// The contact radius of the body's particles: the given one, or the default (half the
    /// smallest lattice spacing of a cuboid, half the cell of a mesh body, 0 for a `particles`
    /// body).
    pub fn contact_radius(&self) -> f64 {
        self.contact_radius.unwrap_or(match &self.shape {
            BodyShape::Cuboid(c) => 0.5 * c.smallest_spacing(),
            BodyShape::Particles(_) => 0.0,
            BodyShape::Mesh(m) => 0.5 * m.voxels.cell(),
        })
    }

    /// Number of particles, saturating (validation refuses scenes where it saturates).
    pub fn particle_count(&self) -> u64 {
        match &self.shape {
            BodyShape::Cuboid(c) => c
                .resolution
                .iter()
                .fold(1u64, |n, &r| n.saturating_mul(r as u64)),
            BodyShape::Particles(p) => p.positions.len() as u64,
            BodyShape::Mesh(m) => m.voxels.particle_count(),
        }
    }

    /// Number of springs of each family.
    pub fn spring_counts(&self) -> SpringCounts {
        match &self.shape {
            BodyShape::Cuboid(c) => topology::cuboid_spring_counts(c),
            BodyShape::Particles(p) => SpringCounts {
                structural: p.springs.len() as u64,
                ..SpringCounts::default()
            },
            BodyShape::Mesh(m) => {
                let all = m.voxels.spring_counts();
                let on =
                    |family: &Option<SpringParams>, n: u64| if family.is_some() { n } else { 0 };
                SpringCounts {
                    structural: on(&m.structural, all.structural),
                    shear: on(&m.shear, all.shear),
                    bending: on(&m.bending, all.bending),
                }
            }
        }
    }
}

/// Springs of each family; springs of `particles` bodies count as structural.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SpringCounts {
    /// Axis neighbours one cell apart (and explicit springs).
    pub structural: u64,
    /// Cell diagonals.
    pub shear: u64,
    /// Axis neighbours two cells apart.
    pub bending: u64,
}

impl SpringCounts {
    /// All springs.
    pub fn total(&self) -> u64 {
        self.structural + self.shear + self.bending
    }
}

impl std::ops::Add for SpringCounts {
    type Output = SpringCounts;
    fn add(self, o: SpringCounts) -> SpringCounts {
        SpringCounts {
            structural: self.structural + o.structural,
            shear: self.shear + o.shear,
            bending: self.bending + o.bending,
        }
    }
}

/// A regular grid of heights: vertex (row r, column c) sits at
/// `origin + (c·cell_size[0], heights[r][c], r·cell_size[1])`.
#[derive(Debug, Clone, PartialEq)]
pub struct Heightfield {
    /// Rows (along z) of heights (along x), at least 2×2, all rows the same length.
    pub heights: Vec<Vec<f64>>,
    /// Grid spacing along x and z, metres.
    pub cell_size: [f64; 2],
    /// World position of `heights[0][0]` at height zero.
    pub origin: DVec3,
}

/// A triangle mesh loaded from an OBJ file.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleMesh {
    /// The file it came from.
    pub path: PathBuf,
    /// Vertices, metres: an OBJ file's `v` positions in the file's order, used by a triangle
    /// or not.
    pub vertices: Vec<DVec3>,
    /// Triangles, counter-clockwise seen from outside (free space).
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// The closed box `[lo, lo + size]³`, four vertices per face (as an exporter of
    /// flat-shaded faces writes them), wound counter-clockwise seen from outside (the box is solid). For tests and for
    /// building terrain in code.
    pub fn cube(lo: DVec3, size: f64) -> TriangleMesh {
        // Each face's corners counter-clockwise seen from outside: +x, −x, +y, −y, +z, −z.
        let faces: [[[f64; 3]; 4]; 6] = [
            [[1., 0., 0.], [1., 1., 0.], [1., 1., 1.], [1., 0., 1.]],
            [[0., 0., 0.], [0., 0., 1.], [0., 1., 1.], [0., 1., 0.]],
            [[0., 1., 0.], [0., 1., 1.], [1., 1., 1.], [1., 1., 0.]],
            [[0., 0., 0.], [1., 0., 0.], [1., 0., 1.], [0., 0., 1.]],
            [[0., 0., 1.], [1., 0., 1.], [1., 1., 1.], [0., 1., 1.]],
            [[0., 0., 0.], [0., 1., 0.], [1., 1., 0.], [1., 0., 0.]],
        ];
        let mut vertices = Vec::with_capacity(24);
        let mut triangles = Vec::with_capacity(12);
        for f in faces {
            let k = vertices.len() as u32;
            vertices.extend(f.map(|p| lo + size * DVec3::from(p)));
            triangles.push([k, k + 1, k + 2]);
            triangles.push([k, k + 2, k + 3]);
        }
        TriangleMesh {
            path: "cube.obj".into(),
            vertices,
            triangles,
        }
    }
}

/// The geometry of one terrain shape.
#[derive(Debug, Clone, PartialEq)]
pub enum TerrainShape {
    /// The half-space below a plane through `point` with outward `normal` (unit length here).
    Plane {
        /// A point on the plane.
        point: DVec3,
        /// Unit outward normal.
        normal: DVec3,
    },
    /// A solid oriented box.
    Box {
        /// Centre.
        center: DVec3,
        /// Half edge lengths.
        half_extents: DVec3,
        /// Rotation, degrees about x, then y, then z.
        rotation: DVec3,
    },
    /// A solid ball.
    Sphere {
        /// Centre.
        center: DVec3,
        /// Radius.
        radius: f64,
    },
    /// The inside of a sphere is free space; particles are kept inside.
    Bowl {
        /// Centre.
        center: DVec3,
        /// Radius.
        radius: f64,
    },
    /// Terrain below a height grid.
    Heightfield(Heightfield),
    /// A triangle mesh; the side its normals point away from is solid.
    Mesh(TriangleMesh),
}

/// One `[[terrain]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Terrain {
    /// Geometry.
    pub shape: TerrainShape,
    /// Coefficient of restitution k_r in [0, 1].
    pub restitution: f64,
    /// Friction coefficient (μ for Coulomb, k_f for viscous).
    pub friction: f64,
    /// Friction law.
    pub friction_model: FrictionModel,
}

/// A complete, validated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Time stepping and global forces.
    pub simulation: Simulation,
    /// The bodies, in file order; their particles are numbered in this order.
    pub bodies: Vec<Body>,
    /// The terrain shapes, in file order.
    pub terrain: Vec<Terrain>,
}

/// Rotation matrix for `[x, y, z]` degrees applied about x first, then y, then z.
pub fn rotation_from_degrees(deg: DVec3) -> DQuat {
    DQuat::from_euler(
        EulerRot::ZYX,
        deg.z.to_radians(),
        deg.y.to_radians(),
        deg.x.to_radians(),
    )
}

impl Scene {
    /// Reads, parses and validates a scene file. Mesh paths are relative to the file.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|cause| SceneError::Io {
            path: path.to_owned(),
            cause,
        })?;
        Scene::from_toml(&text, path)
    }

    /// Parses and validates scene text; `origin` names it in messages and anchors mesh paths.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Scene, SceneError> {
        let file: SceneFile =
            toml::from_str(text).map_err(|e| crate::error::from_toml(origin, text, &e))?;
        let base = origin.parent().unwrap_or(Path::new("."));
        let scene = convert::scene(file, base).map_err(|e| e.locate(origin, text))?;
        scene.validate().map_err(|e| e.locate(origin, text))?;
        Ok(scene)
    }

    /// Total particle count (saturating).
    pub fn particle_count(&self) -> u64 {
        self.bodies
            .iter()
            .fold(0u64, |n, b| n.saturating_add(b.particle_count()))
    }

    /// Springs of each family over all bodies.
    pub fn spring_counts(&self) -> SpringCounts {
        self.bodies
            .iter()
            .fold(SpringCounts::default(), |n, b| n + b.spring_counts())
    }

    /// Total mass, kg.
    pub fn total_mass(&self) -> f64 {
        self.bodies.iter().map(Body::mass).sum()
    }

    /// Checks every value; the error names the key the file would use.
    pub fn validate(&self) -> Result<(), Invalid> {
        crate::validate::scene(self)
    }
}
