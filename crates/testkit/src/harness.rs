//! The harness of the physics test binaries (libtest-mimic): each law is written once, as a
//! function of a [`Backend`] (and of an [`Integrator`], for laws every method must obey), and
//! runs as one trial per backend and integrator: `cpu::NAME::rk4`, `gpu::NAME::implicit_euler`.
//! A failure names its backend and method, and a filter picks them (`-- gpu::NAME`).
//!
//! Trials have a [`Weight`]. Fast trials always run. Heavy ones (long settling runs on a
//! software adapter: minutes of lavapipe each) carry libtest's ignored flag, so they run under
//! `SOFTBODY_HEAVY=1`, or `-- --include-ignored` / nextest's `--run-ignored all`; heavy GPU
//! trials also run on a hardware adapter, where they take seconds. docs/testing.md says what
//! each tier proves.
//!
//! Without a GPU adapter the `gpu::` trials report themselves ignored ("skipped: no GPU
//! adapter"), unless `SOFTBODY_REQUIRE_GPU=1`, which makes a missing adapter a failure (CI sets
//! it).

use std::process::ExitCode;
use std::sync::{Arc, OnceLock};

use libtest_mimic::{Arguments, Completion, Failed, Trial};
use softbody_gpu::Gpu;
use softbody_scene::Integrator;

use crate::{Backend, Kind};

/// A law checked on one backend.
pub type Test = fn(&Backend) -> Result<(), Failed>;

/// A law checked on one backend with one integrator.
pub type IntegratorTest = fn(&Backend, Integrator) -> Result<(), Failed>;

/// A law checked on one backend for one case of a list (a scene file, say).
pub type CaseTest = fn(&Backend, &str) -> Result<(), Failed>;

/// A GPU-only test, given the shared context.
pub type GpuTest = fn(&Arc<Gpu>) -> Result<(), Failed>;

/// Which tier a trial runs in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weight {
    /// Every run of the suite: seconds on two cores and a software adapter.
    Fast,
    /// Only when asked (`SOFTBODY_HEAVY=1`, `--include-ignored`), or on a hardware GPU.
    Heavy,
}

/// A law of a suite: its name, its test, the integrators it runs with and which of its trials
/// are heavy.
pub struct Law {
    name: &'static str,
    test: LawTest,
    heavy: Vec<(Kind, Option<String>)>,
    backends: Vec<Kind>,
}

enum LawTest {
    Once(Test),
    Each(Vec<Integrator>, IntegratorTest),
    Cases(Vec<String>, CaseTest),
}

/// An integrator as the last part of a trial's name: `rk4`, `implicit_euler`.
fn method(integrator: Integrator) -> String {
    integrator.name().replace('-', "_")
}

impl Law {
    /// A law checked once per backend: trials `cpu::NAME` and `gpu::NAME`.
    pub fn new(name: &'static str, test: Test) -> Law {
        Law {
            name,
            test: LawTest::Once(test),
            heavy: Vec::new(),
            backends: vec![Kind::Cpu, Kind::Gpu],
        }
    }

    /// A law checked with every integrator on every backend: trials `cpu::NAME::explicit_euler`
    /// … `gpu::NAME::implicit_euler`.
    pub fn per_integrator(name: &'static str, test: IntegratorTest) -> Law {
        Law {
            name,
            test: LawTest::Each(Integrator::ALL.to_vec(), test),
            heavy: Vec::new(),
            backends: vec![Kind::Cpu, Kind::Gpu],
        }
    }

    /// A law checked for each of `cases` on every backend: trials `cpu::NAME::CASE` …
    pub fn per_case(name: &'static str, cases: Vec<String>, test: CaseTest) -> Law {
        Law {
            name,
            test: LawTest::Cases(cases, test),
            heavy: Vec::new(),
            backends: vec![Kind::Cpu, Kind::Gpu],
        }
    }

