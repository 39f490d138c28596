//! Tests of the WGSL that need no adapter: every stage composes, and its module parses and
//! validates with naga; each entry point's bindings reflect as the host binds them; every
//! struct shared with the host has the Rust twin's layout.

use std::mem::{offset_of, size_of};

use crate::chunks::{Chunking, MAX_SPRING_CHUNKS};
use crate::compose::Composed;
use crate::kernel::{Access, Parsed, reflect};
use crate::layout::{
    CG_DISPATCH_WORDS, CandidateGpu, CgScalars, ContactParams, ContactParticleGpu, LatticeBodyGpu,
    LatticeOffsetGpu, Params, ScanLevel, SpringBlockGpu, SpringChunk, SpringGpu, Status, StepIndex,
    dispatch_slot,
};
use crate::shaders::Stage;
use crate::terrain::SurfaceGpu;

/// The module of `stage` with one spring chunk.
fn composed(stage: Stage) -> Composed {
    stage
        .compose(Chunking::ONE)
        .unwrap_or_else(|e| panic!("{} does not compose: {e}", stage.file()))
}

/// `stage`'s module composed for `chunking`, parsed and validated.
fn parsed(stage: Stage, chunking: Chunking) -> Parsed {
    let module = stage
        .compose(chunking)
        .unwrap_or_else(|e| panic!("{} does not compose: {e}", stage.file()));
    Parsed::new(stage, &module)
        .unwrap_or_else(|e| panic!("{} ({chunking:?}) does not validate:\n{e}", stage.file()))
}

fn parse(stage: Stage) -> naga::Module {
    let module = composed(stage);
    naga::front::wgsl::parse_str(&module.source).unwrap_or_else(|e| {
        panic!(
            "{} does not parse:\n{}",
            stage.file(),
            e.emit_to_string_with_path(&module.source, stage.file())
        )
    })
}

#[test]
fn every_stage_composes_and_validates() {
    for &stage in Stage::ALL {
        parsed(stage, Chunking::ONE);
    }
}

/// Each line of a composed module is the line of the file it is located in, and the composer
/// writes nothing but a header per piece.
#[test]
fn composed_lines_are_located_in_their_files() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for &stage in Stage::ALL {
        let module = stage.compose(Chunking { count: 2, shift: 8 }).unwrap();
        for (k, line) in module.source.lines().enumerate() {
            match module.locate(k + 1) {
                Some((file, _)) if file.starts_with("generated ") => {}
                Some((file, l)) => {
                    let text = std::fs::read_to_string(root.join(file)).unwrap();
                    assert_eq!(text.lines().nth(l - 1), Some(line), "{file}:{l}");
                }
                None => assert!(line.starts_with("// ---- "), "{}: {line}", stage.file()),
            }
        }
    }
}

/// Every file under `shaders/` is a stage, and every one under `shaders/shared/` a piece that
/// some stage imports.
#[test]
fn every_shader_file_is_a_stage_or_an_imported_piece() {
    let mut used: Vec<&str> = Vec::new();
    for &stage in Stage::ALL {
        used.extend(composed(stage).files());
    }
    used.retain(|file| !file.starts_with("generated "));
    used.sort();
    used.dedup();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = 0;
    for dir in ["shaders", "shaders/shared"] {
        for entry in std::fs::read_dir(root.join(dir)).unwrap() {
            let name = entry.unwrap().file_name().into_string().unwrap();
            if let Some(stem) = name.strip_suffix(".wgsl") {
                let path = format!("{dir}/{stem}.wgsl");
                assert!(used.contains(&path.as_str()), "{path} is not used");
                files += 1;
            }
        }
    }
    // And nothing a stage uses is elsewhere.
    assert_eq!(files, used.len());
}

/// The names a kernel binds, as reflection reads them.
fn names(stage: Stage, chunking: Chunking, entry: &str) -> (Vec<String>, bool) {
    let parsed = parsed(stage, chunking);
    let (bindings, terrain) = reflect(&parsed, entry).expect("reflects");
    (bindings.into_iter().map(|b| b.name).collect(), terrain)
}

