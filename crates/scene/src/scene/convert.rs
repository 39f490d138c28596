//! File structs → scene structs: each body and terrain kind gets exactly its keys (one table
//! per table kind says which), meshes are loaded and mesh bodies voxelised. The values are
//! checked afterwards, by `validate`, except what the voxelisation needs first.

use std::path::Path;

use glam::DVec3;

use super::{
    Body, BodyContact, BodyShape, Cuboid, ExplicitSpring, Heightfield, MeshBody, MeshMass,
    ParticleSet, Scene, Simulation, SpringParams, Terrain, TerrainShape, TriangleMesh,
};
use crate::error::{Invalid, KeyPath};
use crate::format::{BodyFile, BodyKind, OneOrThree, SceneFile, TerrainFile, TerrainKind};
use crate::voxel::{LatticeSize, VoxelKey, Voxels};

/// A key that only some kinds of a table take: its name, those kinds, and whether a table
/// has it.
type KindKey<F, K> = (&'static str, &'static [K], fn(&F) -> bool);

/// The `[[body]]` keys and the body kinds that take them, in the order a body's first key of
/// another kind is reported. `name`, `kind`, `pinned`, `contact_radius` and `self_contact`
/// are every kind's.
const BODY_KEYS: [KindKey<BodyFile, BodyKind>; 19] = {
    use BodyKind::{Cuboid as C, Mesh as M, Particles as P};
    [
        ("size", &[C], |b| b.size.is_some()),
        ("resolution", &[C, M], |b| b.resolution.is_some()),
        ("center", &[C, M], |b| b.center.is_some()),
        ("rotation", &[C, M], |b| b.rotation.is_some()),
        ("velocity", &[C, M], |b| b.velocity.is_some()),
        ("mass", &[C, M], |b| b.mass.is_some()),
        ("structural", &[C, M], |b| b.structural.is_some()),
        ("shear", &[C, M], |b| b.shear.is_some()),
        ("bending", &[C, M], |b| b.bending.is_some()),
        ("positions", &[P], |b| b.positions.is_some()),
        ("velocities", &[P], |b| b.velocities.is_some()),
        ("masses", &[P], |b| b.masses.is_some()),
        ("springs", &[P], |b| b.springs.is_some()),
        ("file", &[M], |b| b.file.is_some()),
        ("path", &[M], |b| b.path.is_some()),
        ("cell", &[M], |b| b.cell.is_some()),
        ("scale", &[M], |b| b.scale.is_some()),
        ("density", &[M], |b| b.density.is_some()),
        ("surface", &[M], |b| b.surface.is_some()),
    ]
};

/// The `[[terrain]]` keys and the terrain kinds that take them, in the order a shape's first
/// key of another kind is reported. `kind`, `restitution`, `friction` and `friction_model` are
/// every kind's.
const TERRAIN_KEYS: [KindKey<TerrainFile, TerrainKind>; 11] = {
    use TerrainKind::{Bowl, Box, Heightfield as H, Mesh, Plane, Sphere};
    [
        ("point", &[Plane], |t| t.point.is_some()),
        ("normal", &[Plane], |t| t.normal.is_some()),
        ("center", &[Box, Sphere, Bowl], |t| t.center.is_some()),
        ("half_extents", &[Box], |t| t.half_extents.is_some()),
        ("rotation", &[Box], |t| t.rotation.is_some()),
        ("radius", &[Sphere, Bowl], |t| t.radius.is_some()),
        ("heights", &[H], |t| t.heights.is_some()),
        ("cell_size", &[H], |t| t.cell_size.is_some()),
        ("origin", &[H], |t| t.origin.is_some()),
        ("path", &[Mesh], |t| t.path.is_some()),
        ("file", &[Mesh], |t| t.file.is_some()),
    ]
};

