//! The adapter's limits: a scene the GPU cannot hold is refused before anything is allocated,
//! with the limit named and the figures ([`GpuError::Limit`]).
//!
//! Not chunked, and refused past one binding: the per-particle arrays (random access by every
//! kernel; 8.4 M particles per 128 MiB of `vec4`, 4.2 M for implicit Euler's preconditioner,
//! 2.8 M for its 48-byte contact records) and the CSR adjacency (n + 1 + 2m words: 16.7 M
//! springs per 128 MiB). The per-spring arrays are chunked ([`crate::chunks`]) up to what one
//! kernel may bind. On the stencil route ([`crate::buffers::Route`]) there is neither an
//! adjacency nor a per-spring array: the solver checks the lattice tables in their place and
//! chunks no springs.

use softbody_scene::{Model, State};

use crate::chunks::{
    BLOCK_CHUNK_BINDING, Chunking, MAX_SPRING_CHUNKS, PER_SPRING_CHUNK_BINDING, plan_chunks,
};
use crate::grid::Grid;
use crate::{GpuError, WORKGROUP_SIZE};

/// A storage buffer the scene needs: what it holds, elements, bytes per element.
pub(crate) struct Need {
    pub what: &'static str,
    pub count: u64,
    pub stride: u64,
}

impl Need {
    fn bytes(&self) -> u64 {
        self.count.saturating_mul(self.stride)
    }
}

fn limit_error(
    adapter: &str,
    limit: &'static str,
    what: String,
    needed: String,
    available: String,
) -> GpuError {
    GpuError::Limit {
        adapter: adapter.to_owned(),
        limit,
        what,
        needed,
        available,
    }
}

/// Refuses a scene whose values the GPU's f32 cannot hold: a position, velocity, gravity,
/// time step, mass or spring parameter beyond f32's range (|x| > 3.4e38), or a non-zero one
/// that rounds to zero (a time step, a mass, a rest length below 1.2e-38, which the kernels
/// divide by). Without it such a scene runs on infinities and writes frame 0 with no numbers.
pub(crate) fn check_f32(model: &Model, state: &State) -> Result<(), GpuError> {
    let refuse = |what: String, value: f64| {
        Err(GpuError::Unsupported(format!(
            "{what} = {value:e} does not fit in f32, in which the GPU computes (|x| from \
             {:e} to {:e}); use --backend cpu (f64)",
            f32::MIN_POSITIVE,
            f32::MAX
        )))
    };
    // A value that is already infinite or NaN (a state handed over by `set_state`) is the
    // solver's to report as an instability, as the CPU does: only finite values that f32 loses
    // are refused.
    let fits = |x: f64| !x.is_finite() || (x as f32).is_finite();
    let divisor = |x: f64| fits(x) && (x == 0.0 || (x as f32).abs() >= f32::MIN_POSITIVE);
    for (i, (x, v)) in state.x.iter().zip(&state.v).enumerate() {
        if let Some(c) = x.to_array().into_iter().find(|&c| !fits(c)) {
            return refuse(
                format!("a position coordinate of particle {i}, in metres,"),
                c,
            );
        }
        if let Some(c) = v.to_array().into_iter().find(|&c| !fits(c)) {
            return refuse(format!("a velocity component of particle {i}, in m/s,"), c);
        }
    }
    for (i, &m) in model.mass.iter().enumerate() {
        if !divisor(m) {
            return refuse(format!("the mass of particle {i}, in kg,"), m);
        }
    }
    let sim = &model.simulation;
    if let Some(c) = sim.gravity.to_array().into_iter().find(|&c| !fits(c)) {
        return refuse("a gravity component, in m/s²,".to_owned(), c);
    }
    if !divisor(sim.dt) {
        return refuse("dt, in seconds,".to_owned(), sim.dt);
    }
    // Streamed, not listed: a lattice body's springs exist only as its stencil, and the
    // stencil route never builds the list (a 300³ cube's would take 13.7 GB).
    let mut first_bad = None;
    let mut s = 0u64;
    model.for_each_spring(|_, _, r, k, d| {
        if first_bad.is_none() {
            first_bad = if !fits(k) {
                Some((s, "stiffness, in N/m,", k))
            } else if !fits(d) {
                Some((s, "damping, in N·s/m,", d))
            } else if !divisor(r) {
                Some((s, "rest length, in metres,", r))
            } else {
                None
            };
        }
        s += 1;
    });
    if let Some((s, what, value)) = first_bad {
        return refuse(format!("the {what} of spring {s}"), value);
    }
    Ok(())
}

