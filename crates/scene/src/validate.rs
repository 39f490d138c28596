//! Value checks on a [`Scene`]: every failure names the key a scene file would use.
//!
//! A scene that passes can be built and stepped without any further check: masses are positive,
//! every index names a particle, no spring has zero length, every number is finite, and the
//! whole scene fits in the memory this machine has (refused before anything is allocated).

use glam::DVec3;

use crate::error::{Invalid, KeyPath, Num};
use crate::model;
use crate::scene::{BodyShape, MeshBody, MeshMass, Scene, SpringParams, TerrainShape};

type Check = Result<(), Invalid>;

fn finite(at: KeyPath, x: f64) -> Check {
    if x.is_finite() {
        Ok(())
    } else {
        Err(Invalid::new(
            at,
            format!("must be a finite number, not {}", Num(x)),
        ))
    }
}

fn finite3(at: KeyPath, v: DVec3) -> Check {
    for (i, x) in v.to_array().into_iter().enumerate() {
        finite(at.index(i), x)?;
    }
    Ok(())
}

pub(crate) fn positive(at: KeyPath, x: f64) -> Check {
    finite(at.clone(), x)?;
    if x > 0.0 {
        Ok(())
    } else {
        Err(Invalid::new(
            at,
            format!("must be greater than zero, not {}", Num(x)),
        ))
    }
}

/// A size of terrain that its distance queries divide by and measure against coordinates
/// near `center`: positive, with a finite reciprocal (not subnormal), and more than the
/// rounding of those coordinates (four units in the last place of the largest), below which
/// every point near it rounds onto or off the surface alike.
fn resolvable(at: KeyPath, x: f64, center: DVec3) -> Check {
    positive(at.clone(), x)?;
    let least = f64::MIN_POSITIVE.max(4.0 * f64::EPSILON * center.abs().max_element());
    if x >= least {
        Ok(())
    } else {
        Err(Invalid::new(
            at,
            format!(
                "{} m is below what f64 resolves here: at least {} m (a finite reciprocal, and \
                 more than the rounding of the centre's coordinates)",
                Num(x),
                Num(least)
            ),
        ))
    }
}

/// The kept cells hold every point the mesh winds around, so a closed mesh wound once encloses
/// at most their volume; more means shells nested or overlapping, counted twice by the volume
/// that a density would weigh.
fn enclosed_is_held(at: KeyPath, m: &MeshBody) -> Check {
    let lattice = m.voxels.volume();
    match m.voxels.enclosed_volume() {
        Some(v) if v > lattice * (1.0 + 1e-9) => Err(Invalid::new(
            at,
            format!(
                "the mesh encloses {} m³, more than the {} m³ of the cells that hold it: parts \
                 of it are wound more than once (nested or overlapping shells); give `mass` \
                 instead",
                Num(v),
                Num(lattice)
            ),
        )),
        _ => Ok(()),
    }
}

fn non_negative(at: KeyPath, x: f64) -> Check {
    finite(at.clone(), x)?;
    if x >= 0.0 {
        Ok(())
    } else {
        Err(Invalid::new(
            at,
            format!("must not be negative, not {}", Num(x)),
        ))
    }
}

fn unit_interval(at: KeyPath, x: f64) -> Check {
    finite(at.clone(), x)?;
    if (0.0..=1.0).contains(&x) {
        Ok(())
    } else {
        Err(Invalid::new(
            at,
            format!("must lie in [0, 1], not {}", Num(x)),
        ))
    }
}

fn spring_params(at: KeyPath, p: &SpringParams) -> Check {
    non_negative(at.key("stiffness"), p.stiffness)?;
    non_negative(at.key("damping"), p.damping)
}

