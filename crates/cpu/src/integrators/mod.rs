//! Time integrators. Each advances the state by one step h = dt; the explicit family
//! (explicit Euler, symplectic Euler, midpoint, RK4) evaluates accelerations (gravity, drag,
//! springs, [`crate::contact`]) and ends with [`crate::collision_response`]; implicit Euler
//! handles contact inside its solve.
//!
//! Each integrator is a type owning its scratch, one module each; [`Stepper`] holds the one a
//! run uses. Adding an integrator is a module here, a variant of [`Stepper`], and its WGSL twin
//! on the GPU (see ARCHITECTURE.md, "Add an integrator").
//!
//! Each explicit stage is one fused `pipeline::pass`: spring forces at the stage's (x, v),
//! then per particle its acceleration and the stage update, written to other arrays than the
//! ones read ([`Passes`] double-buffers the state). The last stage also applies the collision
//! response and checks finiteness (`finish`). Updates have no reductions, so any split gives
//! the same bits.

pub mod explicit_euler;
pub mod implicit_euler;
pub mod midpoint;
pub mod rk4;
pub mod symplectic_euler;

use glam::DVec3;
use softbody_scene::{History, Integrator, Model, State, Statistics, StepError, Timings};
use softbody_terrain::{PlaneGeometry, Surface};

use crate::body_contact::{External, NoPairs, PairForces, Partners};
use crate::collision_response::respond_one;
use crate::forces::{acceleration_of, acceleration_with};
use crate::pipeline::{PerParticle, Plan, RowUpdate, pass_rows};
use crate::spring_forces::stencil::Row;
use crate::spring_forces::{Isa, Kernel};
use crate::vec_bytes;

/// The integrator of a run with its scratch.
pub enum Stepper {
    /// [`explicit_euler`]: its scratch is the passes'.
    ExplicitEuler(Passes),
    /// [`symplectic_euler`]: its scratch is the passes'.
    SymplecticEuler(Passes),
    /// [`midpoint`].
    Midpoint(midpoint::Midpoint),
    /// [`rk4`].
    Rk4(rk4::Rk4),
    /// [`implicit_euler`].
    ImplicitEuler(Box<implicit_euler::ImplicitEuler>),
}

/// The stage the explicit integrators' fused passes are timed as.
pub const EXPLICIT_STAGE: &str = "fused passes";

impl Stepper {
    /// The model's integrator, sized for it. Call it in the thread pool that will step it: the
    /// passes split the particles by its thread count.
    pub fn new(model: &Model) -> Stepper {
        match model.simulation.integrator {
            Integrator::ExplicitEuler => Stepper::ExplicitEuler(Passes::new(model)),
            Integrator::SymplecticEuler => Stepper::SymplecticEuler(Passes::new(model)),
            Integrator::Midpoint => Stepper::Midpoint(midpoint::Midpoint::new(model)),
            Integrator::Rk4 => Stepper::Rk4(rk4::Rk4::new(model)),
            Integrator::ImplicitEuler => {
                Stepper::ImplicitEuler(Box::new(implicit_euler::ImplicitEuler::new(model)))
            }
        }
    }

    /// Advances `state` by one step with the forces between particles of the bodies in
    /// contact `pairs` and the `external` forces on each particle (a control input), timing its
    /// stages into `timings`, and returns the first particle with a non-finite position or
    /// velocity afterwards, and which it is.
    pub fn step(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        (pairs, external): (Option<&Partners>, Option<&[DVec3]>),
        state: &mut State,
        timings: &mut Timings,
    ) -> Option<(usize, &'static str)> {
        // Each integrator once for each combination of forces between particles and external
        // forces: without both, rows update side by side.
        macro_rules! with_pairs {
            (|$q:ident| $body:expr) => {
                match (pairs, external) {
                    (None, None) => {
                        let $q = &NoPairs;
                        $body
                    }
                    (Some($q), None) => $body,
                    (None, Some(forces)) => {
                        let $q = &External {
                            forces,
                            inner: &NoPairs,
                        };
                        $body
                    }
                    (Some(inner), Some(forces)) => {
                        let $q = &External { forces, inner };
                        $body
                    }
                }
            };
        }
        let explicit = |timings: &mut Timings, step: &mut dyn FnMut() -> Option<usize>| {
            timings.time(EXPLICIT_STAGE, step)
        };
        let bad = match self {
            Stepper::ExplicitEuler(p) => explicit(timings, &mut || {
                with_pairs!(|q| explicit_euler::step(p, model, surfaces, q, state))
            }),
            Stepper::SymplecticEuler(p) => explicit(timings, &mut || {
                with_pairs!(|q| symplectic_euler::step(p, model, surfaces, q, state))
            }),
            Stepper::Midpoint(s) => explicit(timings, &mut || {
                with_pairs!(|q| s.step(model, surfaces, q, state))
            }),
            Stepper::Rk4(s) => explicit(timings, &mut || {
                with_pairs!(|q| s.step(model, surfaces, q, state))
            }),
            Stepper::ImplicitEuler(s) => {
                s.step(model, surfaces, (pairs, external), state, timings);
                return timings.time("finiteness", || crate::first_non_finite(state));
            }
        };
        bad.map(|i| (i, crate::non_finite_what(state, i)))
    }

