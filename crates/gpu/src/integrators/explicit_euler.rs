//! `shaders/explicit_euler.wgsl` ↔ `softbody_cpu::integrators::explicit_euler`:
//! x' = x + h v, v' = v + h a(x, v).

use super::SingleStage;
use crate::GpuError;
use crate::builder::Setup;
use crate::shaders::Stage;

/// Explicit Euler: forces, then `explicit_euler`.
pub(crate) fn new(s: Setup<'_>) -> Result<SingleStage, GpuError> {
    SingleStage::new(s, Stage::ExplicitEuler, "explicit_euler")
}
