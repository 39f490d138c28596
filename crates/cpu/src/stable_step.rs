//! An estimate of the largest stable step of the explicit integrators, on the springs' stiffest
//! mode itself.
//!
//! Symplectic Euler is stable on a mode of M⁻¹K eigenvalue λ and damping rate c while
//! h²λ + 2hc ≤ 4 ([`softbody_scene::largest_stable_step`]). [`Model::stable_dt`] bounds λ and
//! c by Gershgorin's theorem, about four times low on the jelly cube; here λ is the largest
//! eigenvalue of M^-½KM^-½ for the springs linearised at the positions x (K = Σ k_s l lᵀ over
//! the springs' unit directions l; the geometric stiffness, zero at rest length, is left out;
//! pinned particles do not move), found by [`POWER_ITERATIONS`] power iterations from a fixed
//! pseudo-random start, and c = uᵀDu/uᵀMu on the same vector (D = Σ k_d l lᵀ). The Rayleigh
//! quotient approaches λ from below, so this is an estimate, not a bound: within a few per cent
//! of the step where the jelly cube of `scenes/jelly-on-ground.toml` starts to diverge.
//!
//! K's product is the spring kernel's: a damper of coefficient k_s at velocities v pulls on a
//! with −k_s(l·(v_a − v_b)) l, which is −(K v)_a. So every product is one pass of the explicit
//! integrators' pipeline (`pipeline/`) over the model with its springs' coefficients
//! (k_s, k_d) turned into (0, k_s) — the stencil on lattices, the sweep or the gather on lists:
//! parallel, the same bits for any thread count, and no spring list where the model has none.
//! (`softbody check` on a 100³ cube: 4.7 s on 2 threads; 56 s with the serial sweep over the
//! springs this replaced, which it ran twice.)

use glam::DVec3;
use rayon::prelude::*;
use softbody_scene::{Model, largest_stable_step};

use crate::pipeline::{Plan, pass};
use crate::reduce::chunked_sum;
use crate::spring_forces::Kernel;

/// Power iterations of [`stable_dt_estimate`]: its Rayleigh quotient is within about 1 % of
/// the largest eigenvalue of the benchmark cubes from 10³ to 46³ after this many.
pub const POWER_ITERATIONS: usize = 60;

/// The estimate of the largest stable step of the explicit integrators from the positions `x`
/// (the initial state's; the module doc says how). RK4 tolerates about 1.4 times this step,
/// explicit Euler and midpoint are unstable on undamped springs at any step, and implicit Euler
/// is stable at any step. `None` without springs. Runs in the current rayon pool, with the
/// same bits for any number of threads.
pub fn stable_dt_estimate(model: &Model, x: &[DVec3]) -> Option<f64> {
    let (lambda, c) = stiffest_mode(model, x)?;
    largest_stable_step(lambda, c)
}

/// λ and c of the module doc, or `None` without springs. Where no particle with a spring
/// moves, [`Model::stable_dt`]'s bounds.
fn stiffest_mode(model: &Model, x: &[DVec3]) -> Option<(f64, f64)> {
    if model.spring_count() == 0 {
        return None;
    }
    assert_eq!(x.len(), model.len());
    let n = model.len();
    let scale: Vec<f64> = model.inv_mass.iter().map(|w| w.sqrt()).collect();
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut sign = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        if seed >> 63 == 0 { 1.0 } else { -1.0 }
    };
    let mut w: Vec<DVec3> = scale
        .iter()
        .map(|&s| DVec3::new(sign(), sign(), sign()) * f64::from(u8::from(s > 0.0)))
        .collect();
    let mut scratch = vec![DVec3::ZERO; n];
    let mut y = vec![DVec3::ZERO; n];
    let mut stiffness = Product::new(model.with_spring_coefficients(|k, _| (0.0, k)));
    for _ in 0..POWER_ITERATIONS {
        stiffness.apply(x, &scale, &w, &mut scratch, &mut y);
        let norm = chunked_sum(n, |i| y[i].length_squared()).sqrt();
        if norm == 0.0 {
            break;
        }
        w.par_iter_mut().zip(&y).for_each(|(w, y)| *w = *y / norm);
    }
    let length = chunked_sum(n, |i| w[i].length_squared());
    if length == 0.0 {
        return model.stable_dt_bounds();
    }
    // The quadratic forms of K and D on w.
    stiffness.apply(x, &scale, &w, &mut scratch, &mut y);
    let k = chunked_sum(n, |i| w[i].dot(y[i]));
    drop(stiffness);
    let mut damping = Product::new(model.with_spring_coefficients(|_, d| (0.0, d)));
    damping.apply(x, &scale, &w, &mut scratch, &mut y);
    let d = chunked_sum(n, |i| w[i].dot(y[i]));
    Some((k / length, d / length))
}