pub(crate) fn scene(scene: &Scene) -> Check {
    let sim = &scene.simulation;
    let s = KeyPath::root().key("simulation");
    positive(s.key("dt"), sim.dt)?;
    non_negative(s.key("duration"), sim.duration)?;
    positive(s.key("frame_rate"), sim.frame_rate)?;
    finite3(s.key("gravity"), sim.gravity)?;
    non_negative(s.key("drag"), sim.drag)?;
    non_negative(s.key("contact_distance"), sim.contact_distance)?;
    unit_interval(s.key("body_restitution"), sim.body_contact.restitution)?;
    non_negative(s.key("body_friction"), sim.body_contact.friction)?;
    positive(s.key("cg_tolerance"), sim.cg_tolerance)?;
    if sim.cg_tolerance >= 1.0 {
        return Err(Invalid::new(
            s.key("cg_tolerance"),
            format!(
                "must be below 1 (a fraction of the right-hand side's residual), not {}",
                Num(sim.cg_tolerance)
            ),
        ));
    }
    if sim.duration / sim.dt > 1e15 {
        return Err(Invalid::new(
            s.key("duration"),
            format!(
                "{} / dt = {:e} steps is more than can be run",
                Num(sim.duration),
                sim.duration / sim.dt
            ),
        ));
    }
    if sim.frame_rate * sim.dt > 1.0 + 1e-9 {
        return Err(Invalid::new(
            s.key("frame_rate"),
            format!(
                "{} frames/s asks for more than one frame per step of dt = {} s (at most {})",
                Num(sim.frame_rate),
                Num(sim.dt),
                Num(1.0 / sim.dt)
            ),
        ));
    }

    let mut names = std::collections::HashMap::new();
    for (i, body) in scene.bodies.iter().enumerate() {
        let at = KeyPath::root().key("body").index(i);
        if body.name.is_empty() {
            return Err(Invalid::new(at.key("name"), "must not be empty"));
        }
        if let Some(j) = names.insert(body.name.as_str(), i) {
            return Err(Invalid::new(
                at.key("name"),
                format!("`{}` is already the name of body {j}", body.name),
            ));
        }
        body_values(&at, &body.shape)?;
        if let Some(r) = body.contact_radius {
            non_negative(at.key("contact_radius"), r)?;
            // Beyond one spacing, particles three cells apart would touch at rest: a body would
            // be in self-contact with its own structure, and every particle would have dozens
            // of contact candidates.
            if let BodyShape::Mesh(m) = &body.shape
                && r > m.voxels.cell()
            {
                return Err(Invalid::new(
                    at.key("contact_radius"),
                    format!(
                        "{} m is more than the mesh body's cell, {} m (the default is half of \
                         it)",
                        Num(r),
                        Num(m.voxels.cell())
                    ),
                ));
            }
            if let BodyShape::Cuboid(c) = &body.shape
                && r > c.smallest_spacing()
            {
                return Err(Invalid::new(
                    at.key("contact_radius"),
                    format!(
                        "{} m is more than the cuboid's smallest lattice spacing, {} m (the \
                         default is half of it)",
                        Num(r),
                        Num(c.smallest_spacing())
                    ),
                ));
            }
        }
        let count = body.particle_count();
        for (j, &p) in body.pinned.iter().enumerate() {
            if p as u64 >= count {
                return Err(Invalid::new(
                    at.key("pinned").index(j),
                    format!("particle {p} does not exist: the body has {count} particles"),
                ));
            }
        }
    }

    // Size limits before anything is allocated: indices are u32 (springs are stored as 2s+side in
    // the adjacency), and the estimated footprint must fit in memory. The blame goes to the
    // largest body's size key.
    let particles = scene.particle_count();
    let springs = scene.spring_counts().total();
    let blame = || {
        let (i, body) = scene
            .bodies
            .iter()
            .enumerate()
            .max_by_key(|(_, b)| {
                model::estimated_bytes(b.particle_count(), b.spring_counts().total())
            })
            .expect("only called when the bodies hold too many particles");
        let key = match &body.shape {
            BodyShape::Cuboid(_) => "resolution",
            BodyShape::Particles(_) => "positions",
            BodyShape::Mesh(m) => match m.voxels.size() {
                crate::voxel::LatticeSize::Cell(_) => "cell",
                crate::voxel::LatticeSize::Resolution(_) => "resolution",
            },
        };
        KeyPath::root().key("body").index(i).key(key)
    };
    if particles > model::MAX_PARTICLES {
        return Err(Invalid::new(
            blame(),
            format!(
                "{particles} particles is more than the {} supported",
                model::MAX_PARTICLES
            ),
        ));
    }
    if springs > model::MAX_SPRINGS {
        return Err(Invalid::new(
            blame(),
            format!(
                "{springs} springs is more than the {} supported",
                model::MAX_SPRINGS
            ),
        ));
    }
    let need = model::estimated_scene_bytes(scene);
    if let Some((have, what)) = crate::memory::available_memory().filter(|&(have, _)| need > have) {
        return Err(Invalid::new(
            blame(),
            format!(
                "the scene needs about {:.1} GiB ({particles} particles, {springs} springs) and {:.1} GiB are {what}",
                need as f64 / (1u64 << 30) as f64,
                have as f64 / (1u64 << 30) as f64
            ),
        ));
    }

    for (i, t) in scene.terrain.iter().enumerate() {
        let at = KeyPath::root().key("terrain").index(i);
        unit_interval(at.key("restitution"), t.restitution)?;
        non_negative(at.key("friction"), t.friction)?;
        terrain_values(&at, &t.shape)?;
    }
    crate::initial_energy::check(scene)?;
    // Last, so that the values of a scene under construction (terrain alone) are checked too.
    if scene.bodies.is_empty() {
        return Err(Invalid::new(
            KeyPath::root(),
            "the scene has no [[body]]: nothing to simulate",
        ));
    }
    Ok(())
}

