//! softbody's test kit (dev-only): what the physics tests of every backend share.
//!
//! - [`harness`]: the harness of a test binary (libtest-mimic). Each [`Law`] is written once,
//!   as a function of a [`Backend`] (and an integrator), and runs as one trial per backend and
//!   integrator, fast or heavy ([`Weight`]). [`run_gpu`] runs suites that only make sense on
//!   the GPU (stage twins against the CPU) the same way.
//! - [`Backend`]: opens solvers (the CPU's in one shared rayon pool, the GPU's on one shared
//!   device), and says how precise the backend is ([`Backend::epsilon`],
//!   [`Backend::tolerance`], [`Backend::roundoff`]).
//! - [`scenes`]: scene builders, so each test states its physical set-up next to the closed
//!   form it checks.
//! - [`Rng`]: the one deterministic random generator of the tests (PCG-64, seeded).
//! - [`compare_states`]: a state against another within a tolerance; on a mismatch both are
//!   written under `target/test-artifacts/` with the worst particles named.

pub mod harness;
pub mod scenes;

pub use harness::{CaseTest, GpuTest, IntegratorTest, Law, Test, Weight, run, run_gpu};

use std::sync::{Arc, OnceLock};

use glam::DVec3;
pub use libtest_mimic::Failed;
use rand::{RngExt, SeedableRng};
use softbody_cpu::CpuSolver;
use softbody_gpu::{Gpu, GpuSolver};
use softbody_scene::{Model, Scene, Solver, State};

/// Which backend a test runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The CPU reference solver, f64.
    Cpu,
    /// The wgpu solver, f32.
    Gpu,
}

/// A relative and an absolute tolerance: `got` agrees with `expected` at `scale` when
/// |got − expected| ≤ rel·scale + abs. The scale is the magnitude of the quantity's terms, not
/// its value, which may be a near-cancellation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    /// Relative to the scale.
    pub rel: f64,
    /// Absolute, in the quantity's unit.
    pub abs: f64,
}

impl Tolerance {
    /// The largest difference allowed at `scale`.
    pub fn bound(self, scale: f64) -> f64 {
        self.rel * scale + self.abs
    }

    /// Whether `error` is within the bound at `scale`.
    pub fn allows(self, error: f64, scale: f64) -> bool {
        error <= self.bound(scale)
    }
}

/// A backend, with what its tests share: the CPU's thread pool, the GPU's device.
pub struct Backend {
    kind: Kind,
    gpu: Option<Arc<Gpu>>,
}

/// The CPU pool of the tests: one thread (the tests' systems are small; determinism across
/// thread counts is tested with pools of its own).
fn cpu_pool() -> Arc<rayon::ThreadPool> {
    static POOL: OnceLock<Arc<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .expect("a one-thread pool"),
        )
    })
    .clone()
}

impl Backend {
    /// The CPU backend.
    pub fn cpu() -> Backend {
        Backend {
            kind: Kind::Cpu,
            gpu: None,
        }
    }

    /// The GPU backend on `gpu`.
    pub fn gpu(gpu: Arc<Gpu>) -> Backend {
        Backend {
            kind: Kind::Gpu,
            gpu: Some(gpu),
        }
    }

    /// Which it is.
    pub fn kind(&self) -> Kind {
        self.kind
    }

    /// Whether it is the GPU.
    pub fn is_gpu(&self) -> bool {
        self.kind == Kind::Gpu
    }