/// Every entry point of every stage reflects (the host dispatches its workgroup size) and binds
/// at most 8 storage buffers with the terrain's: WebGPU's guaranteed minimum per stage. The
/// fused step's kernels bind up to 13 (16, GL llvmpipe's limit, with four spring chunks), its
/// stencil variant's up to 14 (the lattices' two tables instead of the springs and adjacency); an
/// adapter with fewer takes the per-spring path (`integrators::Stepper::new`).
#[test]
fn every_entry_point_reflects_within_webgpu_limits() {
    let mut kernels = 0;
    for &stage in Stage::ALL {
        let parsed = parsed(stage, Chunking::ONE);
        let uses_terrain = composed(stage)
            .files()
            .contains(&"shaders/shared/terrain.wgsl");
        for entry in parsed.entry_points() {
            let (bindings, terrain) = reflect(&parsed, entry)
                .unwrap_or_else(|e| panic!("{entry} in {}: {e}", stage.file()));
            let storage = bindings
                .iter()
                .filter(|b| b.access != Access::Uniform)
                .count()
                + if terrain { 2 } else { 0 };
            let allowed = match stage {
                Stage::FusedStep => 13,
                Stage::FusedStencil => 14,
                _ => 8,
            };
            assert!(
                storage <= allowed,
                "{entry} binds {storage} storage buffers"
            );
            assert_eq!(
                terrain,
                uses_terrain
                    && !matches!(
                        entry,
                        "implicit_constrain"
                            | "implicit_active_set"
                            | "implicit_finish"
                            | "implicit_remember"
                    ),
                "{entry}"
            );
            kernels += 1;
        }
    }
    assert_eq!(kernels, 75);
}

/// Reflection reads what an entry point uses through the functions it calls, with the access
/// the WGSL declares, and only that.
#[test]
fn reflection_reads_each_kernels_own_bindings() {
    let one = Chunking::ONE;
    // `gather` (gather.wgsl) reads per_spring and adjacency; contact_force reads the terrain.
    assert_eq!(
        names(Stage::Forces, one, "accelerations"),
        (
            ["params", "x", "v", "per_spring", "adjacency", "mass", "a"]
                .map(String::from)
                .to_vec(),
            true
        )
    );
    assert_eq!(
        names(Stage::Cg, one, "cg_direction"),
        (
            [
                "params",
                "r",
                "c",
                "diag",
                "scalars",
                "dispatch",
                "constraints",
                "partials",
            ]
            .map(String::from)
            .to_vec(),
            false
        )
    );
    let parsed = parsed(Stage::CheckFinite, one);
    let (bindings, _) = reflect(&parsed, "check_finite").unwrap();
    let access: Vec<(&str, Access, bool)> = bindings
        .iter()
        .map(|b| (b.name.as_str(), b.access, b.dynamic))
        .collect();
    assert_eq!(
        access,
        [
            ("params", Access::Uniform, false),
            ("x", Access::Read, false),
            ("v", Access::Read, false),
            ("status", Access::ReadWrite, false),
            ("step_index", Access::Uniform, true),
        ]
    );
    let parsed = self::parsed(Stage::Explicit, one);
    assert!(reflect(&parsed, "no_such_kernel").is_err());
    // The stage forces of bodies that touch: the search of the start grid (neighbours.wgsl)
    // and the admit rule's rest neighbours, the stage state, into `a`; the counting kernels
    // bind the counts as atomics, the scan as plain words at a dynamic offset.
    let strings = |names: &[&str]| names.iter().map(|&n| n.to_owned()).collect::<Vec<_>>();
    assert_eq!(
        names(Stage::BodyContact, one, "pair_forces"),
        (
            strings(&[
                "params",
                "x",
                "v",
                "a",
                "contact",
                "particles",
                "counts",
                "sorted",
                "snapshot_x",
                "rest_neighbours"
            ]),
            false
        )
    );
    // Implicit Euler's pair terms: the same search, the start snapshot's velocities (whether
    // the penalty pushes), the product's vector and its result.
    assert_eq!(
        names(Stage::BodyContact, one, "pair_products"),
        (
            strings(&[
                "params",
                "p",
                "out",
                "contact",
                "particles",
                "counts",
                "sorted",
                "snapshot_x",
                "snapshot_v",
                "rest_neighbours"
            ]),
            false
        )
    );
    assert_eq!(
        names(Stage::BroadPhase, one, "grid_count_end").0,
        strings(&[
            "params",
            "x",
            "v",
            "counts_atomic",
            "particle_bucket",
            "contact",
            "particles",
            "snapshot_x",
            "snapshot_v"
        ])
    );
    let parsed = self::parsed(Stage::BroadPhase, one);
    let (bindings, _) = reflect(&parsed, "scan_up").unwrap();
    let access: Vec<(&str, Access, bool)> = bindings
        .iter()
        .map(|b| (b.name.as_str(), b.access, b.dynamic))
        .collect();
    assert_eq!(
        access,
        [
            ("scan_level", Access::Uniform, true),
            ("counts", Access::ReadWrite, false),
        ]
    );
}

