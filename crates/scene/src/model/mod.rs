//! The model both solvers step: particles, springs and their CSR adjacency, bodies, terrain.
//!
//! A [`Model`] is immutable once built; the changing part is the [`State`] (positions and
//! velocities). Springs are stored as a structure of arrays, and each particle's springs as one
//! contiguous run of the adjacency (compressed sparse rows), so that per-particle force sums are
//! gathers in a fixed order: the same bits whatever the thread count, and the scheme the GPU
//! uses too, since WGSL has no float atomics.
//!
//! # Lean cuboids
//!
//! A lattice body's springs are a stencil ([`Lattice`]): the same offsets and parameters at
//! every particle (a mesh body's masked to its kept cells). The model keeps only the stencil
//! for them, so that a large cube stepped by a
//! stencil kernel holds no per-spring array at all (a 300³ cube has 423 M springs: 13.5 GB as
//! a list, 3.4 GB more as an adjacency). [`Model::springs`] and [`Model::adjacency`] build
//! the full list and its adjacency on first use and keep them, for the consumers that read
//! springs by index (the gather and sweep routes, implicit Euler, the GPU, the exports);
//! [`Model::for_each_spring`] visits every spring in the same order without building anything.

mod build;
mod contacts;
mod embedding;
mod estimate;
mod lattice;
mod springs;

use glam::DVec3;

use crate::scene::{Simulation, SpringCounts, Terrain};
#[cfg(doc)]
use crate::topology;

pub use contacts::{Contacts, PENALTY, PENALTY_IMPLICIT, SELF_CONTACT_EXCLUSION, SLOP, penalty};
pub use embedding::{Embedded, EmbeddedMesh};
pub use estimate::{
    BYTES_PER_PARTICLE, BYTES_PER_SPRING, MAX_PARTICLES, MAX_SPRINGS, estimated_bytes,
    estimated_scene_bytes, lean_bytes_per_particle,
};
pub use lattice::{Lattice, LatticeMask, LatticeSpring};
pub use springs::{Adjacency, Springs};

/// A value computed from the rest of its model on first use, then kept. It is no part of the
/// model's identity: its `Debug` text is the same computed or not (checkpoints fingerprint
/// the model's `Debug` text), and a clone carries it if computed.
#[derive(Clone, Default)]
struct Derived<T>(std::sync::OnceLock<T>);

impl<T> std::fmt::Debug for Derived<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Derived")
    }
}

/// Bytes a vector holds on the heap.
pub fn vec_bytes<T>(v: &Vec<T>) -> u64 {
    (v.capacity() * std::mem::size_of::<T>()) as u64
}

/// Where a body's particles sit in the global arrays.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BodyRange {
    /// The body's name.
    pub name: String,
    /// Index of its first particle.
    pub first: u32,
    /// Number of particles.
    pub count: u32,
}

/// Positions and velocities: what a step changes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct State {
    /// x_i, metres.
    pub x: Vec<DVec3>,
    /// v_i, m/s.
    pub v: Vec<DVec3>,
}

/// Everything about a scene that does not change during a run.
#[derive(Debug, Clone)]
pub struct Model {
    /// Time stepping and global forces.
    pub simulation: Simulation,
    /// m_i, kg.
    pub mass: Vec<f64>,
    /// 1/m_i, and 0 for pinned particles (so they never accelerate).
    pub inv_mass: Vec<f64>,
    /// The springs of the bodies without a lattice (`particles` bodies), in body
    /// order; all of them once [`Model::springs_mut`] has turned the lattices into a list.
    listed: Springs,
    /// The lattice bodies' springs (cuboids and mesh bodies), as stencils on their lattices
    /// (one per body, in body order).
    lattices: Vec<Lattice>,
    /// Every spring ([`Model::springs`]), built on first use when there are lattices.
    all_springs: Derived<Springs>,
    /// Each particle's springs ([`Model::adjacency`]), built on first use.
    adjacency: Derived<Adjacency>,
    /// Springs of each family.
    pub spring_counts: SpringCounts,
    /// Bodies in particle order.
    pub bodies: Vec<BodyRange>,
    /// The outer surface of the cuboid bodies as triangles of particle indices, wound
    /// counter-clockwise seen from outside ([`topology::cuboid_surface`]), and of the mesh
    /// bodies with `surface = "lattice"` (the outer faces of their kept cells,
    /// [`crate::voxel::Voxels::lattice_surface`]); `particles` bodies have no surface and add
    /// none, mesh bodies showing their mesh add it to `embedded` instead.
    pub surface: Vec<[u32; 3]>,
    /// The input meshes of the mesh bodies, carried by their lattices.
    pub embedded: Embedded,
    /// Terrain shapes.
    pub terrain: Vec<Terrain>,
    /// Who touches whom between and within bodies.
    pub contact: Contacts,
}
/// The largest step h of symplectic Euler on a mode of M⁻¹K eigenvalue λ and damping rate c:
/// the root of h²λ + 2hc = 4 (2/c without stiffness); `None` for a mode with neither.
pub fn largest_stable_step(lambda: f64, c: f64) -> Option<f64> {
    if lambda == 0.0 {
        return (c > 0.0).then(|| 2.0 / c);
    }
    Some((-c + (c * c + 4.0 * lambda).sqrt()) / lambda)
}