    /// Implicit Euler's contacts with the terrain in its last step, as its final solve held
    /// them, and the step's Δv; nothing for the others.
    pub(crate) fn implicit_step(&self) -> (&[implicit_euler::Candidate], &[DVec3]) {
        match self {
            Stepper::ImplicitEuler(s) => (s.contacts(), s.dv()),
            _ => (&[], &[]),
        }
    }

    /// Bytes of scratch held on the heap.
    pub fn memory_bytes(&self) -> u64 {
        match self {
            Stepper::ExplicitEuler(p) | Stepper::SymplecticEuler(p) => p.memory_bytes(),
            Stepper::Midpoint(s) => s.memory_bytes(),
            Stepper::Rk4(s) => s.memory_bytes(),
            Stepper::ImplicitEuler(s) => s.memory_bytes(),
        }
    }

    /// What the next step starts from besides the state (nothing for the explicit
    /// integrators).
    pub fn history(&self) -> History {
        match self {
            Stepper::ImplicitEuler(s) => s.history(),
            _ => History::default(),
        }
    }

    /// Takes up [`Stepper::history`]'s.
    pub fn restore(&mut self, model: &Model, history: &History) -> Result<(), StepError> {
        match self {
            Stepper::ImplicitEuler(s) => s.restore(model, history),
            _ if history.parts.is_empty() => Ok(()),
            _ => Err(StepError::Invalid(
                "restore: the history is an implicit integrator's, this solver's integrator is \
                 explicit"
                    .to_owned(),
            )),
        }
    }

    /// The integrator's own counters (implicit Euler's CG iterations and solves; zero for the
    /// others).
    pub fn statistics(&self) -> Statistics {
        let kernel = |p: &Passes| p.plan.kernel_name();
        match self {
            Stepper::ImplicitEuler(s) => Statistics {
                kernel: s.kernel_name(),
                ..s.statistics.clone()
            },
            Stepper::ExplicitEuler(p) | Stepper::SymplecticEuler(p) => Statistics {
                kernel: kernel(p),
                ..Statistics::default()
            },
            Stepper::Midpoint(s) => Statistics {
                kernel: kernel(s.passes()),
                ..Statistics::default()
            },
            Stepper::Rk4(s) => Statistics {
                kernel: kernel(s.passes()),
                ..Statistics::default()
            },
        }
    }
}

/// What every explicit integrator holds: the fused passes' plan for the model and the second
/// state buffer a pass writes the next state into (the buffers are then swapped).
pub struct Passes {
    plan: Plan,
    kernel: Kernel,
    /// The instructions of the Euler methods' row updates ([`EulerRows`]); None: particle by
    /// particle.
    pub(crate) rows: Option<Isa>,
    next_x: Vec<DVec3>,
    next_v: Vec<DVec3>,
}

impl Passes {
    /// Sized and planned for `model`, in the current thread pool.
    pub(crate) fn new(model: &Model) -> Passes {
        let n = model.len();
        let plan = Plan::new(model);
        let kernel = plan.kernel(model);
        Passes {
            plan,
            kernel,
            rows: Some(Isa::detect()),
            next_x: vec![DVec3::ZERO; n],
            next_v: vec![DVec3::ZERO; n],
        }
    }

