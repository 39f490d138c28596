//! What the GPU test binaries share: the terrain of their scenes, and their errors as test
//! failures.

// Each test binary compiles this module and uses only part of it.
#![allow(dead_code)]

use softbody_scene::StepError;
use softbody_testkit::Failed;

/// A step error as a test failure.
pub fn step_error(e: StepError) -> Failed {
    e.to_string().into()
}

/// A level plane, friction 0.5, no restitution: landing particles stay in the contact band.
pub const PLANE: &str = r#"
[[terrain]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
friction = 0.5
restitution = 0.0
"#;

/// The plane with restitution: landing particles bounce up to the edge of the contact band.
pub const BOUNCY_PLANE: &str = r#"
[[terrain]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
friction = 0.5
restitution = 0.2
"#;

/// A plane tilted about 22° (normal (0.4, 1, 0)), friction 0.3: particles slide.
pub const SLOPE: &str = r#"
[[terrain]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.4, 1.0, 0.0]
friction = 0.3
restitution = 0.0
"#;

/// The scale of implicit Euler's right-hand side at each particle, which the GPU's b is
/// compared against: h(m|g| + drag·m|v_i| + Σ_{s ∋ i} |g_s|), with g_s = f_s − h K_s (v_a − v_b)
/// the per-spring terms of the assembly (docs/physics.md), computed here from the model's springs
/// (the CPU's assembly keeps no per-spring terms on lattices).
pub fn rhs_scale(model: &softbody_scene::Model, x: &[glam::DVec3], v: &[glam::DVec3]) -> Vec<f64> {
    let sim = &model.simulation;
    let h = sim.dt;
    let sp = model.springs();
    let terms: Vec<f64> = (0..sp.len())
        .map(|s| {
            let (a, b) = (sp.a[s] as usize, sp.b[s] as usize);
            let (ks, kd, rest) = (sp.stiffness[s], sp.damping[s], sp.rest[s]);
            let f = softbody_cpu::spring_forces::spring_force(x[a], x[b], v[a], v[b], rest, ks, kd);
            // K w = k_s[(1 − α)(u·w)u + α w], α = max(0, 1 − r/ℓ).
            let (d, w) = (x[a] - x[b], v[a] - v[b]);
            let len = d.length();
            let (u, alpha) = match len > 0.0 {
                true => (d / len, (1.0 - rest / len).max(0.0)),
                false => (glam::DVec3::ZERO, 0.0),
            };
            let kw = ks * ((1.0 - alpha) * u.dot(w) * u + alpha * w);
            (f - h * kw).length()
        })
        .collect();
    (0..model.len())
        .map(|i| {
            let m = model.mass[i];
            let springs: f64 = model
                .adjacency()
                .of(i)
                .iter()
                .map(|&e| terms[(e >> 1) as usize])
                .sum();
            h * (m * sim.gravity.length() + sim.drag * m * v[i].length() + springs)
        })
        .collect()
}

/// The scale of the product A p at each particle:
/// m(1 + h·drag)|p_i| + Σ_{s ∋ i} (β_s + γ_s)(|p_a| + |p_b|), where β_s + γ_s = h k_d + h² k_s
/// whatever the spring's state.
pub fn product_scale(model: &softbody_scene::Model, p: &[glam::DVec3]) -> Vec<f64> {
    let sim = &model.simulation;
    let (h, sp) = (sim.dt, model.springs());
    (0..model.len())
        .map(|i| {
            let springs: f64 = model
                .adjacency()
                .of(i)
                .iter()
                .map(|&e| {
                    let s = (e >> 1) as usize;
                    (h * sp.damping[s] + h * h * sp.stiffness[s])
                        * (p[sp.a[s] as usize].length() + p[sp.b[s] as usize].length())
                })
                .sum();
            model.mass[i] * (1.0 + h * sim.drag) * p[i].length() + springs
        })
        .collect()
}

/// The inverse diagonal block of one particle from the GPU's `diag` pair read back
/// (P⁻¹xx, P⁻¹yy, P⁻¹zz, m(1 + h·drag), P⁻¹xy, P⁻¹xz, P⁻¹yz, 0).
pub fn inverse_block(d: [f32; 8]) -> glam::DMat3 {
    let d = d.map(f64::from);
    glam::DMat3::from_cols_array(&[d[0], d[4], d[5], d[4], d[1], d[6], d[5], d[6], d[2]])
}
