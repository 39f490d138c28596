//! Tests of the WGSL that need no adapter: every composed module parses and validates with
//! naga, its bindings match the host's tables, its entry points have the workgroup size the host
//! dispatches for, and every struct shared with the host has the Rust twin's layout.

use std::mem::{offset_of, size_of};

use naga::valid::{Capabilities, ValidationFlags, Validator};

use crate::layout::{Params, SpringGpu, Status, StepIndex};
use crate::shaders::{Access, Stage, TERRAIN_BINDINGS};
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