    /// Bytes held on the heap.
    pub(crate) fn memory_bytes(&self) -> u64 {
        self.plan.memory_bytes() + vec_bytes(&self.next_x) + vec_bytes(&self.next_v)
    }

    /// One step of a single-stage Euler method in one fused pass: spring forces, then per
    /// particle the gathered forces, gravity, drag and contact, `update(x, v, a, h) -> (x', v')`,
    /// the collision response and the finiteness check. Returns the first particle that is not
    /// finite.
    pub(crate) fn euler_step<P: PairForces>(
        &mut self,
        model: &Model,
        surfaces: &[Surface],
        pairs: &P,
        state: &mut State,
        update: impl Fn(DVec3, DVec3, DVec3, f64) -> (DVec3, DVec3) + Sync,
    ) -> Option<usize> {
        let h = model.simulation.dt;
        let (x, v) = (&state.x[..], &state.v[..]);
        let stage = Stage {
            scene: (model, surfaces, pairs),
            input: (x, v),
            start: (x, v),
            last: true,
            update: |_, x, v, a| update(x, v, a, h),
        };
        let outputs = (&mut self.next_x[..], &mut self.next_v[..]);
        let bad = stage.pass((&mut self.plan, self.kernel, self.rows), outputs);
        self.swap_into(state);
        bad
    }

    /// The plan, the kernel and the second state buffer, apart: the stages of a multi-stage
    /// method run their own passes (RK4 alternates the buffer with its stage buffer).
    pub(crate) fn parts(&mut self) -> (&mut Plan, Kernel, &mut Vec<DVec3>, &mut Vec<DVec3>) {
        (
            &mut self.plan,
            self.kernel,
            &mut self.next_x,
            &mut self.next_v,
        )
    }

    /// Makes the second state buffer the state.
    pub(crate) fn swap_into(&mut self, state: &mut State) {
        std::mem::swap(&mut state.x, &mut self.next_x);
        std::mem::swap(&mut state.v, &mut self.next_v);
    }
}

/// A stage of an explicit integrator that writes a pair of per-particle arrays: at the stage
/// state `input` (x_s, v_s), with a = a(x_s, v_s), each particle's outputs are
/// `update(i, x_s, v_s, a)`; the `last` stage's are the new (x, v), which then take the
/// collision response (from the step's `start`) and the finiteness check.
pub(crate) struct Stage<'a, P, U> {
    pub(crate) scene: (&'a Model, &'a [Surface], &'a P),
    pub(crate) input: (&'a [DVec3], &'a [DVec3]),
    pub(crate) start: (&'a [DVec3], &'a [DVec3]),
    pub(crate) last: bool,
    pub(crate) update: U,
}

impl<P, U> Stage<'_, P, U>
where
    P: PairForces,
    U: Fn(usize, DVec3, DVec3, DVec3) -> (DVec3, DVec3) + Sync,
{
    /// The stage in one fused pass into `outputs`, by whole grid rows where they apply (`rows`:
    /// their instructions, None for particle by particle); returns the first particle that is
    /// not finite.
    pub(crate) fn pass(
        &self,
        (plan, kernel, rows): (&mut Plan, Kernel, Option<Isa>),
        outputs: (&mut [DVec3], &mut [DVec3]),
    ) -> Option<usize> {
        let (model, surfaces, _) = self.scene;
        let planes: Option<Vec<&PlaneGeometry>> = surfaces.iter().map(Surface::plane).collect();
        match (planes, rows) {
            (Some(planes), Some(isa)) if P::NONE => {
                let rows = StageRows {
                    stage: self,
                    planes,
                    isa,
                };
                pass_rows(
                    plan,
                    kernel,
                    model,
                    self.input,
                    outputs,
                    &rows,
                    // Inlined into the pass's loops: a call per particle costs more than the
                    // update.
                    #[inline(always)]
                    |i, springs, out| self.particle(i, springs, out),
                )
            }
            _ => pass_rows(
                plan,
                kernel,
                model,
                self.input,
                outputs,
                &PerParticle,
                #[inline(always)]
                |i, springs, out| self.particle(i, springs, out),
            ),
        }
    }

    /// Particle i's outputs, its spring forces' sum `springs` given; false if the last stage
    /// leaves it not finite.
    #[inline(always)]
    fn particle(&self, i: usize, springs: DVec3, (o1, o2): (&mut DVec3, &mut DVec3)) -> bool {
        let (model, surfaces, pairs) = self.scene;
        let (xs, vs) = self.input;
        let f = springs + pairs.force(model, i, xs, vs);
        let a = acceleration_with(model, surfaces, i, xs[i], vs[i], f);
        (*o1, *o2) = (self.update)(i, xs[i], vs[i], a);
        let (x, v) = self.start;
        !self.last || finish(model, surfaces, i, (x[i], v[i]), o1, o2)
    }
}