impl Model {
    /// Number of particles.
    pub fn len(&self) -> usize {
        self.mass.len()
    }

    /// Whether the model has no particles.
    pub fn is_empty(&self) -> bool {
        self.mass.is_empty()
    }

    /// Every spring, bodies in order: a lattice body's in [`topology::for_each_lattice_spring`]'s
    /// order, a `particles` body's as given. Built on first use where there are lattices, then kept
    /// (see the module doc: a caller that only needs to visit them once wants
    /// [`Model::for_each_spring`]).
    pub fn springs(&self) -> &Springs {
        if self.lattices.is_empty() {
            return &self.listed;
        }
        self.all_springs.0.get_or_init(|| {
            let mut all = Springs::with_capacity(self.spring_count());
            self.for_each_spring(|a, b, rest, stiffness, damping| {
                all.push(a, b, rest, stiffness, damping);
            });
            all
        })
    }

    /// Each particle's springs in [`Model::springs`]: built on first use, then kept.
    pub fn adjacency(&self) -> &Adjacency {
        (self.adjacency.0).get_or_init(|| Adjacency::build(self.len(), self.springs()))
    }

    /// The springs, for changing their parameters: the lattices' stencils become a list
    /// (afterwards [`Model::lattices`] is empty and the solvers take the routes for listed
    /// springs). The end points may change too; the adjacency is rebuilt on its next use.
    pub fn springs_mut(&mut self) -> &mut Springs {
        if !self.lattices.is_empty() {
            self.springs();
            self.listed = std::mem::take(&mut self.all_springs)
                .0
                .into_inner()
                .unwrap_or_default();
            self.lattices.clear();
        }
        self.adjacency = Derived::default();
        &mut self.listed
    }

    /// The lattice bodies' springs (cuboids and mesh bodies) as stencils on their lattices, one
    /// per such body in body order:
    /// what lets a solver find a spring's partner at a constant offset.
    pub fn lattices(&self) -> &[Lattice] {
        &self.lattices
    }

    /// The springs of the bodies without a lattice (`particles` bodies), in body
    /// order: with [`Model::lattices`], every spring.
    pub fn listed_springs(&self) -> &Springs {
        &self.listed
    }

    /// Number of springs (without building [`Model::springs`]).
    pub fn spring_count(&self) -> usize {
        let lattices: u64 = self.lattices.iter().map(Lattice::spring_count).sum();
        self.listed.len() + lattices as usize
    }

    /// Calls `f(a, b, rest, stiffness, damping)` for every spring, in the order of
    /// [`Model::springs`], without building it.
    pub fn for_each_spring(&self, mut f: impl FnMut(u32, u32, f64, f64, f64)) {
        let mut lattices = self.lattices.iter().peekable();
        let mut listed = 0;
        for (index, body) in self.bodies.iter().enumerate() {
            if let Some(lattice) = lattices.next_if(|l| l.body as usize == index) {
                lattice.for_each_spring(0..lattice.dims[2], |a, b, s| {
                    f(a, b, s.rest, s.stiffness, s.damping);
                });
                continue;
            }
            let (l, end) = (&self.listed, body.first + body.count);
            while listed < l.len() && l.a[listed] < end {
                let k = listed;
                f(l.a[k], l.b[k], l.rest[k], l.stiffness[k], l.damping[k]);
                listed += 1;
            }
        }
    }

    /// Whether particles i and j may touch: different bodies, or one body with `self_contact`
    /// where they are not rest neighbours — on a cuboid's or mesh body's lattice more than
    /// [`SELF_CONTACT_EXCLUSION`] cells apart along some axis, in a `particles` body not joined
    /// by a spring.
    pub fn admits(&self, i: usize, j: usize) -> bool {
        let c = &self.contact;
        let body = c.body[i];
        if body != c.body[j] {
            return true;
        }
        if !c.self_contact[body as usize] {
            return false;
        }
        match (c.lattice[i], c.lattice[j]) {
            (Some(a), Some(b)) => (0..3).any(|k| (a[k] - b[k]).abs() > SELF_CONTACT_EXCLUSION),
            _ => {
                let springs = self.springs();
                !self.adjacency().of(i).iter().any(|&e| {
                    let s = (e >> 1) as usize;
                    springs.a[s] as usize + springs.b[s] as usize - i == j
                })
            }
        }
    }

