//! The WGSL sources, compiled into the binary, and how each kernel's module is composed.
//!
//! WGSL has no includes, so each stage's module is the concatenation of the shared pieces it
//! needs and its own file: `common.wgsl` (parameters, springs, the thread index) always, then
//! `reduce.wgsl` (the workgroup tree sum) for the stages that reduce, `gather.wgsl` (the CSR
//! gather) for the stages that gather per-spring vectors, `terrain.wgsl` for the stages that
//! query the terrain, then `contact.wgsl` for `forces.wgsl`.
//! [`Stage::bindings`] is the host's side of each module's interface and [`Stage::kernel`] that
//! of each entry point; a test checks them against the module's declarations and each entry
//! point's use with naga, so the two cannot drift apart unnoticed.
//!
//! The stages of the explicit integrators bind every binding of their module to each entry
//! point. The implicit stages (`system.wgsl`, `cg.wgsl`, `implicit_euler.wgsl`) declare more
//! buffers than one kernel may bind (WebGPU guarantees 8 storage buffers per shader stage), so
//! each of their entry points gets a pipeline layout of only the bindings it uses, at most 8
//! storage buffers with the terrain's.

/// `shaders/common.wgsl`.
pub const COMMON: &str = include_str!("../../../shaders/common.wgsl");
/// `shaders/terrain.wgsl`.
pub const TERRAIN: &str = include_str!("../../../shaders/terrain.wgsl");
/// `shaders/contact.wgsl`.
pub const CONTACT: &str = include_str!("../../../shaders/contact.wgsl");
/// `shaders/reduce.wgsl`.
pub const REDUCE: &str = include_str!("../../../shaders/reduce.wgsl");
/// `shaders/gather.wgsl`.
pub const GATHER: &str = include_str!("../../../shaders/gather.wgsl");

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
    /// `system.wgsl` (implicit Euler's linear system).
    System,
    /// `cg.wgsl` (implicit Euler's filtered PCG).
    Cg,
    /// `implicit_euler.wgsl` (contacts, active set, update; with terrain).
    ImplicitEuler,
}

/// One entry point's interface: its `@group(0)` bindings (a subset of its module's, with the
/// module's access) and whether it queries the terrain (`@group(1)`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kernel {
    /// The entry point.
    pub entry: &'static str,
    /// The `@group(0)` binding numbers it uses, ascending (binding 0, `params`, included).
    pub bindings: &'static [u32],
    /// Whether its layout has the terrain group.
    pub terrain: bool,
}

