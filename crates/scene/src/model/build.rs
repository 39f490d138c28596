//! A [`Model`] and its initial [`State`] from a validated scene, body by body.

use glam::DVec3;

use super::{BodyRange, Contacts, Derived, Embedded, EmbeddedMesh, Lattice, Model, Springs, State};
use crate::format::SurfaceKind;
use crate::scene::{BodyShape, Scene};
use crate::topology;

impl Model {
    /// Builds the model and its initial state from a validated scene. Pinned particles start at
    /// rest whatever velocity the scene gives them: they never move.
    pub fn build(scene: &Scene) -> (Model, State) {
        let n = scene.particle_count() as usize;
        let mut state = State {
            x: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
        };
        let mut mass = Vec::with_capacity(n);
        let mut springs = Springs::default();
        let mut lattices = Vec::new();
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut pinned = vec![false; n];
        let mut surface = Vec::new();
        let mut embedded = Embedded::default();
        let mut contact = Contacts {
            laws: scene.simulation.body_contact,
            ..Contacts::default()
        };
        for (b, body) in scene.bodies.iter().enumerate() {
            let first = state.x.len() as u32;
            match &body.shape {
                BodyShape::Cuboid(c) => {
                    let [nx, ny, _] = c.resolution.map(|r| r as i32);
                    let cells = (0..body.particle_count() as i32)
                        .map(|p| Some([p % nx, p / nx % ny, p / (nx * ny)]));
                    contact.lattice.extend(cells);
                    let x = topology::cuboid_positions(c);
                    let m = c.mass / x.len() as f64;
                    state.v.extend(std::iter::repeat_n(c.velocity, x.len()));
                    mass.extend(std::iter::repeat_n(m, x.len()));
                    let lattice = Lattice::new(
                        b as u32,
                        first,
                        c.resolution,
                        topology::cuboid_spacing(c),
                        [c.structural, c.shear, c.bending],
                    );
                    lattices.push(lattice);
                    state.x.extend(x);
                    surface.extend(
                        topology::cuboid_surface(c.resolution)
                            .into_iter()
                            .map(|t| t.map(|p| first + p)),
                    );
                }
                BodyShape::Mesh(m) => {
                    let v = &m.voxels;
                    let rot = crate::scene::rotation_from_degrees(m.rotation);
                    let x: Vec<DVec3> = v
                        .points()
                        .iter()
                        .map(|&p| m.center + rot * v.local(p))
                        .collect();
                    contact
                        .lattice
                        .extend(v.points().iter().map(|p| Some(p.map(|c| c as i32))));
                    let mass_each = m.total_mass() / x.len() as f64;
                    state.v.extend(std::iter::repeat_n(m.velocity, x.len()));
                    mass.extend(std::iter::repeat_n(mass_each, x.len()));
                    let families = [m.structural, m.shear, m.bending];
                    let points = v.lattice_points();
                    let lattice =
                        Lattice::new(b as u32, first, points, DVec3::splat(v.cell()), families);
                    lattices.push(lattice.masked(v.particle_of(), v.present()));
                    state.x.extend(x);
                    match m.surface {
                        SurfaceKind::Lattice => surface.extend(
                            v.lattice_surface()
                                .into_iter()
                                .map(|t| t.map(|p| first + p)),
                        ),
                        SurfaceKind::Mesh => {
                            let mesh = v.mesh();
                            let first_vertex = embedded.len() as u32;
                            embedded.meshes.push(EmbeddedMesh {
                                body: b as u32,
                                first_vertex,
                                vertices: mesh.vertices.len() as u32,
                                first_triangle: embedded.triangles.len() as u32,
                                triangles: mesh.triangles.len() as u32,
                            });
                            for (corners, weights) in v.embedding() {
                                embedded.corners.push(corners.map(|p| first + p));
                                embedded.weights.push(weights);
                            }
                            embedded
                                .triangles
                                .extend(mesh.triangles.iter().map(|t| t.map(|i| first_vertex + i)));
                        }
                    }
                }
                BodyShape::Particles(p) => {
                    contact
                        .lattice
                        .extend(std::iter::repeat_n(None, p.positions.len()));
                    state.x.extend(&p.positions);
                    state.v.extend(&p.velocities);
                    mass.extend(&p.masses);
                    for s in &p.springs {
                        let rest = s.rest.unwrap_or_else(|| {
                            p.positions[s.a as usize].distance(p.positions[s.b as usize])
                        });
                        springs.push(first + s.a, first + s.b, rest, s.stiffness, s.damping);
                    }
                }
            }
            let count = state.x.len() as u32 - first;
            let radius = body.contact_radius();
            contact
                .radius
                .extend(std::iter::repeat_n(radius, count as usize));
            contact
                .body
                .extend(std::iter::repeat_n(b as u32, count as usize));
            contact.self_contact.push(body.self_contact);
            for &p in &body.pinned {
                pinned[(first + p) as usize] = true;
            }
            bodies.push(BodyRange {
                name: body.name.clone(),
                first,
                count,
            });
        }
        let inv_mass = mass
            .iter()
            .zip(&pinned)
            .map(|(&m, &p)| if p { 0.0 } else { 1.0 / m })
            .collect();
        for (v, &p) in state.v.iter_mut().zip(&pinned) {
            if p {
                *v = DVec3::ZERO;
            }
        }
        let model = Model {
            simulation: scene.simulation,
            mass,
            inv_mass,
            listed: springs,
            lattices,
            all_springs: Derived::default(),
            adjacency: Derived::default(),
            spring_counts: scene.spring_counts(),
            bodies,
            surface,
            embedded,
            terrain: scene.terrain.clone(),
            contact,
        };
        (model, state)
    }
}