    /// Only with these integrators (a law about the methods that settle, say).
    pub fn integrators(mut self, list: impl IntoIterator<Item = Integrator>) -> Law {
        if let LawTest::Each(integrators, _) = &mut self.test {
            *integrators = list.into_iter().collect();
        }
        self
    }

    /// Only on `kind`: for a law whose run no adapter at hand can finish in a heavy tier's
    /// minutes, so that its GPU bounds have never been measured.
    pub fn only_on(mut self, kind: Kind) -> Law {
        self.backends = vec![kind];
        self
    }

    /// Every trial of the law on `kind` is heavy.
    pub fn heavy_on(mut self, kind: Kind) -> Law {
        self.heavy.push((kind, None));
        self
    }

    /// The trial of `integrator` on `kind` is heavy.
    pub fn heavy_for(mut self, kind: Kind, integrator: Integrator) -> Law {
        self.heavy.push((kind, Some(method(integrator))));
        self
    }

    /// On `kind`, the fast tier takes only the trials of `fast`; the law's other integrators'
    /// trials there are heavy.
    pub fn fast_only_for(mut self, kind: Kind, fast: impl IntoIterator<Item = Integrator>) -> Law {
        let fast: Vec<Integrator> = fast.into_iter().collect();
        for integrator in Integrator::ALL {
            if !fast.contains(&integrator) {
                self = self.heavy_for(kind, integrator);
            }
        }
        self
    }

    /// The trial of `case` on `kind` is heavy.
    pub fn heavy_case(mut self, kind: Kind, case: &str) -> Law {
        self.heavy.push((kind, Some(case.to_owned())));
        self
    }

    /// The weight of its trial on `kind` whose name ends in `case` (an integrator's or a case's
    /// name; `None` for a law checked once).
    pub fn weight(&self, kind: Kind, case: Option<&str>) -> Weight {
        let heavy = self
            .heavy
            .iter()
            .any(|(k, c)| *k == kind && (c.is_none() || c.as_deref() == case));
        if heavy { Weight::Heavy } else { Weight::Fast }
    }

    /// Its trials on both backends.
    fn trials(&self) -> Vec<Trial> {
        let mut trials = Vec::new();
        for &kind in &self.backends {
            let prefix = match kind {
                Kind::Cpu => "cpu",
                Kind::Gpu => "gpu",
            };
            match &self.test {
                LawTest::Once(test) => {
                    let test = *test;
                    let name = format!("{prefix}::{}", self.name);
                    let run = move |backend: &Backend| test(backend);
                    trials.push(trial(kind, name, self.weight(kind, None), run));
                }
                LawTest::Each(integrators, test) => {
                    for &integrator in integrators {
                        let test = *test;
                        let method = method(integrator);
                        let name = format!("{prefix}::{}::{method}", self.name);
                        let weight = self.weight(kind, Some(&method));
                        let run = move |backend: &Backend| test(backend, integrator);
                        trials.push(trial(kind, name, weight, run));
                    }
                }
                LawTest::Cases(cases, test) => {
                    for case in cases {
                        let test = *test;
                        let name = format!("{prefix}::{}::{case}", self.name);
                        let weight = self.weight(kind, Some(case));
                        let case = case.clone();
                        let run = move |backend: &Backend| test(backend, &case);
                        trials.push(trial(kind, name, weight, run));
                    }
                }
            }
        }
        trials
    }
}

/// A trial of `kind`: the CPU's always runs, the GPU's as [`gpu_trial`] decides.
fn trial(
    kind: Kind,
    name: String,
    weight: Weight,
    run: impl FnOnce(&Backend) -> Result<(), Failed> + Send + 'static,
) -> Trial {
    match kind {
        Kind::Cpu => tiered(
            Trial::test(name, move || run(&Backend::cpu())),
            weight,
            kind,
        ),
        Kind::Gpu => gpu_trial(name, weight, move |gpu| run(&Backend::gpu(gpu.clone()))),
    }
}