    /// Bytes the model holds on the heap per particle and per spring: masses, the contact
    /// arrays, the listed springs, and [`Model::springs`] and [`Model::adjacency`] where they
    /// were built (the surface, embedded meshes and terrain excluded).
    pub fn memory_bytes(&self) -> u64 {
        let springs = |s: &Springs| {
            vec_bytes(&s.a)
                + vec_bytes(&s.b)
                + vec_bytes(&s.rest)
                + vec_bytes(&s.stiffness)
                + vec_bytes(&s.damping)
        };
        let c = &self.contact;
        vec_bytes(&self.mass)
            + vec_bytes(&self.inv_mass)
            + vec_bytes(&c.radius)
            + vec_bytes(&c.body)
            + vec_bytes(&c.lattice)
            + springs(&self.listed)
            + self.all_springs.0.get().map_or(0, springs)
            + (self.adjacency.0.get()).map_or(0, |a| vec_bytes(&a.offsets) + vec_bytes(&a.entries))
    }

    /// Estimate of the largest stable step of the explicit integrators: the symplectic-Euler
    /// bound h²λ + 2hc ≤ 4 of the stiffest mode, with λ ≥ ω² and c bounded by Gershgorin's
    /// theorem on M⁻¹K and M⁻¹D (λ_i = 2Σk_s/m_i, c_i = 2Σk_d/m_i over particle i's springs).
    /// Conservative: a regular cube's true bound is about 1.5 times larger. RK4 tolerates about
    /// 1.4 times this step, explicit Euler and midpoint are unstable on undamped springs at any
    /// step (their energy grows), and implicit Euler is stable at any step. `None` without
    /// springs.
    pub fn stable_dt(&self) -> Option<f64> {
        self.stable_dt_bounds()
            .and_then(|(lambda, c)| largest_stable_step(lambda, c))
    }

    /// Gershgorin's bounds on the λ and c of [`Model::stable_dt`]; `None` without springs.
    pub fn stable_dt_bounds(&self) -> Option<(f64, f64)> {
        if self.spring_count() == 0 {
            return None;
        }
        // Each particle's sums in ascending spring order, as a gather over its adjacency would
        // add them, without building it.
        let mut sums = vec![(0.0f64, 0.0f64); self.len()];
        self.for_each_spring(|a, b, _, k, d| {
            for p in [a, b] {
                let sum = &mut sums[p as usize];
                *sum = (sum.0 + k, sum.1 + d);
            }
        });
        let (mut lambda, mut c) = (0.0f64, 0.0f64);
        for (&(k, d), &m) in sums.iter().zip(&self.mass) {
            lambda = lambda.max(2.0 * k / m);
            c = c.max(2.0 * d / m);
        }
        Some((lambda, c))
    }

    /// The bodies and springs of this model, with every spring's stiffness and damping
    /// (k_s, k_d) replaced by `coefficients(k_s, k_d)`; no terrain, surfaces, embedded meshes
    /// or contact between bodies. A spring kernel run on it computes other linear operators
    /// of the springs: with (0, k_s), the damper forces at velocities w are −K w, the product
    /// of the stiffness matrix linearised at the positions (the stable-step estimate's power
    /// iteration, `softbody_cpu::stable_step`).
    pub fn with_spring_coefficients(&self, coefficients: impl Fn(f64, f64) -> (f64, f64)) -> Model {
        let mut listed = self.listed.clone();
        for (k, d) in listed.stiffness.iter_mut().zip(&mut listed.damping) {
            (*k, *d) = coefficients(*k, *d);
        }
        let mut lattices = self.lattices.clone();
        for s in lattices.iter_mut().flat_map(|l| &mut l.springs) {
            (s.stiffness, s.damping) = coefficients(s.stiffness, s.damping);
        }
        Model {
            simulation: self.simulation,
            mass: self.mass.clone(),
            inv_mass: self.inv_mass.clone(),
            listed,
            lattices,
            all_springs: Derived::default(),
            adjacency: Derived::default(),
            spring_counts: self.spring_counts,
            bodies: self.bodies.clone(),
            surface: Vec::new(),
            embedded: Embedded::default(),
            terrain: Vec::new(),
            contact: Contacts::default(),
        }
    }

    /// Whether particle i is pinned.
    pub fn is_pinned(&self, i: usize) -> bool {
        self.inv_mass[i] == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stable_dt_of_one_spring_is_the_leapfrog_bound() {
        // Two unit masses, one spring k: ω² = 2k/m, and symplectic Euler is stable for h ≤ 2/ω.
        let scene = crate::Scene::from_toml(
            "[simulation]\ndt = 0.001\nduration = 1.0\n[[body]]\nkind = \"particles\"\n\
             positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\nmasses = [1.0, 1.0]\n\
             springs = [{ a = 0, b = 1, stiffness = 50.0 }]\n",
            "t.toml".as_ref(),
        )
        .unwrap();
        let (model, _) = Model::build(&scene);
        assert!((model.stable_dt().unwrap() - 2.0 / 100f64.sqrt()).abs() < 1e-15);
    }
}
