//! The WGSL sources, compiled into the binary, and how each kernel's module is composed.
//!
//! WGSL has no includes, so each stage's module is the concatenation of the shared pieces it
//! needs and its own file: `common.wgsl` (parameters, springs, the thread index) always, then
//! `terrain.wgsl` for the stages that query the terrain, then `contact.wgsl` for `forces.wgsl`.
//! [`Stage::bindings`] is the host's side of each module's interface; a test checks it against
//! the module's declarations with naga, so the two cannot drift apart unnoticed.

/// `shaders/common.wgsl`.
pub const COMMON: &str = include_str!("../../../shaders/common.wgsl");
/// `shaders/terrain.wgsl`.
pub const TERRAIN: &str = include_str!("../../../shaders/terrain.wgsl");
/// `shaders/contact.wgsl`.
pub const CONTACT: &str = include_str!("../../../shaders/contact.wgsl");

/// How a kernel uses a buffer binding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// `var<uniform>`.
    Uniform,
    /// `var<uniform>` bound at a dynamic offset.
    DynamicUniform,
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// The terrain's bindings, `@group(1)` of the stages that query it: `surfaces` and
/// `terrain_data`.
pub const TERRAIN_BINDINGS: &[(u32, Access)] = &[(0, Access::Read), (1, Access::Read)];

/// One shader module: a stage file and its entry points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// `spring_forces.wgsl`.
    SpringForces,
    /// `forces.wgsl` (with terrain and contact).
    Forces,
    /// `explicit_euler.wgsl`.
    ExplicitEuler,
    /// `symplectic_euler.wgsl`.
    SymplecticEuler,
    /// `midpoint.wgsl`.
    Midpoint,
    /// `rk4.wgsl`.
    Rk4,
    /// `collision_response.wgsl` (with terrain).
    CollisionResponse,
    /// `check_finite.wgsl`.
    CheckFinite,
    /// `energy.wgsl`.
    Energy,
}

impl Stage {
    /// Every stage.
    pub const ALL: [Stage; 9] = [
        Stage::SpringForces,
        Stage::Forces,
        Stage::ExplicitEuler,
        Stage::SymplecticEuler,
        Stage::Midpoint,
        Stage::Rk4,
        Stage::CollisionResponse,
        Stage::CheckFinite,
        Stage::Energy,
    ];