/// The scene of a parsed file; mesh paths are relative to `base`.
pub(super) fn scene(file: SceneFile, base: &Path) -> Result<Scene, Invalid> {
    let s = file.simulation;
    let simulation = Simulation {
        integrator: s.integrator,
        dt: s.dt,
        duration: s.duration,
        frame_rate: s.frame_rate,
        gravity: s.gravity.into(),
        drag: s.drag,
        contact_distance: s.contact_distance,
        body_contact: BodyContact {
            restitution: s.body_restitution,
            friction: s.body_friction,
            friction_model: s.body_friction_model,
        },
        preconditioner: s.preconditioner,
        cg_tolerance: s.cg_tolerance,
    };
    let bodies = file
        .bodies
        .into_iter()
        .enumerate()
        .map(|(i, b)| body(b, i, base, &KeyPath::root().key("body").index(i)))
        .collect::<Result<_, _>>()?;
    let terrain = file
        .terrain
        .into_iter()
        .enumerate()
        .map(|(i, t)| terrain(t, base, &KeyPath::root().key("terrain").index(i)))
        .collect::<Result<_, _>>()?;
    Ok(Scene {
        simulation,
        bodies,
        terrain,
    })
}

/// Refuses the first key of `table` that `file` has and its kind (`kind`, called `name`) does
/// not take.
fn forbid<F, K: PartialEq>(
    at: &KeyPath,
    name: &str,
    kind: K,
    file: &F,
    table: &[KindKey<F, K>],
) -> Result<(), Invalid> {
    match (table.iter()).find(|(_, kinds, present)| !kinds.contains(&kind) && present(file)) {
        Some((key, ..)) => Err(Invalid::new(
            at.key(key),
            format!("`{key}` is not a key of a `{name}`"),
        )),
        None => Ok(()),
    }
}

fn require<T>(at: &KeyPath, kind: &str, key: &str, v: Option<T>) -> Result<T, Invalid> {
    v.ok_or_else(|| Invalid::new(at.clone(), format!("a `{kind}` needs the key `{key}`")))
}

fn index(at: KeyPath, i: u64) -> Result<u32, Invalid> {
    u32::try_from(i).map_err(|_| Invalid::new(at, format!("index {i} is out of range")))
}

/// Body `i`: the keys every kind takes here, its kind's in [`cuboid`], [`particles`] or
/// [`mesh_body`].
fn body(mut b: BodyFile, i: usize, base: &Path, at: &KeyPath) -> Result<Body, Invalid> {
    let name = b.name.take().unwrap_or_else(|| format!("body{i}"));
    let pinned = b
        .pinned
        .iter()
        .enumerate()
        .map(|(j, &p)| index(at.key("pinned").index(j), p))
        .collect::<Result<_, _>>()?;
    let kind = match b.kind {
        BodyKind::Cuboid => "cuboid body",
        BodyKind::Particles => "particles body",
        BodyKind::Mesh => "mesh body",
    };
    forbid(at, kind, b.kind, &b, &BODY_KEYS)?;
    let (contact_radius, self_contact) = (b.contact_radius, b.self_contact);
    let shape = match b.kind {
        BodyKind::Cuboid => BodyShape::Cuboid(cuboid(&b, kind, at)?),
        BodyKind::Particles => BodyShape::Particles(particles(b, kind, at)?),
        BodyKind::Mesh => BodyShape::Mesh(mesh_body(&b, kind, base, at)?),
    };
    Ok(Body {
        name,
        shape,
        pinned,
        contact_radius,
        self_contact,
    })
}

/// What cuboids and mesh bodies read alike: where the lattice sits and how it moves, and its
/// spring families (`None`: left out).
struct LatticeKeys {
    center: DVec3,
    rotation: DVec3,
    velocity: DVec3,
    structural: Option<SpringParams>,
    shear: Option<SpringParams>,
    bending: Option<SpringParams>,
}

impl LatticeKeys {
    fn of(b: &BodyFile) -> LatticeKeys {
        let spring = |s: Option<crate::format::SpringFile>| {
            s.map(|s| SpringParams {
                stiffness: s.stiffness,
                damping: s.damping,
            })
        };
        LatticeKeys {
            center: b.center.unwrap_or_default().into(),
            rotation: b.rotation.unwrap_or_default().into(),
            velocity: b.velocity.unwrap_or_default().into(),
            structural: spring(b.structural),
            shear: spring(b.shear),
            bending: spring(b.bending),
        }
    }
}