/// The size of a WGSL struct and its members' (name, offset).
fn wgsl_struct(stage: Stage, name: &str) -> (u32, Vec<(String, u32)>) {
    let module = parse(stage);
    let ty = module
        .types
        .iter()
        .find(|(_, ty)| ty.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name} in {}", stage.file()))
        .1;
    match &ty.inner {
        naga::TypeInner::Struct { members, span } => (
            *span,
            members
                .iter()
                .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
                .collect(),
        ),
        other => panic!("{name} is not a struct: {other:?}"),
    }
}

fn check_layout(stage: Stage, name: &str, size: usize, offsets: &[(&str, usize)]) {
    let (span, members) = wgsl_struct(stage, name);
    assert_eq!(span as usize, size, "size of {name}");
    let members: Vec<(String, usize)> = members.into_iter().map(|(n, o)| (n, o as usize)).collect();
    let expected: Vec<(String, usize)> = offsets.iter().map(|&(n, o)| (n.to_owned(), o)).collect();
    assert_eq!(members, expected, "members of {name}");
}

#[test]
fn params_layout_matches() {
    let pad = offset_of!(Params, _pad);
    check_layout(
        Stage::SpringForces,
        "Params",
        size_of::<Params>(),
        &[
            ("gravity", offset_of!(Params, gravity)),
            ("drag", offset_of!(Params, drag)),
            ("n_particles", offset_of!(Params, n_particles)),
            ("n_springs", offset_of!(Params, n_springs)),
            ("n_surfaces", offset_of!(Params, n_surfaces)),
            ("dt", offset_of!(Params, dt)),
            ("contact_distance", offset_of!(Params, contact_distance)),
            ("_pad0", pad),
            ("_pad1", pad + 4),
            ("_pad2", pad + 8),
        ],
    );
}

#[test]
fn spring_layout_matches() {
    check_layout(
        Stage::Energy,
        "Spring",
        size_of::<SpringGpu>(),
        &[
            ("a", offset_of!(SpringGpu, a)),
            ("b", offset_of!(SpringGpu, b)),
            ("rest", offset_of!(SpringGpu, rest)),
            ("stiffness", offset_of!(SpringGpu, stiffness)),
            ("damping", offset_of!(SpringGpu, damping)),
        ],
    );
}

