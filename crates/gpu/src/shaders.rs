//! The WGSL sources, compiled into the binary, and how each stage's module is composed.
//!
//! `shaders/*.wgsl` are the stages, one file per module the host compiles ([`Stage`]), and
//! `shaders/shared/*.wgsl` the pieces they share. WGSL has no includes: each file starts with
//! `#import` lines naming the pieces it uses, which the preprocessor (`compose.rs`) substitutes,
//! each once, in dependency order (`common.wgsl`, the parameters, springs and thread index, first
//! in every module). The table of [`Stage`] below is the one list of the stages: each names its
//! file and, where one file makes several modules, the defines that choose its `#ifdef` branches
//! (the explicit integrators' kernels, `explicit.wgsl`, on the per-spring path, fused, and fused on
//! the lattices' stencil).
//!
//! The shaders are the only place binding numbers are written: the host reads each entry
//! point's bindings (name, number, access) from the composed module with naga and binds
//! buffers by name.
//!
//! Per-spring arrays may be split into chunks ([`crate::chunks`]): the per-particle gathers
//! then read every chunk, through accessors the host generates for the chunk count as pieces
//! of their own, imported like the others: `per_spring_chunks` (`per_spring_at(s)`, and
//! `gathered(s)`, the stored per-spring vector `gather.wgsl` sums), `block_chunks`
//! (`block_at(s)`) and `spring_chunks` (`spring_at(s)`). They declare the extra chunks as
//! `per_spring_1`, `per_spring_2`, … from [`PER_SPRING_CHUNK_BINDING`], `block_1`, … from
//! [`BLOCK_CHUNK_BINDING`] and `spring_1`, … from [`SPRING_CHUNK_BINDING`] (numbers of
//! [`crate::chunks`]).

use std::borrow::Cow;

use crate::chunks::{
    BLOCK_CHUNK_BINDING, Chunking, PER_SPRING_CHUNK_BINDING, SPRING_CHUNK_BINDING,
};
use crate::compose::{Composed, Piece, compose};

/// The uniforms bound at a dynamic offset, which WGSL cannot say: the step number of
/// `finite.wgsl`, one slot of a constant table per step of a submission; the level of the broad
/// phase's prefix sum, one slot per level.
pub(crate) const DYNAMIC_UNIFORMS: [&str; 2] = ["step_index", "scan_level"];