/// A [`Stage`]'s update of a grid row on the stencil route, where no forces act between
/// particles and every surface is a plane: a lane clear of every plane (φ ≥ ε) at the stage
/// state meets no contact force, and one also clear at its new position after the last stage
/// meets no collision response, so its outputs are the per-particle update's arithmetic with
/// [`acceleration_of`] without surfaces: the same bits. Those lanes run side by side in vector
/// registers; the others, and any lane the last stage leaves not finite, are left to the
/// per-particle update.
struct StageRows<'s, 'a, P, U> {
    stage: &'s Stage<'a, P, U>,
    planes: Vec<&'a PlaneGeometry>,
    isa: Isa,
}

impl<'o, P, U> RowUpdate<(&'o mut [DVec3], &'o mut [DVec3])> for StageRows<'_, '_, P, U>
where
    P: PairForces,
    U: Fn(usize, DVec3, DVec3, DVec3) -> (DVec3, DVec3) + Sync,
{
    fn row(
        &self,
        row: &Row<'_>,
        (o1, o2): &mut (&'o mut [DVec3], &'o mut [DVec3]),
        at: usize,
        todo: &mut [bool],
    ) {
        let n = row.len();
        let (o1, o2) = (&mut o1[at..at + n], &mut o2[at..at + n]);
        #[cfg(target_arch = "x86_64")]
        match self.isa {
            // SAFETY: the CPU has AVX-512F (`Isa::detect`; the tests take only what `runs`).
            Isa::Avx512 => return unsafe { self.row_avx512(row, o1, o2, todo) },
            // SAFETY: the CPU has AVX2 (as above).
            Isa::Avx2 => return unsafe { self.row_avx2(row, o1, o2, todo) },
            Isa::Scalar => {}
        }
        self.lanes(row, o1, o2, todo);
    }
}

impl<P, U> StageRows<'_, '_, P, U>
where
    P: PairForces,
    U: Fn(usize, DVec3, DVec3, DVec3) -> (DVec3, DVec3) + Sync,
{
    /// [`StageRows::lanes`] compiled for AVX-512.
    ///
    /// # Safety
    /// The CPU has AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn row_avx512(
        &self,
        row: &Row<'_>,
        o1: &mut [DVec3],
        o2: &mut [DVec3],
        todo: &mut [bool],
    ) {
        self.lanes(row, o1, o2, todo);
    }

    /// [`StageRows::lanes`] compiled for AVX2.
    ///
    /// # Safety
    /// The CPU has AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn row_avx2(
        &self,
        row: &Row<'_>,
        o1: &mut [DVec3],
        o2: &mut [DVec3],
        todo: &mut [bool],
    ) {
        self.lanes(row, o1, o2, todo);
    }

    /// Every lane's outputs into `o1`, `o2` (the row's), and in `todo` whether the
    /// per-particle update must redo it: branch-free loops over the row, which the compiler
    /// vectorises.
    #[inline(always)]
    fn lanes(&self, row: &Row<'_>, o1: &mut [DVec3], o2: &mut [DVec3], todo: &mut [bool]) {
        let n = row.len();
        let (model, _, _) = self.stage.scene;
        let (sim, last) = (&model.simulation, self.stage.last);
        let eps = sim.contact_distance;
        let mass = &model.mass[row.p0..row.p0 + n];
        let inv_mass = &model.inv_mass[row.p0..row.p0 + n];
        // Two rows ahead (the rows of a slab follow one another in the arrays).
        prefetch(model.mass.get(row.p0 + 2 * n..row.p0 + 3 * n));
        prefetch(model.inv_mass.get(row.p0 + 2 * n..row.p0 + 3 * n));
        let (o1, o2, todo) = (&mut o1[..n], &mut o2[..n], &mut todo[..n]);
        for i in 0..n {
            let (x, v, springs) = row.particle(i);
            let a = acceleration_of(sim, (mass[i], inv_mass[i]), &[], x, v, springs);
            (o1[i], o2[i]) = (self.stage.update)(row.p0 + i, x, v, a);
            todo[i] = last & !all_finite(o1[i], o2[i]);
        }
        for plane in &self.planes {
            for i in 0..n {
                let (x, _, _) = row.particle(i);
                todo[i] |= !(plane.clear_of(x, eps) & (!last | plane.clear_of(o1[i], eps)));
            }
        }
    }
}