#[test]
fn lattice_layouts_match() {
    check_layout(
        Stage::FusedStencil,
        "LatticeOffset",
        size_of::<LatticeOffsetGpu>(),
        &[
            ("d", offset_of!(LatticeOffsetGpu, d)),
            ("rest", offset_of!(LatticeOffsetGpu, rest)),
            ("stiffness", offset_of!(LatticeOffsetGpu, stiffness)),
            ("damping", offset_of!(LatticeOffsetGpu, damping)),
            ("bit", offset_of!(LatticeOffsetGpu, bit)),
            ("linear", offset_of!(LatticeOffsetGpu, linear)),
        ],
    );
    check_layout(
        Stage::FusedStencil,
        "LatticeBody",
        size_of::<LatticeBodyGpu>(),
        &[
            ("first", offset_of!(LatticeBodyGpu, first)),
            ("count", offset_of!(LatticeBodyGpu, count)),
            ("nx", offset_of!(LatticeBodyGpu, nx)),
            ("ny", offset_of!(LatticeBodyGpu, ny)),
            ("nz", offset_of!(LatticeBodyGpu, nz)),
            ("n_offsets", offset_of!(LatticeBodyGpu, n_offsets)),
            ("points", offset_of!(LatticeBodyGpu, points)),
            ("_pad", offset_of!(LatticeBodyGpu, _pad)),
            ("offsets", offset_of!(LatticeBodyGpu, offsets)),
            ("backward", offset_of!(LatticeBodyGpu, backward)),
        ],
    );
}

/// The stencil route's kernels (the fused step's, the energies' `energy_lattices`) read the
/// lattices in place of the spring records and the adjacency.
#[test]
fn the_stencil_reads_no_spring_record() {
    assert_eq!(
        names(Stage::Energy, Chunking::ONE, "energy_lattices"),
        (
            [
                "params",
                "x",
                "spring_partials",
                "lattice_bodies",
                "lattice_points"
            ]
            .map(String::from)
            .to_vec(),
            false
        )
    );
    let (stencil, terrain) = names(Stage::FusedStencil, Chunking::ONE, "symplectic_euler");
    assert!(terrain);
    for name in ["lattice_bodies", "lattice_points", "x", "v", "mass"] {
        assert!(stencil.iter().any(|n| n == name), "{name} in {stencil:?}");
    }
    for name in ["springs", "adjacency", "per_spring"] {
        assert!(!stencil.iter().any(|n| n == name), "{name} in {stencil:?}");
    }
    let (gather, _) = names(Stage::FusedStep, Chunking::ONE, "symplectic_euler");
    assert!(gather.iter().any(|n| n == "springs") && gather.iter().any(|n| n == "adjacency"));
}

#[test]
fn status_layout_matches() {
    check_layout(
        Stage::CheckFinite,
        "Status",
        size_of::<Status>(),
        &[
            ("bad_step", offset_of!(Status, bad_step)),
            ("bad_particle", offset_of!(Status, bad_particle)),
            ("bad_position", offset_of!(Status, bad_position)),
        ],
    );
}

#[test]
fn step_index_layout_matches() {
    let pad = offset_of!(StepIndex, _pad);
    check_layout(
        Stage::CheckFinite,
        "StepIndex",
        size_of::<StepIndex>(),
        &[
            ("step", offset_of!(StepIndex, step)),
            ("_pad0", pad),
            ("_pad1", pad + 4),
            ("_pad2", pad + 8),
        ],
    );
}

#[test]
fn spring_chunk_layout_matches() {
    for stage in [Stage::SpringForces, Stage::Energy, Stage::System] {
        check_layout(
            stage,
            "SpringChunk",
            size_of::<SpringChunk>(),
            &[
                ("base", offset_of!(SpringChunk, base)),
                ("count", offset_of!(SpringChunk, count)),
                ("first_group", offset_of!(SpringChunk, first_group)),
                ("_pad", offset_of!(SpringChunk, _pad)),
            ],
        );
    }
}

