//! Tests of the WGSL that need no adapter: every composed module parses and validates with
//! naga, its bindings match the host's tables, its entry points have the workgroup size the host
//! dispatches for, and every struct shared with the host has the Rust twin's layout.

use std::mem::{offset_of, size_of};

use naga::valid::{Capabilities, ValidationFlags, Validator};

use crate::layout::{
    CG_DISPATCH_WORDS, CandidateGpu, CgScalars, Params, SpringBlockGpu, SpringChunk, SpringGpu,
    Status, StepIndex, dispatch_slot,
};
use crate::shaders::{Access, Chunking, MAX_SPRING_CHUNKS, Stage, TERRAIN_BINDINGS};
use crate::terrain::SurfaceGpu;

fn parse(stage: Stage) -> naga::Module {
    let source = stage.source();
    naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| {
        panic!(
            "{} does not parse:\n{}",
            stage.file(),
            e.emit_to_string_with_path(&source, stage.file())
        )
    })
}

#[test]
fn every_composed_module_parses_and_validates() {
    for stage in Stage::ALL {
        let module = parse(stage);
        let source = stage.source();
        if let Err(e) =
            Validator::new(ValidationFlags::all(), Capabilities::default()).validate(&module)
        {
            panic!(
                "{} does not validate:\n{}",
                stage.file(),
                e.emit_to_string(&source)
            );
        }
    }
}

#[test]
fn bindings_match_the_host_tables() {
    for stage in Stage::ALL {
        let module = parse(stage);
        let mut found: Vec<(u32, u32, Access)> = module
            .global_variables
            .iter()
            .filter_map(|(_, var)| {
                let binding = var.binding.as_ref()?;
                let access = match var.space {
                    naga::AddressSpace::Uniform => Access::Uniform,
                    naga::AddressSpace::Storage { access } => {
                        if access.contains(naga::StorageAccess::STORE) {
                            Access::ReadWrite
                        } else {
                            Access::Read
                        }
                    }
                    other => panic!("{}: unexpected address space {other:?}", stage.file()),
                };
                Some((binding.group, binding.binding, access))
            })
            .collect();
        found.sort_by_key(|&(g, b, _)| (g, b));
        // WGSL does not say whether a uniform is bound at a dynamic offset.
        let mut expected: Vec<(u32, u32, Access)> = stage
            .bindings()
            .iter()
            .map(|&(b, a)| match a {
                Access::DynamicUniform => (0, b, Access::Uniform),
                a => (0, b, a),
            })
            .collect();
        if stage.uses_terrain() {
            expected.extend(TERRAIN_BINDINGS.iter().map(|&(b, a)| (1, b, a)));
        }
        assert_eq!(found, expected, "bindings of {}", stage.file());
    }
}

#[test]
fn entry_points_exist_with_the_dispatched_workgroup_size() {
    for stage in Stage::ALL {
        let module = parse(stage);
        for &name in stage.entry_points() {
            let ep = module
                .entry_points
                .iter()
                .find(|ep| ep.name == name)
                .unwrap_or_else(|| panic!("{} has no entry point {name}", stage.file()));
            assert_eq!(ep.stage, naga::ShaderStage::Compute);
            let expected = [crate::WORKGROUP_SIZE as u32, 1, 1];
            assert_eq!(ep.workgroup_size, expected, "{name} in {}", stage.file());
        }
        assert_eq!(module.entry_points.len(), stage.entry_points().len());
    }
}