fn cuboid(b: &BodyFile, k: &str, at: &KeyPath) -> Result<Cuboid, Invalid> {
    let res = match require(at, k, "resolution", b.resolution)? {
        OneOrThree::Three(r) => r,
        OneOrThree::One(_) => {
            return Err(Invalid::new(
                at.key("resolution"),
                "a cuboid's resolution is three particle counts, [nx, ny, nz]",
            ));
        }
    };
    let mut resolution = [0u32; 3];
    for (axis, r) in res.iter().enumerate() {
        resolution[axis] = u32::try_from(*r).map_err(|_| {
            Invalid::new(
                at.key("resolution").index(axis),
                format!("resolution {r} is far too large"),
            )
        })?;
    }
    let size = require(at, k, "size", b.size)?.into();
    let mass = require(at, k, "mass", b.mass)?;
    let l = LatticeKeys::of(b);
    Ok(Cuboid {
        size,
        resolution,
        center: l.center,
        rotation: l.rotation,
        velocity: l.velocity,
        mass,
        structural: l.structural,
        shear: l.shear,
        bending: l.bending,
    })
}

fn particles(b: BodyFile, k: &str, at: &KeyPath) -> Result<ParticleSet, Invalid> {
    let positions: Vec<DVec3> = require(at, k, "positions", b.positions)?
        .into_iter()
        .map(DVec3::from)
        .collect();
    let velocities = match b.velocities {
        Some(v) => v.into_iter().map(DVec3::from).collect(),
        None => vec![DVec3::ZERO; positions.len()],
    };
    let springs = b
        .springs
        .unwrap_or_default()
        .iter()
        .enumerate()
        .map(|(j, s)| {
            let sp = at.key("springs").index(j);
            Ok(ExplicitSpring {
                a: index(sp.key("a"), s.a)?,
                b: index(sp.key("b"), s.b)?,
                stiffness: s.stiffness,
                damping: s.damping,
                rest: s.rest,
            })
        })
        .collect::<Result<_, Invalid>>()?;
    Ok(ParticleSet {
        positions,
        velocities,
        masses: require(at, k, "masses", b.masses)?,
        springs,
    })
}

/// Which of two keys that exclude each other a table has.
enum Either<A, B> {
    First(A),
    Second(B),
}

/// The value of whichever of the keys `first` and `second` the table at `at` has; `needs`
/// says what is missing when it has neither.
fn one_of<A, B>(
    at: &KeyPath,
    (first, a): (&str, Option<A>),
    (second, b): (&str, Option<B>),
    needs: &str,
) -> Result<Either<A, B>, Invalid> {
    match (a, b) {
        (Some(_), Some(_)) => Err(Invalid::new(
            at.key(second),
            format!("give either `{first}` or `{second}`, not both"),
        )),
        (None, None) => Err(Invalid::new(at.clone(), needs)),
        (Some(a), None) => Ok(Either::First(a)),
        (None, Some(b)) => Ok(Either::Second(b)),
    }
}

/// A `mesh` body: its file loaded and voxelised (the lattice's values are checked here, before
/// the voxelisation needs them; the rest in `validate`).
fn mesh_body(b: &BodyFile, k: &str, base: &Path, at: &KeyPath) -> Result<MeshBody, Invalid> {
    let needs_size = "a `mesh body` needs the key `cell` (the lattice spacing, metres) or \
                      `resolution` (cells along the longest side)";
    let size = match one_of(
        at,
        ("cell", b.cell),
        ("resolution", b.resolution),
        needs_size,
    )? {
        Either::First(h) => {
            crate::validate::positive(at.key("cell"), h)?;
            LatticeSize::Cell(h)
        }
        Either::Second(OneOrThree::One(r)) => {
            if !(1..=u32::MAX as u64).contains(&r) {
                return Err(Invalid::new(
                    at.key("resolution"),
                    format!("must be a number of cells from 1 to {}, not {r}", u32::MAX),
                ));
            }
            LatticeSize::Resolution(r as u32)
        }
        Either::Second(OneOrThree::Three(_)) => {
            return Err(Invalid::new(
                at.key("resolution"),
                "a mesh body's resolution is one number: cells along the longest side",
            ));
        }
    };
    let needs_mass = "a `mesh body` needs the key `mass` (kg) or `density` (kg/m³)";
    let mass = match one_of(at, ("mass", b.mass), ("density", b.density), needs_mass)? {
        Either::First(m) => MeshMass::Mass(m),
        Either::Second(rho) => MeshMass::Density(rho),
    };
    let scale = DVec3::from(b.scale.unwrap_or(OneOrThree::One(1.0)).three());
    for axis in 0..3 {
        let key = match b.scale {
            Some(OneOrThree::Three(_)) => at.key("scale").index(axis),
            _ => at.key("scale"),
        };
        crate::validate::positive(key, scale[axis])?;
    }
    let (file_key, mesh) = obj_file(at, k, b.file.clone(), b.path.clone(), base)?;
    let voxels = Voxels::new(mesh, scale, size).map_err(|e| {
        let key = match (e.key, size) {
            (VoxelKey::File, _) => file_key,
            (VoxelKey::Size, LatticeSize::Cell(_)) => "cell",
            (VoxelKey::Size, LatticeSize::Resolution(_)) => "resolution",
        };
        Invalid::new(at.key(key), e.message)
    })?;
    let l = LatticeKeys::of(b);
    Ok(MeshBody {
        voxels: std::sync::Arc::new(voxels),
        center: l.center,
        rotation: l.rotation,
        velocity: l.velocity,
        mass,
        structural: l.structural,
        shear: l.shear,
        bending: l.bending,
        surface: b.surface.unwrap_or_default(),
    })
}