/// The stage table: `Variant: "file.wgsl"`, or `Variant: "file.wgsl" ["define", …]` for a
/// permutation, with the variant's docs.
macro_rules! stages {
    ($($(#[doc = $doc:literal])+ $stage:ident: $file:literal $([$($define:literal),+])?;)+) => {
        /// One shader module: a stage file composed with the pieces it imports.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum Stage {
            $($(#[doc = $doc])+ $stage,)+
        }

        impl Stage {
            /// Every stage.
            pub const ALL: &'static [Stage] = &[$(Stage::$stage),+];

            /// The stage's file name under `shaders/`.
            pub fn file(self) -> &'static str {
                match self {
                    $(Stage::$stage => $file,)+
                }
            }

            /// The stage's file: its path and text.
            fn text(self) -> (&'static str, &'static str) {
                match self {
                    $(Stage::$stage => (
                        concat!("shaders/", $file),
                        include_str!(concat!("../shaders/", $file)),
                    ),)+
                }
            }

            /// The defines its module is composed with.
            fn defines(self) -> &'static [&'static str] {
                match self {
                    $(Stage::$stage => &[$($($define),+)?],)+
                }
            }
        }
    };
}

/// The pieces `#import` finds under `shaders/shared/`, by name.
macro_rules! pieces {
    ($($name:literal)+) => {
        /// The piece named `name`: its path and text.
        fn shared(name: &str) -> Option<(&'static str, &'static str)> {
            match name {
                $($name => Some((
                    concat!("shaders/shared/", $name, ".wgsl"),
                    include_str!(concat!("../shaders/shared/", $name, ".wgsl")),
                )),)+
                _ => None,
            }
        }
    };
}

pieces!(
    "common" "finite" "reduce" "cg_common" "gather" "fused_gather" "lattice" "stencil" "product"
    "terrain" "contact" "acceleration" "response" "neighbours" "updates"
);

stages! {
    /// `spring_forces.wgsl`.
    SpringForces: "spring_forces.wgsl";
    /// `forces.wgsl` (with terrain and contact).
    Forces: "forces.wgsl";
    /// `explicit.wgsl`: the explicit integrators' updates on the per-spring path, after the
    /// accelerations of [`Stage::Forces`].
    Explicit: "explicit.wgsl";
    /// `collision_response.wgsl` (with terrain).
    CollisionResponse: "collision_response.wgsl";
    /// `check_finite.wgsl`.
    CheckFinite: "check_finite.wgsl";
    /// `energy.wgsl` (with the lattices, for the stencil route's `energy_lattices`).
    Energy: "energy.wgsl";
    /// `system.wgsl` (implicit Euler's linear system).
    System: "system.wgsl";
    /// `fused_product.wgsl`: implicit Euler's product A p in one dispatch, the springs' terms
    /// computed as they are gathered.
    FusedProduct: "fused_product.wgsl";
    /// `cg.wgsl` (implicit Euler's filtered PCG).
    Cg: "cg.wgsl";
    /// `implicit_euler.wgsl` (contacts, active set, update; with terrain).
    ImplicitEuler: "implicit_euler.wgsl";
    /// `terrain_probe.wgsl` (with terrain): the terrain queries alone, for the twin tests.
    TerrainProbe: "terrain_probe.wgsl";
    /// `broad_phase.wgsl` (with the grid): the hashed grid of contact between bodies.
    BroadPhase: "broad_phase.wgsl";
    /// `body_contact.wgsl` (with the grid): the penalty forces and the response between bodies.
    BodyContact: "body_contact.wgsl";
    /// `pairs_probe.wgsl` (with the grid): the pairs in contact, for the twin tests.
    PairsProbe: "pairs_probe.wgsl";
    /// `explicit.wgsl` with `fused` (with terrain and contact): the explicit integrators'
    /// stages, one dispatch each, gathering through the CSR adjacency and the spring records.
    FusedStep: "explicit.wgsl" ["fused"];
    /// `explicit.wgsl` with `fused` and `stencil`: [`Stage::FusedStep`]'s kernels for models
    /// whose bodies are all lattices, their springs found on the lattices (`stencil.wgsl`).
    FusedStencil: "explicit.wgsl" ["fused", "stencil"];
}

impl Stage {
    /// The composed module for per-spring arrays split as `chunking` says (which only the
    /// generated chunk accessors depend on). An error is a defect of the shaders, naming the
    /// file and line at fault.
    pub(crate) fn compose(self, chunking: Chunking) -> Result<Composed, String> {
        let (path, text) = self.text();
        let piece = |name: &str| -> Option<Piece> {
            match shared(name) {
                Some((path, text)) => Some((path, Cow::Borrowed(text))),
                None => chunk_accessors(name, chunking),
            }
        };
        compose(path, text, self.defines(), &piece)
    }
}

/// The generated piece `name` for per-spring arrays split as `chunking` says: `{array}_at(s)`,
/// spring s's element of the array whose chunk 0 is `{first}` and chunk c ≥ 1 `{array}_c` (at
/// binding `binding` + c − 1), and for the per-spring vectors `gathered(s)` too.
fn chunk_accessors(name: &str, chunking: Chunking) -> Option<Piece> {
    let (path, array, ty, first, binding) = match name {
        "per_spring_chunks" => (
            "generated per_spring_chunks",
            "per_spring",
            "vec4<f32>",
            "per_spring",
            PER_SPRING_CHUNK_BINDING,
        ),
        "block_chunks" => (
            "generated block_chunks",
            "block",
            "SpringBlock",
            "blocks",
            BLOCK_CHUNK_BINDING,
        ),
        "spring_chunks" => (
            "generated spring_chunks",
            "spring",
            "Spring",
            "springs",
            SPRING_CHUNK_BINDING,
        ),
        _ => return None,
    };
    let mut out = format!(
        "// Generated by crates/gpu/src/shaders.rs: spring s of {} chunk(s) of 2^{} springs.\n",
        chunking.count, chunking.shift
    );
    if chunking.count == 1 {
        out.push_str(&format!(
            "fn {array}_at(s: u32) -> {ty} {{\n    return {first}[s];\n}}\n"
        ));
    } else {
        for c in 1..chunking.count {
            out.push_str(&format!(
                "@group(0) @binding({}) var<storage, read> {array}_{c}: array<{ty}>;\n",
                binding + c - 1
            ));
        }
        out.push_str(&format!(
            "fn {array}_at(s: u32) -> {ty} {{\n    let j = s & {mask}u;\n    switch s >> {shift}u {{\n",
            mask = (1u32 << chunking.shift) - 1,
            shift = chunking.shift,
        ));
        for c in 1..chunking.count {
            out.push_str(&format!(
                "        case {c}u: {{\n            return {array}_{c}[j];\n        }}\n"
            ));
        }
        out.push_str(&format!(
            "        default: {{\n            return {first}[j];\n        }}\n    }}\n}}\n"
        ));
    }
    if array == "per_spring" {
        out.push_str("fn gathered(s: u32) -> vec3<f32> {\n    return per_spring_at(s).xyz;\n}\n");
    }
    Some((path, Cow::Owned(out)))
}