impl Stage {
    /// Every stage.
    pub const ALL: [Stage; 12] = [
        Stage::SpringForces,
        Stage::Forces,
        Stage::ExplicitEuler,
        Stage::SymplecticEuler,
        Stage::Midpoint,
        Stage::Rk4,
        Stage::CollisionResponse,
        Stage::CheckFinite,
        Stage::Energy,
        Stage::System,
        Stage::Cg,
        Stage::ImplicitEuler,
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
            Stage::System => "system.wgsl",
            Stage::Cg => "cg.wgsl",
            Stage::ImplicitEuler => "implicit_euler.wgsl",
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
            Stage::System => include_str!("../../../shaders/system.wgsl"),
            Stage::Cg => include_str!("../../../shaders/cg.wgsl"),
            Stage::ImplicitEuler => include_str!("../../../shaders/implicit_euler.wgsl"),
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
            Stage::System => &[
                "assemble_springs",
                "assemble_particles",
                "apply_springs",
                "apply_particles",
            ],
            Stage::Cg => &[
                "cg_start",
                "cg_residual",
                "cg_begin",
                "cg_curvature",
                "cg_alpha",
                "cg_advance",
                "cg_beta",
                "cg_direction",
            ],
            Stage::ImplicitEuler => &[
                "implicit_candidates",
                "implicit_constrain",
                "implicit_active_set",
                "implicit_finish",
            ],
        }
    }

    /// Whether each entry point has a layout of its own bindings ([`Stage::kernel`]) rather than
    /// the module's.
    pub fn per_entry_layouts(self) -> bool {
        matches!(self, Stage::System | Stage::Cg | Stage::ImplicitEuler)
    }

    /// The interface of entry point `entry`: for the implicit stages its own bindings, for the
    /// others all of the module's.
    pub fn kernel(self, entry: &str) -> Kernel {
        let own = |entry: &'static str, bindings: &'static [u32], terrain: bool| Kernel {
            entry,
            bindings,
            terrain,
        };
        let all = |entry: &'static str| -> Kernel {
            const ALL: [u32; 8] = [0, 1, 2, 3, 4, 5, 6, 7];
            let n = self.bindings().len();
            own(entry, &ALL[..n], self.uses_terrain())
        };
        let &name = self
            .entry_points()
            .iter()
            .find(|&&e| e == entry)
            .unwrap_or_else(|| panic!("{} has no entry point {entry}", self.file()));
        match (self, name) {
            // params; x, v, springs, blocks, per_spring_out
            (Stage::System, "assemble_springs") => own(name, &[0, 1, 2, 6, 7, 8], false),
            // params; v, per_spring, adjacency, mass, blocks, b, diag
            (Stage::System, "assemble_particles") => own(name, &[0, 2, 3, 4, 5, 7, 11, 12], false),
            // params; springs, blocks, per_spring_out, p
            (Stage::System, "apply_springs") => own(name, &[0, 6, 7, 8, 9], false),
            // params; per_spring, adjacency, p, out, diag
            (Stage::System, "apply_particles") => own(name, &[0, 3, 4, 9, 10, 12], false),
            // params; constraints, z, dv
            (Stage::Cg, "cg_start") => own(name, &[0, 1, 2, 3], false),
            // params; constraints, rhs, q, r, c, diag, partials
            (Stage::Cg, "cg_residual") => own(name, &[0, 1, 4, 5, 6, 7, 8, 9], false),
            // params; partials, scalars, dispatch
            (Stage::Cg, "cg_begin" | "cg_alpha" | "cg_beta") => own(name, &[0, 9, 10, 11], false),
            // params; constraints, q, c, partials
            (Stage::Cg, "cg_curvature") => own(name, &[0, 1, 5, 7, 9], false),
            // params; dv, q, r, c, diag, partials, scalars
            (Stage::Cg, "cg_advance") => own(name, &[0, 3, 5, 6, 7, 8, 9, 10], false),
            // params; constraints, r, c, diag, scalars
            (Stage::Cg, "cg_direction") => own(name, &[0, 1, 6, 7, 8, 10], false),
            // params; x, v, mass, b, candidates; terrain
            (Stage::ImplicitEuler, "implicit_candidates") => own(name, &[0, 1, 2, 3, 5, 8], true),
            // params; v, mass, rhs, b, candidates, constraints, z
            (Stage::ImplicitEuler, "implicit_constrain") => {
                own(name, &[0, 2, 3, 4, 5, 8, 9, 10], false)
            }
            // params; v, mass, rhs, dv, q, candidates, changed
            (Stage::ImplicitEuler, "implicit_active_set") => {
                own(name, &[0, 2, 3, 4, 6, 7, 8, 11], false)
            }
            // params; x, v, dv
            (Stage::ImplicitEuler, "implicit_finish") => own(name, &[0, 1, 2, 6], false),
            _ => all(name),
        }
    }

    /// The `(binding, access)` entries of a kernel's `@group(0)` layout.
    pub fn kernel_bindings(self, kernel: &Kernel) -> Vec<(u32, Access)> {
        kernel
            .bindings
            .iter()
            .map(|&b| {
                let &(_, access) = self
                    .bindings()
                    .iter()
                    .find(|&&(binding, _)| binding == b)
                    .unwrap_or_else(|| panic!("{} has no binding {b}", self.file()));
                (b, access)
            })
            .collect()
    }

    /// Whether its module includes the terrain (bound at `@group(1)`).
    pub fn uses_terrain(self) -> bool {
        matches!(
            self,
            Stage::Forces | Stage::CollisionResponse | Stage::ImplicitEuler
        )
    }

    /// Whether its module includes `reduce.wgsl`.
    fn uses_reduce(self) -> bool {
        matches!(self, Stage::Energy | Stage::Cg)
    }

    /// Whether its module includes `gather.wgsl` (bindings 3 and 4).
    fn uses_gather(self) -> bool {
        matches!(self, Stage::Forces | Stage::System)
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
            // params, x, v, per_spring, adjacency, mass, springs, blocks, per_spring_out, p,
            // out, b, diag
            Stage::System => &[
                (0, Uniform),
                (1, Read),
                (2, Read),
                (3, Read),
                (4, Read),
                (5, Read),
                (6, Read),
                (7, ReadWrite),
                (8, ReadWrite),
                (9, Read),
                (10, ReadWrite),
                (11, ReadWrite),
                (12, ReadWrite),
            ],
            // params, constraints, z, dv, rhs, q, r, c, diag, partials, scalars, dispatch
            Stage::Cg => &[
                (0, Uniform),
                (1, Read),
                (2, Read),
                (3, ReadWrite),
                (4, Read),
                (5, ReadWrite),
                (6, ReadWrite),
                (7, ReadWrite),
                (8, Read),
                (9, ReadWrite),
                (10, ReadWrite),
                (11, ReadWrite),
            ],
            // params, x, v, mass, rhs, b, dv, q, candidates, constraints, z, changed
            Stage::ImplicitEuler => &[
                (0, Uniform),
                (1, ReadWrite),
                (2, ReadWrite),
                (3, Read),
                (4, ReadWrite),
                (5, Read),
                (6, Read),
                (7, Read),
                (8, ReadWrite),
                (9, ReadWrite),
                (10, ReadWrite),
                (11, ReadWrite),
            ],
        }
    }

    /// The pieces of its module, in order: (file name, source).
    pub fn pieces(self) -> Vec<(&'static str, &'static str)> {
        let mut pieces = vec![("common.wgsl", COMMON)];
        if self.uses_reduce() {
            pieces.push(("reduce.wgsl", REDUCE));
        }
        if self.uses_gather() {
            pieces.push(("gather.wgsl", GATHER));
        }
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