/// Marks a heavy trial (its kind shows as `[heavy]`) and gives it the ignored flag unless the
/// heavy tier is on for `kind`.
fn tiered(trial: Trial, weight: Weight, kind: Kind) -> Trial {
    match weight {
        Weight::Fast => trial,
        Weight::Heavy => trial
            .with_kind("heavy")
            .with_ignored_flag(!heavy_tier_runs(kind)),
    }
}

/// Whether heavy trials of `kind` run without being asked for by name: with
/// `SOFTBODY_HEAVY=1`, and on the GPU when the adapter is hardware (not lavapipe or llvmpipe).
fn heavy_tier_runs(kind: Kind) -> bool {
    if std::env::var("SOFTBODY_HEAVY").is_ok_and(|v| v == "1") {
        return true;
    }
    kind == Kind::Gpu
        && shared_gpu()
            .as_ref()
            .is_ok_and(|gpu| gpu.info.device_type != wgpu::DeviceType::Cpu)
}

/// The device of the test binary, opened once; the error says why there is none.
fn shared_gpu() -> &'static Result<Arc<Gpu>, String> {
    static GPU: OnceLock<Result<Arc<Gpu>, String>> = OnceLock::new();
    GPU.get_or_init(|| Gpu::open().map_err(|e| e.to_string()))
}

/// Whether a missing adapter fails the GPU tests (`SOFTBODY_REQUIRE_GPU=1`).
fn gpu_required() -> bool {
    std::env::var("SOFTBODY_REQUIRE_GPU").is_ok_and(|v| v == "1")
}

/// A trial that needs the GPU: run when there is one; without, ignored, or failed when
/// required.
fn gpu_trial(
    name: String,
    weight: Weight,
    test: impl FnOnce(&Arc<Gpu>) -> Result<(), Failed> + Send + 'static,
) -> Trial {
    match shared_gpu() {
        Ok(_) => tiered(
            Trial::test(name, move || {
                let gpu = shared_gpu().as_ref().map_err(|e| Failed::from(e.clone()))?;
                test(gpu)
            }),
            weight,
            Kind::Gpu,
        ),
        Err(e) if gpu_required() => {
            let message = format!("SOFTBODY_REQUIRE_GPU=1 but {e}");
            Trial::test(name, move || Err(message.into()))
        }
        Err(_) => Trial::ignorable_test(name, || {
            Ok(Completion::ignored_with("skipped: no GPU adapter"))
        }),
    }
}

/// Says which adapter the GPU trials of `suite` run on, or why they do not run.
fn announce(suite: &str) {
    match shared_gpu() {
        Ok(gpu) => eprintln!("{suite}: GPU tests on {}", gpu.name()),
        Err(e) => eprintln!("{suite}: {e}"),
    }
}

/// Runs every trial of `laws` under the command line's libtest arguments.
pub fn run(suite: &str, laws: impl IntoIterator<Item = Law>) -> ExitCode {
    let args = Arguments::from_args();
    announce(suite);
    let trials = laws.into_iter().flat_map(|law| law.trials()).collect();
    libtest_mimic::run(&args, trials).exit_code()
}

/// Runs GPU-only tests (each given the binary's shared context) under the command line's
/// libtest arguments: `(name, test)` pairs, plain [`GpuTest`] functions or closures (one test
/// per case of a table, say). All of them are fast: a twin runs a stage once or a few steps.
pub fn run_gpu<N, F>(suite: &str, tests: impl IntoIterator<Item = (N, F)>) -> ExitCode
where
    N: Into<String>,
    F: FnOnce(&Arc<Gpu>) -> Result<(), Failed> + Send + 'static,
{
    let args = Arguments::from_args();
    announce(suite);
    let trials = tests
        .into_iter()
        .map(|(name, test)| gpu_trial(name.into(), Weight::Fast, test))
        .collect();
    libtest_mimic::run(&args, trials).exit_code()
}