fn body_values(at: &KeyPath, shape: &BodyShape) -> Check {
    match shape {
        BodyShape::Cuboid(c) => {
            for axis in 0..3 {
                positive(at.key("size").index(axis), c.size[axis])?;
                if c.resolution[axis] < 2 {
                    return Err(Invalid::new(
                        at.key("resolution").index(axis),
                        format!(
                            "must be at least 2 particles per axis, not {}",
                            c.resolution[axis]
                        ),
                    ));
                }
            }
            finite3(at.key("center"), c.center)?;
            finite3(at.key("rotation"), c.rotation)?;
            finite3(at.key("velocity"), c.velocity)?;
            positive(at.key("mass"), c.mass)?;
            for (key, p) in [
                ("structural", &c.structural),
                ("shear", &c.shear),
                ("bending", &c.bending),
            ] {
                if let Some(p) = p {
                    spring_params(at.key(key), p)?;
                }
            }
        }
        BodyShape::Mesh(m) => {
            finite3(at.key("center"), m.center)?;
            finite3(at.key("rotation"), m.rotation)?;
            finite3(at.key("velocity"), m.velocity)?;
            match m.mass {
                MeshMass::Mass(mass) => positive(at.key("mass"), mass)?,
                MeshMass::Density(rho) => {
                    positive(at.key("density"), rho)?;
                    enclosed_is_held(at.key("density"), m)?;
                    // A density times a tiny volume can still underflow to no mass at all.
                    positive(at.key("density"), m.total_mass())?;
                }
            }
            for (key, p) in [
                ("structural", &m.structural),
                ("shear", &m.shear),
                ("bending", &m.bending),
            ] {
                if let Some(p) = p {
                    spring_params(at.key(key), p)?;
                }
            }
        }
        BodyShape::Particles(p) => {
            if p.positions.is_empty() {
                return Err(Invalid::new(
                    at.key("positions"),
                    "must hold at least one particle",
                ));
            }
            let n = p.positions.len();
            for (key, len) in [
                ("velocities", p.velocities.len()),
                ("masses", p.masses.len()),
            ] {
                if len != n {
                    return Err(Invalid::new(
                        at.key(key),
                        format!("has {len} entries but `positions` has {n}"),
                    ));
                }
            }
            for (i, x) in p.positions.iter().enumerate() {
                finite3(at.key("positions").index(i), *x)?;
            }
            for (i, v) in p.velocities.iter().enumerate() {
                finite3(at.key("velocities").index(i), *v)?;
            }
            for (i, &m) in p.masses.iter().enumerate() {
                positive(at.key("masses").index(i), m)?;
            }
            for (i, s) in p.springs.iter().enumerate() {
                let sp = at.key("springs").index(i);
                for (key, idx) in [("a", s.a), ("b", s.b)] {
                    if idx as usize >= n {
                        return Err(Invalid::new(
                            sp.key(key),
                            format!("particle {idx} does not exist: the body has {n} particles"),
                        ));
                    }
                }
                if s.a == s.b {
                    return Err(Invalid::new(
                        sp.key("b"),
                        format!("a spring joins particle {} to itself", s.a),
                    ));
                }
                non_negative(sp.key("stiffness"), s.stiffness)?;
                non_negative(sp.key("damping"), s.damping)?;
                let length = p.positions[s.a as usize].distance(p.positions[s.b as usize]);
                if length == 0.0 {
                    return Err(Invalid::new(
                        sp.clone(),
                        format!("zero-length spring: particles {} and {} coincide", s.a, s.b),
                    ));
                }
                if let Some(rest) = s.rest {
                    positive(sp.key("rest"), rest)?;
                }
            }
        }
    }
    Ok(())
}