/// For k spring chunks, the fused product of A Δv binds 2k + 4 storage buffers (the records'
/// and the blocks' chunks, the adjacency, p, out, diag), fewer than the assembly's gather,
/// which every implicit model runs; that of the CG's direction c binds the constraints and the
/// partial sums besides, 2k + 6, one more than the assembly, and its two-pass gather k + 6, not
/// more than the assembly. So an adapter that can assemble the system can always form both
/// products, fused except the second where its limit is the assembly's exactly
/// (`integrators::implicit_euler::system`).
#[test]
fn the_products_bind_at_most_one_buffer_more_than_the_assembly() {
    let storage = |stage: Stage, chunking: Chunking, entry: &str| {
        let (bindings, _) = reflect(&parsed(stage, chunking), entry).unwrap();
        bindings
            .iter()
            .filter(|b| b.access != Access::Uniform)
            .count()
    };
    for count in 1..=MAX_SPRING_CHUNKS {
        let chunking = Chunking { count, shift: 22 };
        let k = count as usize;
        for (pairs, assembly) in [
            ("", "assemble_particles"),
            ("_with_pairs", "assemble_particles_with_pairs"),
        ] {
            let assembled = storage(Stage::System, chunking, assembly);
            assert_eq!(assembled, 2 * k + 5, "{assembly}, {count} chunk(s)");
            let product = format!("apply_particles{pairs}");
            let curvature = format!("apply_particles{pairs}_curvature");
            for (stage, entry, expected) in [
                (Stage::FusedProduct, &product, 2 * k + 4),
                (Stage::FusedProduct, &curvature, 2 * k + 6),
                (Stage::System, &product, k + 4),
                (Stage::System, &curvature, k + 6),
            ] {
                assert_eq!(
                    storage(stage, chunking, entry),
                    expected,
                    "{entry} in {}, {count} chunk(s)",
                    stage.file()
                );
            }
        }
    }
}

/// The gathering modules composed for several spring chunks validate, and each gathering
/// entry point reads every chunk (`per_spring_1`, …, the blocks' `block_1`, … for
/// `assemble_particles`, the spring records' `spring_1`, … for the fused step's kernels, both
/// records and blocks for the fused product); no other entry point reads one.
#[test]
fn chunked_gathers_validate_and_read_every_chunk() {
    let chunkings = [
        Chunking { count: 2, shift: 8 },
        Chunking {
            count: 4,
            shift: 11,
        },
        Chunking {
            count: MAX_SPRING_CHUNKS,
            shift: 22,
        },
    ];
    for chunking in chunkings {
        for stage in [
            Stage::Forces,
            Stage::System,
            Stage::FusedStep,
            Stage::FusedProduct,
        ] {
            let parsed = parsed(stage, chunking);
            for entry in parsed.entry_points() {
                let (bindings, _) = reflect(&parsed, entry).unwrap();
                let chunk_reads: Vec<String> = bindings
                    .iter()
                    .map(|b| b.name.clone())
                    .filter(|n| {
                        n.rsplit_once('_').is_some_and(|(base, c)| {
                            matches!(base, "per_spring" | "block" | "spring")
                                && c.parse::<u32>().is_ok()
                        })
                    })
                    .collect();
                let extra =
                    |base: &'static str| (1..chunking.count).map(move |c| format!("{base}_{c}"));
                let expected: Vec<String> = match entry {
                    _ if stage == Stage::FusedStep => extra("spring").collect(),
                    _ if stage == Stage::FusedProduct => {
                        extra("spring").chain(extra("block")).collect()
                    }
                    "accelerations"
                    | "accelerations_with_pairs"
                    | "apply_particles"
                    | "apply_particles_with_pairs"
                    | "apply_particles_curvature"
                    | "apply_particles_with_pairs_curvature" => extra("per_spring").collect(),
                    "assemble_particles" | "assemble_particles_with_pairs" => {
                        extra("per_spring").chain(extra("block")).collect()
                    }
                    _ => Vec::new(),
                };
                let mut sorted = chunk_reads.clone();
                sorted.sort();
                let mut expected_sorted = expected.clone();
                expected_sorted.sort();
                assert_eq!(
                    sorted,
                    expected_sorted,
                    "{entry} in {} ({chunking:?})",
                    stage.file()
                );
            }
        }
    }
}

#[test]
fn surface_size_matches_its_array_stride() {
    // The host uploads `SurfaceGpu`s back to back: the WGSL array stride must be the Rust size.
    // (The terrain module's own test checks the members.)
    let (span, _) = wgsl_struct(Stage::Forces, "SurfaceGpu");
    assert_eq!(span as usize, size_of::<SurfaceGpu>());
}