/// Each entry point uses exactly the bindings of its [`Stage::kernel`] table (for the stages
/// with per-entry layouts; for the others, a subset of the module's), its terrain group only if
/// the table says so, and at most 8 storage buffers (WebGPU's guaranteed minimum per stage).
#[test]
fn entry_points_use_their_kernel_bindings() {
    for stage in Stage::ALL {
        let module = parse(stage);
        let info = Validator::new(ValidationFlags::all(), Capabilities::default())
            .validate(&module)
            .expect("validates");
        for (index, ep) in module.entry_points.iter().enumerate() {
            let uses = info.get_entry_point(index);
            let mut used: Vec<(u32, u32)> = module
                .global_variables
                .iter()
                .filter(|&(handle, var)| var.binding.is_some() && !uses[handle].is_empty())
                .map(|(_, var)| {
                    let b = var.binding.as_ref().unwrap();
                    (b.group, b.binding)
                })
                .collect();
            used.sort();
            let kernel = stage.kernel(&ep.name);
            let mut declared: Vec<(u32, u32)> = kernel.bindings.iter().map(|&b| (0, b)).collect();
            if kernel.terrain {
                declared.extend(TERRAIN_BINDINGS.iter().map(|&(b, _)| (1, b)));
            }
            let name = format!("{} in {}", ep.name, stage.file());
            if stage.per_entry_layouts() {
                // Binding 0 (params) is in every layout, used or not.
                let used_or_params: Vec<(u32, u32)> = if used.contains(&(0, 0)) {
                    used.clone()
                } else {
                    std::iter::once((0, 0))
                        .chain(used.iter().copied())
                        .collect()
                };
                assert_eq!(used_or_params, declared, "bindings of {name}");
            } else {
                for b in &used {
                    assert!(declared.contains(b), "{name} uses {b:?} outside its layout");
                }
            }
            let storage = stage
                .kernel_bindings(&kernel)
                .iter()
                .filter(|(_, a)| matches!(a, Access::Read | Access::ReadWrite))
                .count()
                + if kernel.terrain {
                    TERRAIN_BINDINGS.len()
                } else {
                    0
                };
            assert!(storage <= 8, "{name} binds {storage} storage buffers");
        }
    }
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

/// The gathering modules composed for several spring chunks validate, and each gathering entry
/// point uses exactly its kernel's bindings plus [`Stage::chunk_bindings`] (every chunk bound is
/// read, none read unbound); the other entry points are unchanged.
#[test]
fn chunked_gathers_validate_and_read_every_chunk() {
    let chunkings = [
        Chunking::ONE,
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
        for stage in [Stage::Forces, Stage::System] {
            let source = stage.source_chunked(chunking);
            let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| {
                panic!(
                    "{} ({chunking:?}) does not parse:\n{}",
                    stage.file(),
                    e.emit_to_string(&source)
                )
            });
            let info = Validator::new(ValidationFlags::all(), Capabilities::default())
                .validate(&module)
                .unwrap_or_else(|e| {
                    panic!(
                        "{} ({chunking:?}) does not validate:\n{}",
                        stage.file(),
                        e.emit_to_string(&source)
                    )
                });
            for (index, ep) in module.entry_points.iter().enumerate() {
                let uses = info.get_entry_point(index);
                let mut used: Vec<u32> = module
                    .global_variables
                    .iter()
                    .filter(|&(handle, _)| !uses[handle].is_empty())
                    .filter_map(|(_, var)| var.binding.as_ref())
                    .filter(|b| b.group == 0 && b.binding != 0)
                    .map(|b| b.binding)
                    .collect();
                used.sort();
                let kernel = stage.kernel(&ep.name);
                let extra = stage.chunk_bindings(&ep.name, chunking);
                assert_eq!(extra.len() % (chunking.count as usize - 1).max(1), 0);
                let mut expected: Vec<u32> = kernel
                    .bindings
                    .iter()
                    .copied()
                    .chain(extra.iter().map(|&(b, _)| b))
                    .filter(|&b| b != 0)
                    .collect();
                expected.sort();
                let name = format!("{} in {} ({chunking:?})", ep.name, stage.file());
                if stage.per_entry_layouts() {
                    assert_eq!(used, expected, "bindings of {name}");
                } else {
                    for b in &used {
                        assert!(expected.contains(b), "{name} uses {b} outside its layout");
                    }
                    for &(b, _) in &extra {
                        assert!(used.contains(&b), "{name} does not read chunk binding {b}");
                    }
                }
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
fn locate_maps_composed_lines_back_to_files() {
    for stage in Stage::ALL {
        let source = stage.source();
        let pieces = stage.pieces();
        let mut headers = 0;
        for (k, line) in source.lines().enumerate() {
            // The generated chunk accessors come after every piece.
            if line.starts_with("// ---- generated") {
                break;
            }
            match stage.locate(k + 1) {
                Some((file, l)) => {
                    let text = pieces.iter().find(|(f, _)| *f == file).unwrap().1;
                    assert_eq!(text.lines().nth(l - 1), Some(line), "{file}:{l}");
                }
                None => {
                    assert!(line.starts_with("// ---- shaders/"), "line {}", k + 1);
                    headers += 1;
                }
            }
        }
        assert_eq!(headers, pieces.len());
    }
}

#[test]
fn spring_block_layout_matches() {
    let pad = offset_of!(SpringBlockGpu, _pad);
    assert_eq!(pad, 20);
    check_layout(
        Stage::System,
        "SpringBlock",
        size_of::<SpringBlockGpu>(),
        &[
            ("u", offset_of!(SpringBlockGpu, u)),
            ("beta", offset_of!(SpringBlockGpu, beta)),
            ("gamma", offset_of!(SpringBlockGpu, gamma)),
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
            ("_pad", offset_of!(CgScalars, _pad)),
            ("particle_grid", offset_of!(CgScalars, particle_grid)),
            ("spring_grid", offset_of!(CgScalars, spring_grid)),
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

/// The indirect dispatch slots the host dispatches from are those the scalar kernels write, and
/// the constraint codes the host uploads are the shaders'.
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
    use softbody_scene::implicit::Constraint;
    for (name, c) in [
        ("CONSTRAINT_FREE", Constraint::Free),
        ("CONSTRAINT_NORMAL", Constraint::Normal(glam::DVec3::Y)),
        ("CONSTRAINT_FIXED", Constraint::Fixed),
    ] {
        assert_eq!(
            wgsl_const(Stage::Cg, name),
            f64::from(crate::implicit::constraint_vec4(c)[3]),
            "{name}"
        );
    }
}
