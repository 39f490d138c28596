//! The harness of the GPU test binaries (libtest-mimic): every test runs when wgpu finds an
//! adapter; without one each reports itself ignored ("skipped: no GPU adapter"), unless
//! `SOFTBODY_REQUIRE_GPU=1`, which makes a missing adapter a failure (CI sets it). Also the
//! terrain the binaries' scenes share.

// Each test binary compiles this module and uses only part of the terrain.
#![allow(dead_code)]

use std::process::ExitCode;

use libtest_mimic::{Arguments, Completion, Failed, Trial};

/// A GPU test.
pub type Test = fn() -> Result<(), Failed>;

/// Runs `tests` under the command line's libtest arguments; `what` names the suite in the line
/// that says which adapter it runs on.
pub fn run(what: &str, tests: Vec<(&'static str, Test)>) -> ExitCode {
    let args = Arguments::from_args();
    let adapter = softbody_gpu::device::Gpu::open().map(|gpu| gpu.name());
    let require = std::env::var("SOFTBODY_REQUIRE_GPU").is_ok_and(|v| v == "1");
    match &adapter {
        Ok(name) => eprintln!("{what} on {name}"),
        Err(e) => eprintln!("{what}: {e}"),
    }
    let trials = tests
        .into_iter()
        .map(|(name, test)| match &adapter {
            Ok(_) => Trial::test(name, test),
            Err(e) if require => {
                let message = format!("SOFTBODY_REQUIRE_GPU=1 but {e}");
                Trial::test(name, move || Err(message.into()))
            }
            Err(_) => Trial::ignorable_test(name, || {
                Ok(Completion::ignored_with("skipped: no GPU adapter"))
            }),
        })
        .collect();
    libtest_mimic::run(&args, trials).exit_code()
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
