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