    /// The stage's file name under `shaders/`.
    pub fn file(self) -> &'static str {
        match self {
            Stage::SpringForces => "spring_forces.wgsl",
            Stage::Forces => "forces.wgsl",
            Stage::ExplicitEuler => "explicit_euler.wgsl",
            Stage::SymplecticEuler => "symplectic_euler.wgsl",
            Stage::Midpoint => "midpoint.wgsl",
            Stage::Rk4 => "rk4.wgsl",
            Stage::CollisionResponse => "collision_response.wgsl",
            Stage::CheckFinite => "check_finite.wgsl",
            Stage::Energy => "energy.wgsl",
        }
    }

    /// The stage file's own source.
    fn own_source(self) -> &'static str {
        match self {
            Stage::SpringForces => include_str!("../../../shaders/spring_forces.wgsl"),
            Stage::Forces => include_str!("../../../shaders/forces.wgsl"),
            Stage::ExplicitEuler => include_str!("../../../shaders/explicit_euler.wgsl"),
            Stage::SymplecticEuler => include_str!("../../../shaders/symplectic_euler.wgsl"),
            Stage::Midpoint => include_str!("../../../shaders/midpoint.wgsl"),
            Stage::Rk4 => include_str!("../../../shaders/rk4.wgsl"),
            Stage::CollisionResponse => include_str!("../../../shaders/collision_response.wgsl"),
            Stage::CheckFinite => include_str!("../../../shaders/check_finite.wgsl"),
            Stage::Energy => include_str!("../../../shaders/energy.wgsl"),
        }
    }

    /// Its entry points.
    pub fn entry_points(self) -> &'static [&'static str] {
        match self {
            Stage::SpringForces => &["spring_forces"],
            Stage::Forces => &["accelerations"],
            Stage::ExplicitEuler => &["explicit_euler"],
            Stage::SymplecticEuler => &["symplectic_euler"],
            Stage::Midpoint => &["midpoint_stage", "midpoint_update"],
            Stage::Rk4 => &["rk4_first", "rk4_second", "rk4_third", "rk4_last"],
            Stage::CollisionResponse => &["collision_response"],
            Stage::CheckFinite => &["check_finite"],
            Stage::Energy => &["energy_particles", "energy_springs"],
        }
    }

    /// Whether its module includes the terrain (bound at `@group(1)`).
    pub fn uses_terrain(self) -> bool {
        matches!(self, Stage::Forces | Stage::CollisionResponse)
    }

    /// Its `@group(0)` bindings, in order; binding 0 is always `params`. The host builds the
    /// bind group layout from this table.
    pub fn bindings(self) -> &'static [(u32, Access)] {
        use Access::*;
        match self {
            // params, x, v, springs, per_spring
            Stage::SpringForces => &[
                (0, Uniform),
                (1, Read),
                (2, Read),
                (3, Read),
                (4, ReadWrite),
            ],
            // params, x, v, per_spring, adjacency, mass, a
            Stage::Forces => &[
                (0, Uniform),
                (1, Read),
                (2, Read),
                (3, Read),
                (4, Read),
                (5, Read),
                (6, ReadWrite),
            ],
            // params, x, v, a
            Stage::ExplicitEuler | Stage::SymplecticEuler => {
                &[(0, Uniform), (1, ReadWrite), (2, ReadWrite), (3, Read)]
            }
            // params, x, v, a, stage_x, stage_v
            Stage::Midpoint => &[
                (0, Uniform),
                (1, ReadWrite),
                (2, ReadWrite),
                (3, Read),
                (4, ReadWrite),
                (5, ReadWrite),
            ],
            // params, x, v, a, stage_x, stage_v, sum_x, sum_v
            Stage::Rk4 => &[
                (0, Uniform),
                (1, ReadWrite),
                (2, ReadWrite),
                (3, Read),
                (4, ReadWrite),
                (5, ReadWrite),
                (6, ReadWrite),
                (7, ReadWrite),
            ],
            // params, x, v, mass
            Stage::CollisionResponse => &[(0, Uniform), (1, ReadWrite), (2, ReadWrite), (3, Read)],
            // params, x, v, status, step_index
            Stage::CheckFinite => &[
                (0, Uniform),
                (1, Read),
                (2, Read),
                (3, ReadWrite),
                (4, DynamicUniform),
            ],
            // params, x, v, mass, springs, particle_partials, spring_partials
            Stage::Energy => &[
                (0, Uniform),
                (1, Read),
                (2, Read),
                (3, Read),
                (4, Read),
                (5, ReadWrite),
                (6, ReadWrite),
            ],
        }
    }

    /// The pieces of its module, in order: (file name, source).
    pub fn pieces(self) -> Vec<(&'static str, &'static str)> {
        let mut pieces = vec![("common.wgsl", COMMON)];
        if self.uses_terrain() {
            pieces.push(("terrain.wgsl", TERRAIN));
        }
        if self == Stage::Forces {
            pieces.push(("contact.wgsl", CONTACT));
        }
        pieces.push((self.file(), self.own_source()));
        pieces
    }

    /// The composed module: its pieces, each introduced by a comment naming the file.
    pub fn source(self) -> String {
        let mut source = String::new();
        for (file, text) in self.pieces() {
            source.push_str("// ---- shaders/");
            source.push_str(file);
            source.push_str(" ----\n");
            source.push_str(text);
            if !text.ends_with('\n') {
                source.push('\n');
            }
        }
        source
    }

    /// Maps a 1-based line of [`Stage::source`] back to (file, line in it), for error messages.
    pub fn locate(self, line: usize) -> Option<(&'static str, usize)> {
        let mut first = 1; // the composed line of the current piece's header
        for (file, text) in self.pieces() {
            let lines = text.lines().count();
            if line > first && line <= first + lines {
                return Some((file, line - first));
            }
            first += lines + 1;
        }
        None
    }
}
