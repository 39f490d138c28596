//! `shaders/energy.wgsl` ↔ `softbody_cpu::energy`: kinetic ½Σ m|v|², gravitational −Σ m g·x
//! and elastic ½Σ k_s(|x_a − x_b| − r)² of the solver's state.
//!
//! Each workgroup sums its particles' (or springs') terms in a fixed tree and writes one
//! partial sum; the host reads the partials back and adds them in order, in f64: the same bits
//! every run on one adapter. The springs' terms are summed per spring chunk over the spring
//! list (`energy_springs`), or on the stencil route, which has none, per particle over the
//! springs starting at its lattice point (`energy_lattices`, twin of
//! `softbody_cpu::energy::energy_lattices`).

use softbody_scene::{Energies, StepError};

use crate::GpuError;
use crate::buffers::{ModelBuffers, Setup, SpringBuffers};
use crate::grid::Grid;
use crate::kernel::Call;
use crate::shaders::Stage;
use crate::submit::Submitter;

/// The energy reductions of the solver's state.
pub(crate) struct Energy {
    particles: Call,
    particle_grid: Grid,
    /// One call per spring chunk, with its grid; on the stencil route one call over the
    /// particles.
    springs: Vec<(Call, Grid)>,
    particle_partials: wgpu::Buffer,
    spring_partials: wgpu::Buffer,
    /// Bytes of the partial sums: 8 per particle workgroup, 4 per spring workgroup.
    particle_bytes: u64,
    spring_bytes: u64,
}

impl Energy {
    /// The reductions of the solver's state, with `spring_groups` partial sums of the springs'
    /// terms.
    pub fn new(s: Setup<'_>, spring_groups: u64) -> Result<Energy, GpuError> {
        let b: &ModelBuffers = s.buffers;
        let springs = match b.springs {
            SpringBuffers::Lattices { .. } => {
                let call = s
                    .builder
                    .call(Stage::Energy, "energy_lattices", &b.resources())?;
                vec![(call, s.particles)]
            }
            SpringBuffers::List(_) => s
                .per_chunk(Stage::Energy, "energy_springs", |_, r| r)?
                .into_iter()
                .zip(s.chunks.grids.iter().copied())
                .collect(),
        };
        Ok(Energy {
            particles: s
                .builder
                .call(Stage::Energy, "energy_particles", &b.resources())?,
            particle_grid: s.particles,
            springs,
            particle_partials: b.particle_partials.clone(),
            spring_partials: b.spring_partials.clone(),
            particle_bytes: s.particles.groups() * 8,
            spring_bytes: spring_groups * 4,
        })
    }

    /// Runs the reductions and adds the partial sums in order.
    pub fn energies(&self, submitter: &mut Submitter) -> Result<Energies, StepError> {
        let encoder = submitter.encode_pass("energies", |pass| {
            self.particles.run(pass, self.particle_grid);
            for (call, grid) in &self.springs {
                call.run(pass, *grid);
            }
        });
        let bytes = submitter.submit_and_read(
            encoder,
            &[
                (&self.particle_partials, self.particle_bytes),
                (&self.spring_partials, self.spring_bytes),
            ],
        )?;
        let (particles, springs) = bytes.split_at(self.particle_bytes as usize);
        let particles: Vec<[f32; 2]> = bytemuck::pod_collect_to_vec(particles);
        let springs: Vec<f32> = bytemuck::pod_collect_to_vec(springs);
        let (mut kinetic, mut gravitational, mut elastic) = (0.0f64, 0.0f64, 0.0f64);
        for p in &particles {
            kinetic += f64::from(p[0]);
            gravitational += f64::from(p[1]);
        }
        for &s in &springs {
            elastic += f64::from(s);
        }
        Ok(Energies {
            kinetic: 0.5 * kinetic,
            gravitational: -gravitational,
            elastic: 0.5 * elastic,
        })
    }
}