#[test]
fn contact_layouts_match() {
    for stage in [Stage::BroadPhase, Stage::BodyContact, Stage::PairsProbe] {
        check_layout(
            stage,
            "ContactParams",
            size_of::<ContactParams>(),
            &[
                ("inv_cell", offset_of!(ContactParams, inv_cell)),
                ("buckets", offset_of!(ContactParams, buckets)),
                ("restitution", offset_of!(ContactParams, restitution)),
                ("friction", offset_of!(ContactParams, friction)),
                ("friction_model", offset_of!(ContactParams, friction_model)),
                ("penalty", offset_of!(ContactParams, penalty)),
                ("slop", offset_of!(ContactParams, slop)),
                ("exclusion", offset_of!(ContactParams, exclusion)),
            ],
        );
        check_layout(
            stage,
            "ContactParticle",
            size_of::<ContactParticleGpu>(),
            &[
                ("lattice", offset_of!(ContactParticleGpu, lattice)),
                ("body", offset_of!(ContactParticleGpu, body)),
                ("radius", offset_of!(ContactParticleGpu, radius)),
                ("inv_mass", offset_of!(ContactParticleGpu, inv_mass)),
                ("flags", offset_of!(ContactParticleGpu, flags)),
                ("_pad", offset_of!(ContactParticleGpu, _pad)),
            ],
        );
    }
    check_layout(
        Stage::BroadPhase,
        "ScanLevel",
        size_of::<ScanLevel>(),
        &[
            ("offset", offset_of!(ScanLevel, offset)),
            ("count", offset_of!(ScanLevel, count)),
            ("sums", offset_of!(ScanLevel, sums)),
            ("_pad", offset_of!(ScanLevel, _pad)),
        ],
    );
    // The flags' and friction models' values, as the WGSL names them.
    let constant = |name| wgsl_const(Stage::BodyContact, name) as u32;
    assert_eq!(constant("SELF_CONTACT"), ContactParticleGpu::SELF_CONTACT);
    assert_eq!(constant("LATTICE"), ContactParticleGpu::LATTICE);
    assert_eq!(
        constant("FRICTION_COULOMB"),
        crate::layout::FRICTION_COULOMB
    );
    assert_eq!(
        constant("FRICTION_VISCOUS"),
        crate::layout::FRICTION_VISCOUS
    );
}

#[test]
fn spring_block_layout_matches() {
    let pad = offset_of!(SpringBlockGpu, _pad);
    assert_eq!(pad, 24);
    check_layout(
        Stage::System,
        "SpringBlock",
        size_of::<SpringBlockGpu>(),
        &[
            ("u", offset_of!(SpringBlockGpu, u)),
            ("beta", offset_of!(SpringBlockGpu, beta)),
            ("gamma", offset_of!(SpringBlockGpu, gamma)),
            ("resolution", offset_of!(SpringBlockGpu, resolution)),
        ],
    );
}

#[test]
fn cg_scalars_layout_matches() {
    check_layout(
        Stage::Cg,
        "CgScalars",
        size_of::<CgScalars>(),
        &[
            ("delta", offset_of!(CgScalars, delta)),
            ("scale", offset_of!(CgScalars, scale)),
            ("target_delta", offset_of!(CgScalars, target_delta)),
            ("smallest", offset_of!(CgScalars, smallest)),
            ("alpha", offset_of!(CgScalars, alpha)),
            ("beta", offset_of!(CgScalars, beta)),
            ("iterations", offset_of!(CgScalars, iterations)),
            ("done", offset_of!(CgScalars, done)),
            ("tolerance", offset_of!(CgScalars, tolerance)),
            ("max_iterations", offset_of!(CgScalars, max_iterations)),
            ("n_partials", offset_of!(CgScalars, n_partials)),
            ("previous_delta", offset_of!(CgScalars, previous_delta)),
            ("particle_grid", offset_of!(CgScalars, particle_grid)),
            ("spring_grid", offset_of!(CgScalars, spring_grid)),
            ("warm_start", offset_of!(CgScalars, warm_start)),
            ("_pad", offset_of!(CgScalars, _pad)),
        ],
    );
}