/// Asks for `ahead` in the cache: the row update waited on the masses' loads at 100³ (with
/// the prefetch two rows ahead, +4–8% on one thread, BENCHMARKS.md).
#[inline]
pub(crate) fn prefetch<T>(ahead: Option<&[T]>) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let bytes = std::mem::size_of_val(ahead.unwrap_or(&[]));
        let start = ahead.map_or(std::ptr::null(), |a| a.as_ptr().cast::<i8>());
        for line in (0..bytes).step_by(64) {
            // SAFETY: a prefetch of an address inside the slice.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(start.add(line)) };
        }
    }
}

/// The end of an explicit step for particle i, which started it at `x_start`: its collision
/// response (unless it is pinned), then whether its position and velocity are finite.
#[inline(always)]
pub(crate) fn finish(
    model: &Model,
    surfaces: &[Surface],
    i: usize,
    start: (DVec3, DVec3),
    x: &mut DVec3,
    v: &mut DVec3,
) -> bool {
    let eps = model.simulation.contact_distance;
    // Clear of every surface (and with none): the response would change nothing.
    if !surfaces.iter().all(|s| s.clear_of(*x, eps)) && model.inv_mass[i] != 0.0 {
        respond_one(surfaces, eps, model.simulation.dt, start, x, v);
    }
    all_finite(*x, *v)
}