/// Refuses a scene that exceeds the adapter's limits, naming the limit and the figures.
pub(crate) fn check_limits(
    limits: &wgpu::Limits,
    adapter: &str,
    needs: &[Need],
    readback_bytes: u64,
    threads: &[(&'static str, u64)],
) -> Result<(), GpuError> {
    // What every kernel needs whatever the scene: checked first, as they say the adapter cannot
    // run the solver at all.
    let fixed: [(&'static str, u64, u64, &str); 6] = [
        (
            "max_compute_invocations_per_workgroup",
            u64::from(limits.max_compute_invocations_per_workgroup),
            WORKGROUP_SIZE,
            "threads per workgroup",
        ),
        (
            "max_compute_workgroup_size_x",
            u64::from(limits.max_compute_workgroup_size_x),
            WORKGROUP_SIZE,
            "threads along x",
        ),
        (
            "max_compute_workgroup_storage_size",
            u64::from(limits.max_compute_workgroup_storage_size),
            WORKGROUP_SIZE * 8,
            "bytes of workgroup memory (the energy reduction)",
        ),
        (
            "max_storage_buffers_per_shader_stage",
            u64::from(limits.max_storage_buffers_per_shader_stage),
            8,
            "storage buffers (the force kernel)",
        ),
        (
            "max_bind_groups",
            u64::from(limits.max_bind_groups),
            2,
            "bind groups",
        ),
        (
            "max_bindings_per_bind_group",
            u64::from(limits.max_bindings_per_bind_group),
            // The limit bounds binding numbers, not counts: system.wgsl numbers up to 13.
            14,
            "binding numbers in one group (0 to 13)",
        ),
    ];
    for (limit, available, needed, unit) in fixed {
        if available < needed {
            return Err(limit_error(
                adapter,
                limit,
                "the solver's kernels".to_owned(),
                format!("{needed} {unit}"),
                format!("{available}"),
            ));
        }
    }
    for need in needs {
        let bytes = need.bytes();
        for (limit, available) in [
            (
                "max_storage_buffer_binding_size",
                limits.max_storage_buffer_binding_size,
            ),
            ("max_buffer_size", limits.max_buffer_size),
        ] {
            if bytes > available {
                return Err(limit_error(
                    adapter,
                    limit,
                    format!(
                        "the {} buffer ({} × {} bytes)",
                        need.what, need.count, need.stride
                    ),
                    format!("{bytes} bytes"),
                    format!("{available} bytes"),
                ));
            }
        }
    }
    if readback_bytes > limits.max_buffer_size {
        return Err(limit_error(
            adapter,
            "max_buffer_size",
            "the read-back buffer (positions and velocities)".to_owned(),
            format!("{readback_bytes} bytes"),
            format!("{} bytes", limits.max_buffer_size),
        ));
    }
    let max_dim = limits.max_compute_workgroups_per_dimension;
    for &(what, count) in threads {
        if Grid::new(count, max_dim).is_none() {
            return Err(limit_error(
                adapter,
                "max_compute_workgroups_per_dimension",
                format!("one thread per {what} ({count})"),
                format!(
                    "{} workgroups of {WORKGROUP_SIZE}",
                    count.div_ceil(WORKGROUP_SIZE)
                ),
                format!("{max_dim} × {max_dim} workgroups"),
            ));
        }
    }
    Ok(())
}

/// The bytes one per-spring chunk may have: the smaller of the binding and buffer limits, and
/// which limit that is.
fn chunk_cap(limits: &wgpu::Limits) -> (&'static str, u64) {
    let binding = limits.max_storage_buffer_binding_size;
    if binding <= limits.max_buffer_size {
        ("max_storage_buffer_binding_size", binding)
    } else {
        ("max_buffer_size", limits.max_buffer_size)
    }
}

/// How to split `springs` springs whose widest per-spring element has `stride` bytes (20, or
/// 32 with implicit Euler's blocks, `implicit`), or why they cannot be split on this adapter,
/// naming the limit and the figures.
pub(crate) fn check_chunks(
    limits: &wgpu::Limits,
    adapter: &str,
    springs: u64,
    stride: u64,
    implicit: bool,
) -> Result<Chunking, GpuError> {
    let (cap_limit, cap) = chunk_cap(limits);
    let Some(chunking) = plan_chunks(springs, stride, cap) else {
        return Err(limit_error(
            adapter,
            cap_limit,
            format!("a chunk of {WORKGROUP_SIZE} springs ({stride} bytes each)"),
            format!("{} bytes", WORKGROUP_SIZE * stride),
            format!("{cap} bytes"),
        ));
    };
    if chunking.count == 1 {
        return Ok(chunking);
    }
    let k = chunking.count;
    let what = || {
        format!(
            "{springs} springs ({stride} bytes each) in {k} chunks of {} (one per {cap}-byte binding, the {cap_limit})",
            1u64 << chunking.shift
        )
    };
    if k > MAX_SPRING_CHUNKS {
        return Err(limit_error(
            adapter,
            cap_limit,
            what(),
            format!("{k} chunks"),
            format!("{cap} bytes per binding, for at most {MAX_SPRING_CHUNKS} chunks"),
        ));
    }
    // The force gather binds x, v, adjacency, mass, a, two terrain buffers and every chunk of
    // the per-spring vectors; implicit Euler's assembly v, adjacency, mass, b, diag and every
    // chunk of the vectors and of the blocks.
    let storage = if implicit {
        (7 + k).max(5 + 2 * k)
    } else {
        7 + k
    };
    if storage > limits.max_storage_buffers_per_shader_stage {
        return Err(limit_error(
            adapter,
            "max_storage_buffers_per_shader_stage",
            what(),
            format!("{storage} storage buffers in one kernel (the per-particle gather)"),
            format!("{}", limits.max_storage_buffers_per_shader_stage),
        ));
    }
    let first = if implicit {
        BLOCK_CHUNK_BINDING
    } else {
        PER_SPRING_CHUNK_BINDING
    };
    let bindings = first + k - 1;
    if bindings > limits.max_bindings_per_bind_group {
        return Err(limit_error(
            adapter,
            "max_bindings_per_bind_group",
            what(),
            format!("binding numbers up to {}", bindings - 1),
            format!("{}", limits.max_bindings_per_bind_group),
        ));
    }
    Ok(chunking)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values beyond f32's range are refused, naming what and where; a scene in range passes.
    #[test]
    fn values_beyond_f32_are_refused() {
        let scene = |velocity: &str, gravity: &str, mass: &str| {
            let text = format!(
                "[simulation]\ndt = 0.001\nduration = 0.01\ngravity = {gravity}\n\
                 [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]\n\
                 masses = [1.0, {mass}]\nvelocities = [{velocity}, [0.0, 0.0, 0.0]]\n\
                 springs = [{{ a = 0, b = 1, stiffness = 10.0 }}]\n"
            );
            let scene = softbody_scene::Scene::from_toml(&text, "t.toml".as_ref()).unwrap();
            let (model, state) = Model::build(&scene);
            check_f32(&model, &state).map_err(|e| e.to_string())
        };
        let ok = "[0.0, 0.0, 0.0]";
        assert_eq!(scene(ok, "[0.0, -9.81, 0.0]", "1.0"), Ok(()));
        let e = scene("[1e40, 0.0, 0.0]", "[0.0, -9.81, 0.0]", "1.0").unwrap_err();
        assert!(
            e.starts_with("a velocity component of particle 0, in m/s, = 1e40"),
            "{e}"
        );
        assert!(e.contains("--backend cpu"), "{e}");
        let e = scene(ok, "[0.0, -1e300, 0.0]", "1.0").unwrap_err();
        assert!(e.starts_with("a gravity component"), "{e}");
        let e = scene(ok, "[0.0, -9.81, 0.0]", "1e-50").unwrap_err();
        assert!(e.starts_with("the mass of particle 1"), "{e}");
    }

    /// A lattice body's spring beyond f32 is named by its index in `Model::springs`' order,
    /// found by streaming the springs: the model builds no spring list for the check.
    #[test]
    fn springs_beyond_f32_are_refused_without_listing_them() {
        let cuboid = |name: &str, x: f64, bending: f64| {
            format!(
                "[[body]]\nname = \"{name}\"\nkind = \"cuboid\"\nsize = [0.1, 0.1, 0.1]\n\
                 resolution = [3, 3, 3]\ncenter = [{x}, 0.5, 0.0]\nmass = 1.0\n\
                 bending = {{ stiffness = {bending:e} }}\n"
            )
        };
        let text = format!(
            "[simulation]\ndt = 0.001\nduration = 0.01\n{}{}",
            cuboid("a", 0.0, 100.0),
            cuboid("b", 1.0, 1e39)
        );
        let scene = softbody_scene::Scene::from_toml(&text, "t.toml".as_ref()).unwrap();
        let (model, state) = Model::build(&scene);
        let lean = model.memory_bytes();
        let e = check_f32(&model, &state).unwrap_err().to_string();
        assert_eq!(
            model.memory_bytes(),
            lean,
            "the check built the spring list"
        );
        let springs = model.springs();
        let first = (0..springs.len())
            .find(|&s| springs.stiffness[s] == 1e39)
            .unwrap();
        assert!(
            first > 0 && springs.a[first] >= 27,
            "in the second body: {first}"
        );
        assert!(
            e.starts_with(&format!("the stiffness, in N/m, of spring {first} = 1e39")),
            "{e}"
        );
    }

    /// Bytes of a `vec4<f32>`.
    const VEC4: u64 = 16;

    fn needs(particles: u64) -> Vec<Need> {
        vec![Need {
            what: "positions",
            count: particles,
            stride: VEC4,
        }]
    }

    #[test]
    fn limits_are_named_with_their_figures() {
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: 1 << 27,
            ..wgpu::Limits::default()
        };
        let ok = check_limits(&limits, "test adapter", &needs(1 << 23), 0, &[]);
        assert_eq!(ok, Ok(()));
        let e = check_limits(&limits, "test adapter", &needs((1 << 23) + 1), 0, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffer_binding_size"), "{e}");
        assert!(
            e.contains("the positions buffer (8388609 × 16 bytes) needs 134217744 bytes"),
            "{e}"
        );
        assert!(e.contains("test adapter allows 134217728 bytes"), "{e}");
        assert!(e.contains("--backend cpu"), "{e}");

        let e = check_limits(
            &limits,
            "a",
            &[],
            0,
            &[("spring", 65_535u64 * 65_535 * 256 + 1)],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("max_compute_workgroups_per_dimension"), "{e}");

        let small = wgpu::Limits {
            max_storage_buffers_per_shader_stage: 4,
            ..wgpu::Limits::default()
        };
        let e = check_limits(&small, "a", &[], 0, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffers_per_shader_stage"), "{e}");
        assert!(e.contains("needs 8 storage buffers"), "{e}");

        let e = check_limits(&limits, "a", &[], limits.max_buffer_size + 1, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_buffer_size"), "{e}");
    }

    #[test]
    fn chunks_past_what_a_kernel_can_bind_are_refused_with_the_figures() {
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: 1 << 27,
            max_buffer_size: 1 << 30,
            max_storage_buffers_per_shader_stage: 16,
            ..wgpu::Limits::default()
        };
        // 4 chunks: the force gather binds 11, implicit Euler's assembly 13 storage buffers.
        let ok = check_chunks(&limits, "a", 15_700_000, 20, false).unwrap();
        assert_eq!(ok.count, 4);
        assert_eq!(
            check_chunks(&limits, "a", 15_700_000, 32, true)
                .unwrap()
                .count,
            4
        );
        // 6 chunks: 13 for the force gather, but 17 for the implicit assembly.
        let m = 6 * (1 << 22) - 1;
        assert_eq!(check_chunks(&limits, "a", m, 20, false).unwrap().count, 6);
        let e = check_chunks(&limits, "GL adapter", m, 32, true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffers_per_shader_stage"), "{e}");
        assert!(
            e.contains("25165823 springs (32 bytes each) in 6 chunks of 4194304"),
            "{e}"
        );
        assert!(e.contains("needs 17 storage buffers"), "{e}");
        assert!(e.contains("GL adapter allows 16"), "{e}");
        // More chunks than the gathers have bindings for.
        let wide = wgpu::Limits {
            max_storage_buffers_per_shader_stage: 64,
            ..limits.clone()
        };
        let e = check_chunks(&wide, "a", 17 << 22, 20, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_storage_buffer_binding_size"), "{e}");
        assert!(e.contains("needs 17 chunks"), "{e}");
        // The smaller of the binding and buffer limits is named.
        let small_buffers = wgpu::Limits {
            max_buffer_size: 1000,
            ..limits
        };
        let e = check_chunks(&small_buffers, "a", 1_000_000, 20, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_buffer_size"), "{e}");
        assert!(
            e.contains("a chunk of 256 springs (20 bytes each) needs 5120 bytes"),
            "{e}"
        );
    }
}