    /// `"cpu"` or `"gpu"`.
    pub fn name(&self) -> &'static str {
        match self.kind {
            Kind::Cpu => "cpu",
            Kind::Gpu => "gpu",
        }
    }

    /// A solver for `scene`.
    pub fn solver(&self, scene: &Scene) -> Result<Box<dyn Solver>, Failed> {
        let (model, state) = Model::build(scene);
        self.solver_from(model, state)
    }

    /// A solver for `model` from `state`.
    pub fn solver_from(&self, model: Model, state: State) -> Result<Box<dyn Solver>, Failed> {
        match &self.gpu {
            None => Ok(Box::new(CpuSolver::in_pool(model, state, cpu_pool()))),
            Some(gpu) => Ok(Box::new(
                GpuSolver::on(gpu, model, state).map_err(|e| e.to_string())?,
            )),
        }
    }

    /// The GPU context (`None` on the CPU).
    pub fn context(&self) -> Option<&Arc<Gpu>> {
        self.gpu.as_ref()
    }

    /// Machine epsilon of the backend's arithmetic: 2⁻⁵² (f64) or 2⁻²³ (f32).
    pub fn epsilon(&self) -> f64 {
        match self.kind {
            Kind::Cpu => f64::EPSILON,
            Kind::Gpu => f64::from(f32::EPSILON),
        }
    }

    /// How closely one evaluation of a stage agrees with its closed form (or its twin) on this
    /// backend: 1e-12 relative on the CPU, 1e-5 on the GPU (about 170 f32 roundings: a stage is
    /// a few dozen operations), each with an absolute floor a thousand times smaller.
    pub fn tolerance(&self) -> Tolerance {
        match self.kind {
            Kind::Cpu => Tolerance {
                rel: 1e-12,
                abs: 1e-15,
            },
            Kind::Gpu => Tolerance {
                rel: 1e-5,
                abs: 1e-8,
            },
        }
    }

    /// The relative tolerance the backend's implicit-Euler CG solves to (preconditioned
    /// residual): 1e-8 on the CPU, 1e-5 in f32 on the GPU.
    pub fn cg_tolerance(&self) -> f64 {
        match self.kind {
            Kind::Cpu => softbody_cpu::integrators::implicit_euler::CG_TOLERANCE,
            Kind::Gpu => f64::from(softbody_gpu::CG_TOLERANCE_F32),
        }
    }

    /// The rounding a quantity of magnitude `scale` gathers over `steps` steps: 2·ε·scale·√steps.
    /// Each step rounds the state a few times, and the roundings of independent steps add like
    /// a random walk. Measured on lavapipe, the f32 runs of the integrator tests drift by 0.1 to
    /// 0.25 of ε·scale·√steps: the factor 2 leaves a margin of 8 for other adapters' rounding
    /// (fused multiply-adds, other orders). Tests add it to their analytic bounds: on the CPU
    /// it is far below every one of them, on the GPU it is what f32 can resolve.
    pub fn roundoff(&self, scale: f64, steps: u64) -> f64 {
        2.0 * self.epsilon() * scale * (steps as f64).sqrt()
    }
}

/// `Err(message)` unless `ok`: a check that reports what was measured.
pub fn ensure(ok: bool, message: impl FnOnce() -> String) -> Result<(), Failed> {
    if ok { Ok(()) } else { Err(message().into()) }
}

/// The failures collected over the cases of a test, reported together so that one run shows
/// the numbers of all of them.
pub fn all(failures: Vec<String>) -> Result<(), Failed> {
    ensure(failures.is_empty(), || format!("\n{}", failures.join("\n")))
}

/// The one deterministic random generator of the tests: PCG-64 from a seed, so every run draws
/// the same numbers.
pub struct Rng(rand_pcg::Pcg64);

impl Rng {
    /// Seeded.
    pub fn new(seed: u64) -> Rng {
        Rng(rand_pcg::Pcg64::seed_from_u64(seed))
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        self.0.random()
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in [−1, 1).
    pub fn signed(&mut self) -> f64 {
        self.range(-1.0, 1.0)
    }

    /// Each coordinate uniform in [−s, s).
    pub fn vec(&mut self, s: f64) -> DVec3 {
        DVec3::new(self.signed(), self.signed(), self.signed()) * s
    }

    /// Uniform in the box [lo, hi).
    pub fn in_box(&mut self, lo: DVec3, hi: DVec3) -> DVec3 {
        DVec3::new(
            self.range(lo.x, hi.x),
            self.range(lo.y, hi.y),
            self.range(lo.z, hi.z),
        )
    }

    /// A uniformly distributed unit vector (rejection sampling in the unit ball).
    pub fn direction(&mut self) -> DVec3 {
        loop {
            let v = self.vec(1.0);
            let l = v.length();
            if l > 0.1 && l <= 1.0 {
                return v / l;
            }
        }
    }

    /// Uniform index in 0..n (n > 0).
    pub fn index(&mut self, n: usize) -> usize {
        ((self.unit() * n as f64) as usize).min(n - 1)
    }
}

/// Where a test's evidence goes: `target/test-artifacts/<test>/`, beside the test binary's
/// target directory.
pub fn artifacts_dir(test: &str) -> std::path::PathBuf {
    let exe = std::env::current_exe().unwrap_or_default();
    // target/<profile>/deps/<binary>
    let target = exe
        .ancestors()
        .nth(3)
        .map(std::path::Path::to_path_buf)
        .unwrap_or_else(|| "target".into());
    target.join("test-artifacts").join(test.replace("::", "-"))
}

/// The largest per-particle difference of positions and of velocities between two states.
pub fn max_difference(a: &State, b: &State) -> (f64, f64) {
    let worst = |p: &[DVec3], q: &[DVec3]| {
        p.iter()
            .zip(q)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0f64, f64::max)
    };
    (worst(&a.x, &b.x), worst(&a.v, &b.v))
}