fn terrain_values(at: &KeyPath, shape: &TerrainShape) -> Check {
    match shape {
        TerrainShape::Plane { point, normal } => {
            finite3(at.key("point"), *point)?;
            finite3(at.key("normal"), *normal)?;
            if normal.length_squared() == 0.0 {
                return Err(Invalid::new(
                    at.key("normal"),
                    "must not be the zero vector",
                ));
            }
        }
        TerrainShape::Box {
            center,
            half_extents,
            rotation,
        } => {
            finite3(at.key("center"), *center)?;
            finite3(at.key("rotation"), *rotation)?;
            for axis in 0..3 {
                resolvable(
                    at.key("half_extents").index(axis),
                    half_extents[axis],
                    *center,
                )?;
            }
        }
        TerrainShape::Sphere { center, radius } | TerrainShape::Bowl { center, radius } => {
            finite3(at.key("center"), *center)?;
            resolvable(at.key("radius"), *radius, *center)?;
        }
        TerrainShape::Heightfield(h) => {
            let rows = h.heights.len();
            let cols = h.heights.first().map_or(0, Vec::len);
            if rows < 2 || cols < 2 {
                return Err(Invalid::new(
                    at.key("heights"),
                    format!("must be at least 2×2, not {rows}×{cols}"),
                ));
            }
            for (r, row) in h.heights.iter().enumerate() {
                if row.len() != cols {
                    return Err(Invalid::new(
                        at.key("heights").index(r),
                        format!("has {} heights but row 0 has {cols}", row.len()),
                    ));
                }
                for (c, &y) in row.iter().enumerate() {
                    finite(at.key("heights").index(r).index(c), y)?;
                }
            }
            finite3(at.key("origin"), h.origin)?;
            resolvable(at.key("cell_size").index(0), h.cell_size[0], h.origin)?;
            resolvable(at.key("cell_size").index(1), h.cell_size[1], h.origin)?;
        }
        TerrainShape::Mesh(m) => {
            crate::voxel::check_mesh(m).map_err(|e| Invalid::new(at.key("path"), e))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::Scene;

    /// A cuboid body's keys but its mass.
    const CUBE: &str =
        "[[body]]\nkind = \"cuboid\"\nsize = [1.0, 1.0, 1.0]\nresolution = [2, 2, 2]\n";

    /// The located error of a cube of 1 kg with `rest` (TOML) after its keys, as `key: message`.
    fn error(rest: &str) -> String {
        error_of("", &format!("{CUBE}mass = 1.0\n{rest}"))
    }

    /// The located error of the scene of `[simulation]` with `sim` and the tables of `rest`.
    fn error_of(sim: &str, rest: &str) -> String {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("flat.obj"),
            "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 0 0\nf 1 2 3\nf 1 4 2\n",
        )
        .unwrap();
        let text = format!("[simulation]\ndt = 0.001\nduration = 0.01\n{sim}\n{rest}");
        let e = Scene::from_toml(&text, &dir.path().join("s.toml")).unwrap_err();
        let d = e.diagnostic().unwrap();
        format!("{}: {}", d.key, d.message)
    }

    /// A mesh whose every triangle is degenerate (corners on a line, or two coinciding) has no
    /// surface to touch; a bowl of a subnormal radius has none f64 can resolve.
    #[test]
    fn terrain_without_a_resolvable_surface_is_refused() {
        let e = error("[[terrain]]\nkind = \"mesh\"\npath = \"flat.obj\"\n");
        assert!(e.starts_with("terrain[0].path: "), "{e}");
        assert!(
            e.ends_with(
                "flat.obj: every triangle has zero area (its corners on one line), or one too \
                 small or too large for f64: the mesh has no surface"
            ),
            "{e}"
        );
        let why = "(a finite reciprocal, and more than the rounding of the centre's coordinates)";
        assert_eq!(
            error("[[terrain]]\nkind = \"bowl\"\nradius = 5e-324\n"),
            format!(
                "terrain[0].radius: 5e-324 m is below what f64 resolves here: at least \
                 2.2250738585072014e-308 m {why}"
            )
        );
        // Coordinates near 1e12 m are rounded to 1.2e-4 m.
        assert_eq!(
            error("[[terrain]]\nkind = \"sphere\"\ncenter = [1e12, 0.0, 0.0]\nradius = 1e-4\n"),
            format!(
                "terrain[0].radius: 0.0001 m is below what f64 resolves here: at least \
                 0.0008881784197001252 m {why}"
            )
        );
        assert_eq!(
            error("[[terrain]]\nkind = \"box\"\nhalf_extents = [1.0, 1e-310, 1.0]\n"),
            format!(
                "terrain[0].half_extents[1]: 1e-310 m is below what f64 resolves here: at least \
                 2.2250738585072014e-308 m {why}"
            )
        );
    }

    /// Implicit Euler's CG tolerance is a fraction in (0, 1); 1e-8 when the scene says none.
    #[test]
    fn the_cg_tolerance_is_a_fraction_below_one() {
        let rest = format!("{CUBE}mass = 1.0\n");
        for (value, why) in [
            ("0.0", "must be greater than zero, not 0"),
            ("-1e-9", "must be greater than zero, not -1e-9"),
            ("inf", "must be a finite number, not inf"),
            (
                "1.0",
                "must be below 1 (a fraction of the right-hand side's residual), not 1",
            ),
        ] {
            assert_eq!(
                error_of(&format!("cg_tolerance = {value}"), &rest),
                format!("simulation.cg_tolerance: {why}")
            );
        }
        let text = format!("[simulation]\ndt = 0.001\nduration = 0.01\n{rest}");
        let scene = Scene::from_toml(&text, "s.toml".as_ref()).unwrap();
        assert_eq!(scene.simulation.cg_tolerance, 1e-8);
    }

    /// Very large and very small values are written in exponent form, not as 300 digits.
    #[test]
    fn values_in_messages_are_short() {
        assert_eq!(
            error("contact_radius = 1e300\n"),
            "body[0].contact_radius: 1e300 m is more than the cuboid's smallest lattice spacing, \
             1 m (the default is half of it)"
        );
        assert_eq!(
            error(
                "[[terrain]]\nkind = \"plane\"\nnormal = [0.0, 1.0, 0.0]\nfriction = -2.5e-300\n"
            ),
            "terrain[0].friction: must not be negative, not -2.5e-300"
        );
    }

    /// A body whose initial energy overflows f64 is refused naming the body and, where one
    /// value alone overflows it, that value; bodies whose energies add up beyond f64's range
    /// are refused naming them all.
    #[test]
    fn an_initial_energy_beyond_f64_names_the_body_and_the_value() {
        assert_eq!(
            error("velocity = [1e200, 0.0, 0.0]\n"),
            "body[0].velocity: the initial kinetic energy is not a finite number: the speed \
             1e200 m/s squared is beyond f64's range"
        );
        assert_eq!(
            error_of(
                "",
                &format!("{CUBE}velocity = [1e150, 0.0, 0.0]\nmass = 1e300\n")
            ),
            "body[0]: the initial kinetic energy ½·m·|v|² is not a finite number: 1e300 kg at \
             1e150 m/s is beyond f64's range"
        );
        assert_eq!(
            error_of(
                "",
                &format!("{CUBE}center = [0.0, 10.0, 0.0]\nmass = 1e308\n")
            ),
            "body[0]: the initial gravitational energy −m·g·x is not a finite number: 1e308 kg \
             at g·x = -98.10000000000001 J/kg is beyond f64's range"
        );
        assert_eq!(
            error_of(
                "gravity = [0.0, -1e300, 0.0]",
                &format!("{CUBE}center = [0.0, 1e10, 0.0]\nmass = 1.0\n")
            ),
            "simulation.gravity: the initial gravitational energy of body[0] is not a finite \
             number: |g| = 1e300 m/s² times its centre of mass, 10000000000 m from the origin, is \
             beyond f64's range"
        );
        assert_eq!(
            error("center = [0.0, 1e308, 0.0]\n"),
            "body[0].center: the initial gravitational energy is not a finite number: its \
             centre of mass, 1e308 m from the origin, times |g| = 9.81 m/s² is beyond f64's range"
        );
        let pair = "[[body]]\nkind = \"particles\"\npositions = [[0.0, 0.0, 0.0], [1e150, 0.0, 0.0]]\n\
                    masses = [1.0, 1.0]\nsprings = [{ a = 0, b = 1, stiffness = 1e300, rest = 1.0 }]\n";
        assert_eq!(
            error_of("gravity = [0.0, 0.0, 0.0]", pair),
            "body[0].springs[0]: the initial elastic energy is not a finite number: ½·k·(|d| − r)² \
             of a spring of stiffness 1e300 N/m stretched by 1e150 m is beyond f64's range"
        );
        assert_eq!(
            error_of("", &pair.replace("1e150", "1e200")),
            "body[0].springs[0]: the initial elastic energy is not a finite number: the \
             spring's length, 1e200 m, squared is beyond f64's range"
        );
        // Each 7.5e307 J: finite alone, not together.
        let fast = format!("{CUBE}velocity = [1e154, 0.0, 0.0]\nmass = 1.5\n");
        assert_eq!(
            error_of("gravity = [0.0, 0.0, 0.0]", &format!("{fast}{fast}{fast}")),
            "(document): the scene's initial energy is not a finite number: the bodies' \
             energies, 7.5e307 J (body[0]), 7.5e307 J (body[1]), 7.5e307 J (body[2]), add up \
             beyond f64's range"
        );
    }
}