/// `x.is_finite() && v.is_finite()` in a few instructions: c − c is +0 for a finite c and NaN
/// for an infinite or NaN one, so the six differences sum to 0 exactly when all are finite.
#[inline(always)]
#[allow(clippy::eq_op, reason = "c − c is the test")]
fn all_finite(x: DVec3, v: DVec3) -> bool {
    let d = (x - x) + (v - v);
    d.x + d.y + d.z == 0.0
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use glam::DVec3;
    use softbody_scene::{Integrator, Model, Scene, State};
    use softbody_terrain::Surface;

    use super::midpoint::Midpoint;
    use super::{Isa, Passes, all_finite};
    use crate::body_contact::NoPairs;

    /// Cuboids of `resolutions` (one body each) on two planes that cut through them, every
    /// particle moved and moving differently, a few pinned, one with an infinite velocity if
    /// `blow_up`.
    fn scene_on_planes(resolutions: &[[u32; 3]], blow_up: bool) -> (Model, State, Vec<Surface>) {
        let mut text = String::from(
            "[simulation]\nintegrator = \"symplectic-euler\"\ndt = 1e-3\nduration = 0.0\n\
             contact_distance = 0.05\n\
             [[terrain]]\nkind = \"plane\"\npoint = [0.0, 0.8, 0.0]\nnormal = [0.0, 1.0, 0.0]\n\
             friction = 0.5\nrestitution = 0.3\n\
             [[terrain]]\nkind = \"plane\"\npoint = [0.0, 0.0, 0.6]\nnormal = [0.2, 0.3, -1.0]\n\
             friction = 0.2\nrestitution = 0.0\n",
        );
        for (b, [nx, ny, nz]) in resolutions.iter().enumerate() {
            text += &format!(
                "[[body]]\nname = \"b{b}\"\nkind = \"cuboid\"\ncenter = [{x}, 1.0, 0.0]\n\
                 size = [1.2, 1.0, 1.6]\nresolution = [{nx}, {ny}, {nz}]\nmass = 2.0\n\
                 pinned = [0, 3]\n\
                 structural = {{ stiffness = 2000.0, damping = 5.0 }}\n\
                 shear = {{ stiffness = 1500.0, damping = 4.0 }}\n\
                 bending = {{ stiffness = 700.0, damping = 3.0 }}\n",
                x = 1.5 * b as f64,
            );
        }
        let scene = Scene::from_toml(&text, Path::new("test.toml")).expect("valid scene");
        let (model, mut state) = Model::build(&scene);
        for (i, (x, v)) in state.x.iter_mut().zip(&mut state.v).enumerate() {
            let t = i as f64;
            *x += 0.01 * DVec3::new((1.3 * t).sin(), (0.7 * t).cos(), (2.1 * t).sin());
            *v = DVec3::new((0.9 * t).sin(), (0.3 * t).cos() - 2.0, (1.7 * t).sin());
        }
        if blow_up {
            state.v[model.len() / 2].y = f64::INFINITY;
        }
        let surfaces = scene.terrain.iter().map(Surface::new).collect();
        (model, state, surfaces)
    }

    /// The row updates of explicit and symplectic Euler and of both midpoint stages (with
    /// every instruction set the CPU has) give the bits of the per-particle update, on lattices
    /// 2 and 3 wide, lanes in contact with two planes or pinned among lanes in the air, and a
    /// particle blown up, for 1 to 7 threads.
    #[test]
    fn row_updates_are_the_per_particle_update() {
        let isas: Vec<Isa> = [Isa::Scalar, Isa::Avx2, Isa::Avx512]
            .into_iter()
            .filter(|isa| isa.runs())
            .collect();
        let shapes: [&[[u32; 3]]; 3] = [&[[13, 11, 17]], &[[2, 3, 5], [3, 2, 4]], &[[9, 9, 9]]];
        let integrators = [
            Integrator::SymplecticEuler,
            Integrator::ExplicitEuler,
            Integrator::Midpoint,
        ];
        for (resolutions, blow_up) in shapes.into_iter().zip([false, false, true]) {
            let (model, start, surfaces) = scene_on_planes(resolutions, blow_up);
            let step = |threads: usize, rows: Option<Isa>, integrator: Integrator| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("thread pool");
                pool.install(|| {
                    let mut state = start.clone();
                    let bad = match integrator {
                        Integrator::Midpoint => {
                            let mut midpoint = Midpoint::new(&model);
                            midpoint.passes_mut().rows = rows;
                            midpoint.step(&model, &surfaces, &NoPairs, &mut state)
                        }
                        euler => {
                            let mut passes = Passes::new(&model);
                            passes.rows = rows;
                            let symplectic = euler == Integrator::SymplecticEuler;
                            passes.euler_step(
                                &model,
                                &surfaces,
                                &NoPairs,
                                &mut state,
                                |x, v, a, h| {
                                    if symplectic {
                                        let v1 = v + h * a;
                                        (x + h * v1, v1)
                                    } else {
                                        (x + h * v, v + h * a)
                                    }
                                },
                            )
                        }
                    };
                    let bits = |p: &[DVec3]| -> Vec<[u64; 3]> {
                        p.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
                    };
                    (bad, bits(&state.x), bits(&state.v))
                })
            };
            for integrator in integrators {
                let expected = step(1, None, integrator);
                assert_eq!(expected.0.is_some(), blow_up, "{resolutions:?}");
                for threads in 1..=7 {
                    for &isa in &isas {
                        let got = step(threads, Some(isa), integrator);
                        let what = format!("{resolutions:?} {isa:?} {threads} threads");
                        assert!(got == expected, "{what}, {integrator:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn all_finite_is_is_finite() {
        let values = [
            0.0,
            -0.0,
            1.5,
            -f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for &a in &values {
            for &b in &values {
                for k in 0..6 {
                    let mut c = [1.0; 6];
                    c[k] = a;
                    c[(k + 1) % 6] = b;
                    let (x, v) = (DVec3::new(c[0], c[1], c[2]), DVec3::new(c[3], c[4], c[5]));
                    assert_eq!(all_finite(x, v), x.is_finite() && v.is_finite(), "{x} {v}");
                }
            }
        }
    }
}
