//! The GPU backend from the command line: without a usable adapter the run stops before
//! writing anything, says which backends it tried and what to do, and exits with status 4.

mod common;

use std::process::{Command, Output, Stdio};

use common::{Sandbox, entries};

/// One falling particle: any backend runs it.
const ONE_PARTICLE: &str = "[simulation]\ndt = 0.001\nduration = 0.01\n\n[[body]]\n\
                            kind = \"particles\"\npositions = [[0.0, 1.0, 0.0]]\nmasses = [1.0]\n";

/// `softbody ARGS` in `sandbox` with `WGPU_BACKEND=metal`, which on a machine without Metal (any
/// Linux) leaves wgpu no adapter at all, whatever drivers are installed: the one way to test
/// the missing-adapter path everywhere.
fn without_an_adapter(sandbox: &Sandbox, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_softbody"))
        .args(args)
        .current_dir(sandbox.path())
        .env("WGPU_BACKEND", "metal")
        .stdin(Stdio::null())
        .output()
        .expect("the softbody binary starts")
}

#[test]
#[cfg(target_os = "linux")]
fn no_adapter_exits_4_with_advice_and_writes_nothing() {
    let sandbox = Sandbox::new();
    sandbox.write("scene.toml", ONE_PARTICLE);
    let out_dir = sandbox.mkdir("frames");
    let args = [
        "run",
        "scene.toml",
        "--backend",
        "gpu",
        "--out",
        "frames/f.jsonl",
    ];
    let out = without_an_adapter(&sandbox, &args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "stderr: {stderr}");
    for hint in [
        "backends tried",
        "WGPU_BACKEND",
        "mesa-vulkan-drivers",
        "--backend cpu",
    ] {
        assert!(
            stderr.to_lowercase().contains(&hint.to_lowercase()),
            "names `{hint}`: {stderr}"
        );
    }
    assert!(
        entries(&out_dir).is_empty(),
        "nothing written: {:?}",
        entries(&out_dir)
    );
}

/// `render --backend gpu` simulates on the GPU: without an adapter it stops with status 4 before
/// drawing anything.
#[test]
#[cfg(target_os = "linux")]
fn render_takes_the_backend() {
    let sandbox = Sandbox::new();
    sandbox.write("scene.toml", ONE_PARTICLE);
    let args = [
        "render",
        "scene.toml",
        "--backend",
        "gpu",
        "--out",
        "p",
        "-q",
    ];
    let out = without_an_adapter(&sandbox, &args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "stderr: {stderr}");
    assert!(!sandbox.path().join("p").exists(), "nothing drawn");
}