/// The mesh of the OBJ file that `file` or `path` names (the two are one key, under the name
/// each of a mesh body and a mesh terrain had first), checked as `validate` checks it but
/// blaming the name it was given by, and that name, for the errors about it.
fn obj_file(
    at: &KeyPath,
    kind: &str,
    file: Option<String>,
    path: Option<String>,
    base: &Path,
) -> Result<(&'static str, TriangleMesh), Invalid> {
    let needs = format!("a `{kind}` needs the key `file` (or `path`): its OBJ file");
    let (key, rel) = match one_of(at, ("file", file), ("path", path), &needs)? {
        Either::First(rel) => ("file", rel),
        Either::Second(rel) => ("path", rel),
    };
    let mesh = crate::mesh::load_obj(&base.join(&rel))
        .and_then(|mesh| crate::voxel::check_mesh(&mesh).map(|()| mesh))
        .map_err(|m| Invalid::new(at.key(key), m))?;
    Ok((key, mesh))
}

fn terrain(t: TerrainFile, base: &Path, at: &KeyPath) -> Result<Terrain, Invalid> {
    let k = match t.kind {
        TerrainKind::Plane => "plane",
        TerrainKind::Box => "box",
        TerrainKind::Sphere => "sphere",
        TerrainKind::Bowl => "bowl",
        TerrainKind::Heightfield => "heightfield",
        TerrainKind::Mesh => "mesh",
    };
    forbid(at, k, t.kind, &t, &TERRAIN_KEYS)?;
    let shape = match t.kind {
        TerrainKind::Plane => TerrainShape::Plane {
            point: t.point.unwrap_or_default().into(),
            normal: require(at, k, "normal", t.normal)?.into(),
        },
        TerrainKind::Box => TerrainShape::Box {
            center: t.center.unwrap_or_default().into(),
            half_extents: require(at, k, "half_extents", t.half_extents)?.into(),
            rotation: t.rotation.unwrap_or_default().into(),
        },
        TerrainKind::Sphere | TerrainKind::Bowl => {
            let center = t.center.unwrap_or_default().into();
            let radius = require(at, k, "radius", t.radius)?;
            if t.kind == TerrainKind::Sphere {
                TerrainShape::Sphere { center, radius }
            } else {
                TerrainShape::Bowl { center, radius }
            }
        }
        TerrainKind::Heightfield => TerrainShape::Heightfield(Heightfield {
            heights: require(at, k, "heights", t.heights)?,
            cell_size: require(at, k, "cell_size", t.cell_size)?,
            origin: t.origin.unwrap_or_default().into(),
        }),
        TerrainKind::Mesh => TerrainShape::Mesh(obj_file(at, k, t.file, t.path, base)?.1),
    };
    Ok(Terrain {
        shape,
        restitution: t.restitution,
        friction: t.friction,
        friction_model: t.friction_model,
    })
}