#[test]
fn candidate_layout_matches() {
    check_layout(
        Stage::ImplicitEuler,
        "Candidate",
        size_of::<CandidateGpu>(),
        &[
            ("normal", offset_of!(CandidateGpu, normal)),
            ("phi", offset_of!(CandidateGpu, phi)),
            ("friction_dir", offset_of!(CandidateGpu, friction_dir)),
            ("vn_target", offset_of!(CandidateGpu, vn_target)),
            ("lambda_n", offset_of!(CandidateGpu, lambda_n)),
            ("friction", offset_of!(CandidateGpu, friction)),
            ("restitution", offset_of!(CandidateGpu, restitution)),
            ("state", offset_of!(CandidateGpu, state)),
        ],
    );
}

/// The value of a `const` of a module (u32 or f32 literal).
fn wgsl_const(stage: Stage, name: &str) -> f64 {
    let module = parse(stage);
    let (_, c) = module
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no const {name} in {}", stage.file()));
    match module.global_expressions[c.init] {
        naga::Expression::Literal(naga::Literal::U32(v)) => f64::from(v),
        naga::Expression::Literal(naga::Literal::F32(v)) => f64::from(v),
        naga::Expression::Literal(naga::Literal::AbstractInt(v)) => v as f64,
        naga::Expression::Literal(naga::Literal::AbstractFloat(v)) => v,
        ref other => panic!("{name} is not a literal: {other:?}"),
    }
}

/// The activation slack of a resting contact counts the CPU's units of rounding, in f32's.
#[test]
fn resting_slack_matches_the_cpu() {
    assert_eq!(
        wgsl_const(Stage::ImplicitEuler, "RESTING_ULPS"),
        softbody_scene::implicit::RESTING_ULPS
    );
    assert_eq!(
        wgsl_const(Stage::ImplicitEuler, "F32_EPSILON"),
        f64::from(f32::EPSILON)
    );
}

/// The indirect dispatch slots the host dispatches from are those the scalar kernels write, the
/// partial sums it allocates are those the CG indexes, and the constraint codes the host
/// uploads are the shaders'.
#[test]
fn cg_dispatch_slots_and_constraint_codes_match() {
    let words = |name| (wgsl_const(Stage::Cg, name) * 4.0) as u64;
    assert_eq!(words("DISPATCH_PARTICLES"), dispatch_slot::PARTICLES);
    assert_eq!(words("DISPATCH_SPRINGS"), dispatch_slot::SPRINGS);
    assert_eq!(
        words("DISPATCH_FINISHED_PARTICLES"),
        dispatch_slot::FINISHED_PARTICLES
    );
    assert_eq!(
        words("DISPATCH_FINISHED_SPRINGS"),
        dispatch_slot::FINISHED_SPRINGS
    );
    assert_eq!(
        wgsl_const(Stage::Cg, "DISPATCH_WORDS") as usize,
        CG_DISPATCH_WORDS
    );
    // The host allocates the halves the shaders index: the projection's eight, from
    // PROJECTION, are the last.
    assert_eq!(
        wgsl_const(Stage::Cg, "PARTIAL_HALVES") as u64,
        crate::layout::CG_PARTIAL_HALVES
    );
    assert_eq!(
        wgsl_const(Stage::Cg, "PROJECTION") + 8.0,
        wgsl_const(Stage::Cg, "PARTIAL_HALVES")
    );
    use softbody_scene::implicit::Constraint;
    for (name, c) in [
        ("CONSTRAINT_FREE", Constraint::Free),
        ("CONSTRAINT_NORMAL", Constraint::Normal(glam::DVec3::Y)),
        ("CONSTRAINT_FIXED", Constraint::Fixed),
    ] {
        assert_eq!(
            wgsl_const(Stage::Cg, name),
            f64::from(crate::layout::constraint_vec4(c)[3]),
            "{name}"
        );
    }
}