/// The product w ↦ M^-½ B M^-½ w of a matrix B = Σ k_d l lᵀ of the springs of a model (their
/// damping coefficients; stiffness zero), by its damper forces.
struct Product {
    model: Model,
    plan: Plan,
    kernel: Kernel,
}

impl Product {
    fn new(model: Model) -> Product {
        let plan = Plan::new(&model);
        let kernel = plan.kernel(&model);
        Product {
            model,
            plan,
            kernel,
        }
    }

    /// `y = M^-½ B M^-½ w`, with `scale` the diagonal of M^-½ (0 for pinned particles) and
    /// `v` scratch for the velocities M^-½ w.
    fn apply(&mut self, x: &[DVec3], scale: &[f64], w: &[DVec3], v: &mut [DVec3], y: &mut [DVec3]) {
        (v.par_iter_mut().zip(w).zip(scale)).for_each(|((v, w), s)| *v = *s * *w);
        pass(
            &mut self.plan,
            self.kernel,
            &self.model,
            (x, v),
            y,
            |i, f, y: &mut DVec3| {
                *y = -scale[i] * f;
                true
            },
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, SymmetricEigen};
    use softbody_scene::Scene;

    fn model(toml: &str) -> (Model, Vec<DVec3>) {
        let scene = Scene::from_toml(toml, "t.toml".as_ref()).unwrap();
        let (model, state) = Model::build(&scene);
        (model, state.x)
    }

    /// M^-½KM^-½ and M^-½DM^-½, dense, from the spring list.
    fn dense(model: &Model, x: &[DVec3]) -> [DMatrix<f64>; 2] {
        let n = 3 * model.len();
        let mut m = [DMatrix::zeros(n, n), DMatrix::zeros(n, n)];
        model.for_each_spring(|a, b, _, k, d| {
            let (a, b) = (a as usize, b as usize);
            let l = (x[a] - x[b]).normalize();
            for (matrix, coefficient) in m.iter_mut().zip([k, d]) {
                for r in 0..3 {
                    for c in 0..3 {
                        let e = coefficient * l[r] * l[c];
                        matrix[(3 * a + r, 3 * a + c)] += e;
                        matrix[(3 * b + r, 3 * b + c)] += e;
                        matrix[(3 * a + r, 3 * b + c)] -= e;
                        matrix[(3 * b + r, 3 * a + c)] -= e;
                    }
                }
            }
        });
        for matrix in &mut m {
            for i in 0..n {
                for j in 0..n {
                    let s = (model.inv_mass[i / 3] * model.inv_mass[j / 3]).sqrt();
                    matrix[(i, j)] *= s;
                }
            }
        }
        m
    }

    /// The estimate against the stiffest eigenpair of the dense matrices: λ from below, within
    /// `tolerance`, and the step within `tolerance` of the one of the eigenvector's c.
    fn assert_near_the_stiffest_mode(toml: &str, tolerance: f64) {
        let (model, x) = model(toml);
        let (lambda, c) = stiffest_mode(&model, &x).unwrap();
        let [k, d] = dense(&model, &x);
        let eigen = SymmetricEigen::new(k);
        let top = eigen.eigenvalues.imax();
        let (lambda_max, u) = (eigen.eigenvalues[top], eigen.eigenvectors.column(top));
        let c_max = (u.transpose() * &d * u)[(0, 0)];
        assert!(
            lambda <= lambda_max * (1.0 + 1e-12),
            "{lambda} above {lambda_max}"
        );
        assert!(
            lambda >= lambda_max * (1.0 - tolerance),
            "{lambda} of {lambda_max}"
        );
        let (h, h_max) = (
            largest_stable_step(lambda, c).unwrap(),
            largest_stable_step(lambda_max, c_max).unwrap(),
        );
        assert!((h / h_max - 1.0).abs() < tolerance, "{h} against {h_max}");
    }

    #[test]
    fn one_spring_gives_the_leapfrog_bound() {
        // Two unit masses, one spring k: ω² = 2k/m, and symplectic Euler is stable for h ≤ 2/ω.
        let (model, x) = model(
            "[simulation]\ndt = 0.001\nduration = 1.0\n[[body]]\nkind = \"particles\"\n\
             positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\nmasses = [1.0, 1.0]\n\
             springs = [{ a = 0, b = 1, stiffness = 50.0 }]\n",
        );
        let estimate = stable_dt_estimate(&model, &x).unwrap();
        assert!((estimate - 2.0 / 100f64.sqrt()).abs() < 1e-12, "{estimate}");
    }

    #[test]
    fn a_rotated_cuboid_with_a_pinned_corner_is_near_its_stiffest_mode() {
        // The stencil's products; damping not in proportion to stiffness.
        assert_near_the_stiffest_mode(
            "[simulation]\ndt = 0.001\nduration = 1.0\n[[body]]\nkind = \"cuboid\"\n\
             size = [0.3, 0.2, 0.4]\nresolution = [4, 3, 5]\nrotation = [10.0, 20.0, 30.0]\n\
             mass = 6.0\npinned = [0, 7]\n\
             structural = { stiffness = 2000.0, damping = 5.0 }\n\
             shear = { stiffness = 800.0, damping = 20.0 }\n\
             bending = { stiffness = 300.0, damping = 1.0 }\n",
            0.01,
        );
    }

    #[test]
    fn a_particles_body_is_near_its_stiffest_mode() {
        // Listed springs, not sorted by their first end: the gather's products.
        assert_near_the_stiffest_mode(
            "[simulation]\ndt = 0.001\nduration = 1.0\n[[body]]\nkind = \"particles\"\n\
             positions = [[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 1.0, 0.3], [0.1, 0.0, 1.2],\n\
             [1.1, 1.0, 0.9]]\nmasses = [1.0, 2.0, 0.5, 3.0, 1.5]\n\
             springs = [{ a = 1, b = 0, stiffness = 50.0, damping = 1.0 },\n\
             { a = 2, b = 0, stiffness = 80.0 }, { a = 3, b = 1, stiffness = 20.0, damping = 3.0 },\n\
             { a = 2, b = 3, stiffness = 60.0 }, { a = 4, b = 2, stiffness = 90.0, damping = 0.5 },\n\
             { a = 4, b = 1, stiffness = 10.0 }, { a = 0, b = 4, stiffness = 40.0 }]\n",
            0.01,
        );
    }

    #[test]
    fn the_estimate_has_the_same_bits_for_any_thread_count() {
        let (model, x) = model(
            "[simulation]\ndt = 0.001\nduration = 1.0\n[[body]]\nkind = \"cuboid\"\n\
             size = [0.3, 0.3, 0.9]\nresolution = [6, 7, 30]\nrotation = [0.0, 0.0, 40.0]\n\
             mass = 10.0\nstructural = { stiffness = 2000.0, damping = 5.0 }\n\
             shear = { stiffness = 2000.0, damping = 5.0 }\n",
        );
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build();
            pool.unwrap()
                .install(|| stable_dt_estimate(&model, &x).unwrap().to_bits())
        };
        let one = on(1);
        for threads in 2..=5 {
            assert_eq!(on(threads), one, "{threads} threads");
        }
    }
}