/// Compares `got` with `expected` particle by particle: positions within `x` and velocities
/// within `v` at their scales (the largest |x| and |v| of `expected`). On a mismatch both
/// states are written as JSON under [`artifacts_dir`]`(test)` and the message names the worst
/// particles.
pub fn compare_states(
    test: &str,
    (expected_label, expected): (&str, &State),
    (got_label, got): (&str, &State),
    x: Tolerance,
    v: Tolerance,
) -> Result<(), Failed> {
    let scale = |p: &[DVec3]| p.iter().map(|p| p.length()).fold(0.0f64, f64::max);
    let (x_scale, v_scale) = (scale(&expected.x), scale(&expected.v));
    let worst = |p: &[DVec3], q: &[DVec3]| {
        p.iter()
            .zip(q)
            .enumerate()
            .map(|(i, (p, q))| (i, (*p - *q).length()))
            .fold((0, 0.0f64), |a, b| if b.1 > a.1 { b } else { a })
    };
    let (xi, dx) = worst(&expected.x, &got.x);
    let (vi, dv) = worst(&expected.v, &got.v);
    let lengths = expected.x.len() == got.x.len() && expected.v.len() == got.v.len();
    if lengths && x.allows(dx, x_scale) && v.allows(dv, v_scale) {
        return Ok(());
    }
    let dir = artifacts_dir(test);
    let written = std::fs::create_dir_all(&dir).and_then(|()| {
        for (label, state) in [(expected_label, expected), (got_label, got)] {
            let json = serde_json::json!({
                "x": state.x.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
                "v": state.v.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
            });
            std::fs::write(dir.join(format!("{label}.json")), json.to_string())?;
        }
        Ok(())
    });
    let evidence = match written {
        Ok(()) => format!("both states are in {}", dir.display()),
        Err(e) => format!("(could not write the states to {}: {e})", dir.display()),
    };
    Err(format!(
        "{got_label} differs from {expected_label}: {} particles against {}; worst position \
         particle {xi}, |Δx| = {dx:.3e} m (allowed {:.3e} at scale {x_scale:.3e}); worst \
         velocity particle {vi}, |Δv| = {dv:.3e} m/s (allowed {:.3e}); {evidence}",
        got.x.len(),
        expected.x.len(),
        x.bound(x_scale),
        v.bound(v_scale),
    )
    .into())
}

/// What one implicit-Euler step's CG residual can change the momentum by, at the state
/// (`x`, `v`) the backend reached: |Σ r_i| ≤ √n·ρ·√(λmax(P)/λmin(P))·‖b‖, with ρ the backend's
/// CG tolerance, P the block-Jacobi preconditioner (λmin at least the mass part: the springs'
/// blocks are positive semi-definite) and b the step's right-hand side, both assembled with the
/// CPU's `System`.
pub fn cg_momentum_bound(
    backend: &Backend,
    system: &mut softbody_cpu::integrators::implicit_euler::system::System,
    model: &Model,
    x: &[DVec3],
    v: &[DVec3],
) -> f64 {
    let n = model.len();
    let mut b = vec![DVec3::ZERO; n];
    system.assemble(model, (None, None), x, v, &mut b);
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for i in 0..n {
        let d = system.diag[i];
        let block = nalgebra::Matrix3::from_fn(|r, c| d.col(c)[r]);
        lo = lo.min(system.mass_diag[i]);
        hi = hi.max(block.symmetric_eigenvalues().max());
    }
    let norm_b = b.iter().map(|b| b.length_squared()).sum::<f64>().sqrt();
    (n as f64).sqrt() * backend.cg_tolerance() * (hi / lo).sqrt() * norm_b
}
