//! Whether a study measured anything: the reference's convergence and each run's standing.
//!
//! The reference's error is bounded by b = max |x_check − x_ref| (its check run at twice its
//! step). A run's measured error e = max |x − x_ref| is then its true error to within ±b, so the
//! figure is the true one to ±1/[`RESOLVED`] only where e ≥ [`RESOLVED`]·b. The reference itself
//! is not converged, and no run is comparable against it, when
//!
//! - its check step is past the explicit integrators' stable step estimate (`softbody check`'s):
//!   RK4 there is near the edge of its stability region, far from the fourth-order regime, so b
//!   bounds nothing;
//! - b is more than [`SIZE_FRACTION`] of the bodies' size (the diagonal of their initial bounding
//!   box): the reference's own trajectory is that far from the converged one, typically because
//!   the run is long enough for contact to make it chaotic (differences grow until they saturate
//!   at the body's size whatever the step);
//! - no run that stayed stable is resolved (every e < [`RESOLVED`]·b).

/// A run's max error is comparable when at least this many times the reference's error bound:
/// the true error then lies within ±10 % of the figure.
pub const RESOLVED: f64 = 10.0;

/// The reference is converged only when its error bound is at most this fraction of the bodies'
/// size: errors below 1 % of a body are below what a study of its motion can tell apart.
pub const SIZE_FRACTION: f64 = 1e-2;

/// Why a run's error is or is not a measure of its integrator at its step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Standing {
    /// Stable, the reference converged, the error resolved.
    Comparable,
    /// The run diverged: its error covers only the frames before.
    Unstable,
    /// The reference is not converged ([`Reference::unconverged`](super::Reference)).
    ReferenceNotConverged,
    /// Its error is below [`RESOLVED`] times the reference's bound.
    WithinReferenceError,
}

impl Standing {
    /// The JSON name of a run that is not comparable, `None` for one that is.
    pub fn reason(self) -> Option<&'static str> {
        match self {
            Standing::Comparable => None,
            Standing::Unstable => Some("unstable"),
            Standing::ReferenceNotConverged => Some("reference-not-converged"),
            Standing::WithinReferenceError => Some("within-reference-error"),
        }
    }
}

/// What the reference's convergence is judged from.
#[derive(Debug, Clone, Copy)]
pub(super) struct Evidence<'a> {
    /// The check run's step, 2·dt_ref.
    pub check_dt: f64,
    /// The explicit integrators' stable step estimate (None without springs).
    pub stable_dt: Option<f64>,
    /// The reference's error bound b.
    pub bound: f64,
    /// The bodies' size.
    pub size: f64,
    /// Each run's max error, None where it diverged.
    pub errors: &'a [Option<f64>],
}

/// Why the reference is not converged; empty when it is.
pub(super) fn unconverged(e: Evidence<'_>) -> Vec<String> {
    let mut reasons = Vec::new();
    if let Some(stable) = e.stable_dt
        && e.check_dt > stable
    {
        reasons.push(format!(
            "its check run's step, {:.4e} s, is past the stable step estimate {stable:.4e} s \
             (softbody check's), so the check bounds nothing",
            e.check_dt
        ));
    }
    if e.bound > SIZE_FRACTION * e.size {
        reasons.push(format!(
            "its error bound {:.3e} m is more than {}% of the bodies' size ({:.3e} m)",
            e.bound,
            SIZE_FRACTION * 100.0,
            e.size
        ));
    }
    let stable: Vec<f64> = e.errors.iter().flatten().copied().collect();
    if !stable.is_empty() && stable.iter().all(|&err| err < RESOLVED * e.bound) {
        reasons.push(format!(
            "its error bound {:.3e} m is more than 1/{RESOLVED} of every stable run's error",
            e.bound
        ));
    }
    reasons
}

/// A run's standing given its max error (None: it diverged), the reference's bound and whether
/// the reference converged.
pub(super) fn standing(error: Option<f64>, bound: f64, converged: bool) -> Standing {
    match error {
        None => Standing::Unstable,
        Some(_) if !converged => Standing::ReferenceNotConverged,
        Some(e) if e < RESOLVED * bound => Standing::WithinReferenceError,
        Some(_) => Standing::Comparable,
    }
}

/// The refinement to try next: one whose check step is below the stable estimate, and at least
/// twice `refinement` (RK4's bound then falls 16-fold on a smooth motion).
pub(super) fn suggested_refinement(refinement: u32, min_dt: f64, stable_dt: Option<f64>) -> u32 {
    let past = stable_dt.map_or(0.0, |s| (2.0 * min_dt / s).ceil());
    (2.0 * f64::from(refinement))
        .max(past)
        .min(f64::from(u32::MAX)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evidence(errors: &[Option<f64>]) -> Evidence<'_> {
        Evidence {
            check_dt: 1e-3,
            stable_dt: Some(2e-3),
            bound: 1e-4,
            size: 1.0,
            errors,
        }
    }

    /// Each criterion alone: converged with a resolved run; past the stable step; a bound over
    /// 1 % of the size; every run within 10× the bound. The standings follow the same limits.
    #[test]
    fn each_criterion_marks_the_reference_unconverged() {
        let resolved = [Some(1e-3), None];
        assert!(unconverged(evidence(&resolved)).is_empty());
        let past = Evidence {
            check_dt: 2.5e-3,
            ..evidence(&resolved)
        };
        assert!(unconverged(past)[0].contains("past the stable step estimate 2.0000e-3 s"));
        let large = Evidence {
            bound: 1.1e-2,
            errors: &[Some(1.0)],
            ..evidence(&resolved)
        };
        assert_eq!(unconverged(large).len(), 1);
        assert!(unconverged(large)[0].contains("more than 1% of the bodies' size"));
        let unresolved = [Some(9.9e-4), None];
        assert!(unconverged(evidence(&unresolved))[0].contains("every stable run's error"));
        // Without springs there is no estimate, and without a stable run nothing to resolve.
        let free = Evidence {
            stable_dt: None,
            check_dt: 1.0,
            errors: &[None],
            ..evidence(&resolved)
        };
        assert!(unconverged(free).is_empty());

        assert_eq!(standing(None, 1e-4, true), Standing::Unstable);
        assert_eq!(
            standing(Some(1.0), 1e-4, false),
            Standing::ReferenceNotConverged
        );
        assert_eq!(
            standing(Some(9.9e-4), 1e-4, true),
            Standing::WithinReferenceError
        );
        assert_eq!(standing(Some(1e-3), 1e-4, true), Standing::Comparable);
    }

    #[test]
    fn the_suggested_refinement_clears_the_stable_step_and_doubles_at_least() {
        // 2 · (1/60 s) / 1.35e-3 s = 24.7: 25 clears it.
        assert_eq!(suggested_refinement(16, 1.0 / 60.0, Some(1.35e-3)), 32);
        assert_eq!(suggested_refinement(4, 1.0 / 60.0, Some(1.35e-3)), 25);
        assert_eq!(suggested_refinement(16, 1e-3, None), 32);
    }
}
