//! A study's report as JSON and as a text table.

use serde_json::{Value, json};

use super::{RESOLVED, Report, Standing};

/// The table's error and drift of an unstable run: measured only over the frames before its
/// blow-up, they would look better than those of a stable run.
const NOT_COMPARABLE: &str = "unstable";

impl Report {
    /// The report as one JSON object (keys in docs/guide/cli.md, "softbody compare").
    pub fn to_json(&self, scene: &str) -> Value {
        json!({
            "scene": scene,
            "particles": self.particles,
            "duration": self.duration,
            "frame_rate": self.frame_rate,
            "backend": self.backend.name(),
            "device": self.device,
            "energy_scale": self.energy_scale,
            "rest_speed": self.rest_speed,
            "reference": {
                "integrator": self.reference.integrator.name(),
                "dt": self.reference.dt,
                "steps": self.reference.steps,
                "seconds": self.reference.seconds,
                "check_dt": self.reference.check_dt,
                "error_estimate": self.reference.error_estimate,
                "stable_dt_estimate": self.reference.stable_dt,
                "size": self.reference.size,
                "converged": self.reference.converged(),
                "not_converged_because": self.reference.unconverged,
                "suggested_refinement": self.reference.suggested_refinement,
            },
            "runs": self.runs.iter().map(|r| json!({
                "integrator": r.integrator.name(),
                "dt": r.dt,
                "steps": r.steps,
                "planned_steps": r.planned_steps,
                "seconds": r.seconds,
                "steps_per_second": r.steps_per_second(),
                "unstable": r.instability.as_ref().map(|i| json!({
                    "step": i.step,
                    "time": i.time,
                    "particle": i.particle,
                    "what": i.what,
                })),
                // An unstable run's frames stop before its blow-up, and an error against an
                // unconverged reference, or within its bound, is no measure of the integrator
                // at that step.
                "comparable": r.standing == Standing::Comparable,
                "not_comparable": r.standing.reason(),
                "max_error": r.max_error,
                "max_error_time": r.max_error_time,
                "energy_drift": r.energy_drift,
                "deepest_penetration": r.deepest_penetration,
                "final_max_speed": r.final_max_speed,
                "final_kinetic_energy": r.final_kinetic,
                "at_rest": r.at_rest,
                "series": {
                    "time": r.samples.iter().map(|s| s.time).collect::<Vec<_>>(),
                    "error": r.samples.iter().map(|s| s.error).collect::<Vec<_>>(),
                    "energy": r.samples.iter().map(|s| s.energy).collect::<Vec<_>>(),
                },
            })).collect::<Vec<_>>(),
        })
    }

    /// The report as text: a heading with the reference, an aligned table with one line per
    /// run, and what the columns mean.
    pub fn table(&self, scene: &str) -> String {
        let mut out = format!(
            "{scene}: {} particles, {} s at {} frames/s, on {} ({})\n",
            self.particles, self.duration, self.frame_rate, self.backend, self.device
        );
        let r = &self.reference;
        out.push_str(&format!(
            "reference: {} at dt = {:.4e} s ({} steps, {:.2} s)\n\
             reference error: at most {:.2e} m ({} at dt = {:.4e} s differs from it by that much)\n",
            r.integrator, r.dt, r.steps, r.seconds, r.error_estimate, r.integrator, r.check_dt
        ));
        if !r.converged() {
            out.push_str(&format!(
                "reference NOT converged: {}.\n  No run is comparable against it: try --refinement {} \
                 (a finer reference), or a shorter\n  --duration (contact makes a long run chaotic: \
                 its differences grow to the bodies' size\n  whatever the step).\n",
                r.unconverged.join("; "),
                r.suggested_refinement
            ));
        }
        out.push('\n');
        let header = [
            "integrator",
            "dt [s]",
            "steps",
            "wall [s]",
            "steps/s",
            "unstable at",
            "max error [m]",
            "energy drift",
            "min phi [m]",
            "end speed [m/s]",
            "at rest",
        ];
        let rows: Vec<[String; 11]> = self
            .runs
            .iter()
            .map(|r| {
                [
                    r.integrator.name().to_owned(),
                    format!("{:.3e}", r.dt),
                    r.steps.to_string(),
                    format!("{:.3}", r.seconds),
                    format!("{:.0}", r.steps_per_second()),
                    r.instability.as_ref().map_or("-".to_owned(), |i| {
                        format!("step {} ({:.4} s)", i.step, i.time)
                    }),
                    match r.standing {
                        Standing::Unstable => NOT_COMPARABLE.to_owned(),
                        Standing::Comparable => format!("{:.3e}", r.max_error),
                        _ => format!("{:.3e}*", r.max_error),
                    },
                    if r.instability.is_some() {
                        NOT_COMPARABLE.to_owned()
                    } else {
                        format!("{:.3e}", r.energy_drift)
                    },
                    r.deepest_penetration
                        .map_or("-".to_owned(), |d| format!("{d:.3e}")),
                    format!("{:.3e}", r.final_max_speed),
                    match r.at_rest {
                        Some(true) => "yes",
                        Some(false) => "no",
                        None => "-",
                    }
                    .to_owned(),
                ]
            })
            .collect();
        let widths: Vec<usize> = (0..header.len())
            .map(|c| {
                rows.iter()
                    .map(|row| row[c].chars().count())
                    .chain([header[c].chars().count()])
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        let line = |cells: &[&str]| {
            let mut s = String::new();
            for (c, cell) in cells.iter().enumerate() {
                let pad = widths[c] - cell.chars().count();
                if c == 0 {
                    // Names left-aligned, numbers right-aligned.
                    s.push_str(cell);
                    s.push_str(&" ".repeat(pad));
                } else {
                    s.push_str("  ");
                    s.push_str(&" ".repeat(pad));
                    s.push_str(cell);
                }
            }
            s.push('\n');
            s
        };
        out.push_str(&line(&header));
        for row in &rows {
            out.push_str(&line(&row.iter().map(String::as_str).collect::<Vec<_>>()));
        }
        out.push_str(&format!(
            "\nmax error: max over frames and particles of |x - x_ref| (`unstable`: the run blew up, and\n  \
             its error before that is not comparable with the others; `*`: not comparable, the\n  \
             reference is not converged or the error is below {RESOLVED} times its bound).\n\
             energy drift: max |E - E0| / E_s over the frames, E_s = {:.4e} J (the energy scale of the\n  \
             instability guard); it measures the integrator only in undamped scenes: damping,\n  \
             friction and contacts remove energy on purpose.\n\
             min phi: the smallest signed distance of any particle to the terrain at the frames\n  \
             (< 0: the deepest penetration; - : no terrain).\n\
             at rest: the fastest particle slower than {} m/s at the last frame (end speed).\n",
            self.energy_scale, self.rest_speed
        ));
        out
    }
}
