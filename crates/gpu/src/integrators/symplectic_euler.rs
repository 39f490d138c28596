//! `shaders/symplectic_euler.wgsl` ↔ `softbody_cpu::integrators::symplectic_euler`:
//! v' = v + h a(x, v), x' = x + h v'.

use super::SingleStage;
use crate::GpuError;
use crate::builder::Setup;
use crate::shaders::Stage;

/// Symplectic Euler: forces, then `symplectic_euler`.
pub(crate) fn new(s: Setup<'_>) -> Result<SingleStage, GpuError> {
    SingleStage::new(s, Stage::SymplecticEuler, "symplectic_euler")
}
