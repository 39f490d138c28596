//! `softbody compare`: run a scene with several integrators and time steps against a converged
//! reference ([`softbody::compare`]), print a table or JSON, and plot the errors and energies.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use softbody::compare::{Report, Study, StudyError};
use softbody::{Backend, Integrator, Overrides, Setting};

use crate::args::{SceneOverrides, time_step};
use crate::{Failure, bad_input, emit, load_with, open_failure, progress, status};

#[derive(Args)]
pub struct CompareArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Integrators, comma-separated (explicit-euler, symplectic-euler, midpoint, rk4,
    /// implicit-euler), or `all`.
    #[arg(long, value_delimiter = ',', default_value = "all", value_parser = integrators)]
    integrators: Vec<Vec<Integrator>>,
    /// Time steps, seconds, comma-separated, e.g. 1e-4,5e-5 or 1/60 (default: the scene's dt).
    #[arg(long, value_delimiter = ',', value_parser = time_step, allow_negative_numbers = true)]
    dt: Vec<f64>,
    /// The reference is rk4 at the smallest dt divided by this (its check at twice that step).
    #[arg(long, default_value_t = softbody::compare::REFINEMENT,
          value_parser = clap::value_parser!(u32).range(2..=1_000_000))]
    refinement: u32,
    /// Backend of the runs: cpu (f64) or gpu (f32); the reference always runs on the CPU.
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Also draw the position error and energy drift against time into this PNG file.
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// CPU threads (default: all cores).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..), allow_negative_numbers = true)]
    threads: Option<u16>,
    /// No progress bar and no summary.
    #[arg(long, short)]
    quiet: bool,
    // Last: the heading applies to every option after it.
    #[command(flatten, next_help_heading = "Overrides of the scene")]
    overrides: SceneOverrides,
}

fn integrators(s: &str) -> Result<Vec<Integrator>, String> {
    if s == "all" {
        Ok(Integrator::ALL.to_vec())
    } else {
        s.parse().map(|i| vec![i])
    }
}

pub fn compare(args: CompareArgs) -> Result<(), Failure> {
    let settings = args.overrides.all_settings();
    let scene = load_with(&args.scene, &settings)?;
    // A plot that cannot be written is found out before minutes of simulation, not after.
    if let Some(path) = &args.plot {
        if !plot::AVAILABLE {
            return Err(bad_input(anyhow::anyhow!(
                "this softbody was built without the `plot` feature: --plot is not available"
            )));
        }
        check_writable(path)?;
    }
    let mut list: Vec<Integrator> = Vec::new();
    for i in args.integrators.iter().flatten() {
        if !list.contains(i) {
            list.push(*i);
        }
    }
    // Each dt is an override like `run --dt`, refused alike; the study checks the rest.
    for &dt in &args.dt {
        let overrides = Overrides {
            dt: Some(dt),
            ..Overrides::default()
        };
        let with_dt: Vec<Setting> = settings
            .iter()
            .cloned()
            .chain(overrides.to_settings())
            .collect();
        load_with(&args.scene, &with_dt)?;
    }
    let study = Study {
        integrators: list,
        dts: args.dt.clone(),
        backend: args.backend,
        threads: args.threads.map(usize::from),
        refinement: args.refinement,
        ..Study::new(scene)
    };
    let failure = |e: StudyError| match e {
        StudyError::Invalid(_) => bad_input(anyhow::anyhow!("{}: {e}", args.scene.display())),
        StudyError::Open(o) => open_failure(o),
        StudyError::ReferenceUnstable { .. } => Failure {
            status: status::UNSTABLE,
            error: anyhow::anyhow!("{e}; try a smaller --dt or a larger --refinement"),
        },
        StudyError::Device(_) => Failure {
            status: status::NO_ADAPTER,
            error: e.into(),
        },
    };
    study.validate().map_err(failure)?;

    let bar = progress::bar(study.total_steps(), "steps", args.quiet);
    let started = Instant::now();
    let result = study.run(&mut |done, _| bar.set_position(done));
    bar.finish_and_clear();
    let report = result.map_err(failure)?;

    let name = args.scene.display().to_string();
    if let Some(path) = &args.plot {
        plot::draw(&report, &name, path)?;
    }
    if args.json {
        emit(&format!("{}\n", report.to_json(&name)))?;
    } else {
        emit(&report.table(&name))?;
    }
    if !args.quiet {
        let unstable = report
            .runs
            .iter()
            .filter(|r| r.instability.is_some())
            .count();
        say!(
            "{} runs ({unstable} unstable) and the reference in {:.1} s{}",
            report.runs.len(),
            started.elapsed().as_secs_f64(),
            args.plot
                .as_ref()
                .map_or(String::new(), |p| format!("; plot in {}", p.display()))
        );
    }
    let r = &report.reference;
    if !r.converged() {
        return Err(Failure {
            status: status::UNCONVERGED,
            error: anyhow::anyhow!(
                "the reference (rk4 at dt = {:.4e} s) is not converged: {}; no run is comparable \
                 against it: try --refinement {}, or a shorter --duration",
                r.dt,
                r.unconverged.join("; "),
                r.suggested_refinement
            ),
        });
    }
    Ok(())
}

/// The plot's directory must exist and the file must not be a directory (status 1 otherwise,
/// like any output that cannot be written).
fn check_writable(path: &Path) -> Result<(), Failure> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(anyhow::anyhow!(
            "cannot write the plot {}: {} is not a directory",
            path.display(),
            dir.display()
        )
        .into());
    }
    if path.is_dir() {
        return Err(anyhow::anyhow!(
            "cannot write the plot {}: it is a directory",
            path.display()
        )
        .into());
    }
    Ok(())
}

#[cfg(not(feature = "plot"))]
mod plot {
    use super::*;

    pub const AVAILABLE: bool = false;

    pub fn draw(_: &Report, _: &str, _: &Path) -> Result<(), Failure> {
        // Not reached: `compare` refuses --plot up front when AVAILABLE is false.
        Err(bad_input(anyhow::anyhow!("--plot is not available")))
    }
}

#[cfg(feature = "plot")]
mod plot {
    //! Two panels, one line per run: max |x − x_ref| against time (log scale) above,
    //! (E − E₀)/E_s against time below. Drawn by plotters into an RGB buffer, encoded by `png`.

    use std::io::BufWriter;

    use anyhow::Context;
    use plotters::prelude::*;
    use plotters::style::FontStyle;

    use super::*;

    pub const AVAILABLE: bool = true;

    /// Pixels.
    pub const WIDTH: u32 = 1200;
    pub const HEIGHT: u32 = 900;

    /// DejaVu Sans (Bitstream Vera licence, assets/fonts/LICENSE-DejaVu.txt): plotters' ab_glyph
    /// text has no system fonts, only those registered.
    const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

    /// Errors below this are drawn at it: the log axis has no zero (frame 0's error is 0).
    const ERROR_FLOOR: f64 = 1e-16;

    /// Tableau 10: distinct on white, and for most colour-blind readers.
    const COLOURS: [RGBColor; 10] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
    ];

    pub fn draw(report: &Report, scene: &str, path: &Path) -> Result<(), Failure> {
        let mut buffer = vec![0u8; (WIDTH * HEIGHT * 3) as usize];
        render(report, scene, &mut buffer)
            .map_err(|e| anyhow::anyhow!("cannot draw the plot: {e}"))?;
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let mut encoder = png::Encoder::new(BufWriter::new(file), WIDTH, HEIGHT);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        // Flat colours and thin lines compress well: about 100 KB instead of 500 KB.
        encoder.set_compression(png::Compression::High);
        encoder.set_filter(png::Filter::Adaptive);
        encoder
            .write_header()
            .and_then(|mut w| w.write_image_data(&buffer))
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(())
    }

    /// Width of the legend column, pixels.
    const LEGEND_WIDTH: u32 = 330;

    /// How one run is drawn: its integrator's colour, and a dash pattern for its dt (solid for
    /// the smallest, then longer and shorter dashes as dt grows).
    struct Look {
        colour: RGBColor,
        /// (dash, gap) in pixels; None: solid.
        dash: Option<(u32, u32)>,
    }

    fn looks(report: &Report) -> Vec<Look> {
        let mut integrators = Vec::new();
        let mut dts: Vec<f64> = Vec::new();
        for r in &report.runs {
            if !integrators.contains(&r.integrator) {
                integrators.push(r.integrator);
            }
            if !dts.contains(&r.dt) {
                dts.push(r.dt);
            }
        }
        dts.sort_by(f64::total_cmp);
        const DASHES: [Option<(u32, u32)>; 4] = [None, Some((10, 6)), Some((3, 4)), Some((16, 5))];
        report
            .runs
            .iter()
            .map(|r| {
                let i = integrators
                    .iter()
                    .position(|&x| x == r.integrator)
                    .unwrap_or(0);
                let d = dts.iter().position(|&x| x == r.dt).unwrap_or(0);
                Look {
                    colour: COLOURS[i % COLOURS.len()],
                    dash: DASHES[d % DASHES.len()],
                }
            })
            .collect()
    }

    /// Draws `points` in a chart with `look`.
    fn series<DB: DrawingBackend, X, Y>(
        chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
        points: Vec<(X::ValueType, Y::ValueType)>,
        look: &Look,
    ) -> Result<(), Box<dyn std::error::Error>>
    where
        X: Ranged,
        Y: Ranged,
        X::ValueType: Clone + 'static,
        Y::ValueType: Clone + 'static,
        DB::ErrorType: 'static,
    {
        let style = look.colour.stroke_width(2);
        match look.dash {
            None => {
                chart.draw_series(LineSeries::new(points, style))?;
            }
            Some((dash, gap)) => {
                chart.draw_series(DashedLineSeries::new(points, dash, gap, style))?;
            }
        }
        Ok(())
    }

    /// The legend column: one entry per run, a line sample and its integrator and dt, and where
    /// it became unstable.
    fn legend<DB: DrawingBackend>(
        area: &DrawingArea<DB, plotters::coord::Shift>,
        report: &Report,
        looks: &[Look],
    ) -> Result<(), Box<dyn std::error::Error>>
    where
        DB::ErrorType: 'static,
    {
        let font = ("sans-serif", 15).into_font().color(&BLACK);
        let small = ("sans-serif", 13).into_font().color(&RGBColor(90, 90, 90));
        let mut y = 60;
        area.draw(&Text::new(
            "runs",
            (10, y - 30),
            ("sans-serif", 17).into_font(),
        ))?;
        for (r, look) in report.runs.iter().zip(looks) {
            let style = look.colour.stroke_width(3);
            match look.dash {
                None => area.draw(&PathElement::new(vec![(10, y), (44, y)], style))?,
                Some((dash, gap)) => {
                    let mut x = 10;
                    while x < 44 {
                        let end = (x + dash as i32).min(44);
                        area.draw(&PathElement::new(vec![(x, y), (end, y)], style))?;
                        x = end + gap as i32;
                    }
                }
            }
            area.draw(&Text::new(
                format!("{}, dt {:.3e} s", r.integrator, r.dt),
                (52, y - 8),
                font.clone(),
            ))?;
            y += 21;
            if let Some(i) = &r.instability {
                area.draw(&Text::new(
                    format!("unstable at step {} (t = {:.3} s)", i.step, i.time),
                    (52, y - 9),
                    small.clone(),
                ))?;
                y += 17;
            }
        }
        area.draw(&Text::new(
            "colour: integrator; dashes: dt",
            (10, y + 8),
            small.clone(),
        ))?;
        Ok(())
    }

    /// A tick label of the drift axis spanning `span`: as many decimals as the ticks' spacing
    /// (about span/10) needs, scientific for very small or large spans, and 0 for the round-off
    /// that a tick at zero carries.
    fn drift_label(v: f64, span: f64) -> String {
        if v.abs() < span * 1e-9 {
            "0".to_owned()
        } else if (1e-3..1e4).contains(&span) {
            let decimals = (-(span / 10.0).log10().floor()).max(0.0) as usize;
            format!("{v:.decimals$}")
        } else {
            format!("{v:.2e}")
        }
    }

    fn render(
        report: &Report,
        scene: &str,
        buffer: &mut [u8],
    ) -> Result<(), Box<dyn std::error::Error>> {
        // Registering twice is harmless; an unreadable font would leave the text blank.
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| "the bundled font does not load")?;
        let root = BitMapBackend::with_buffer(buffer, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE)?;
        let stem = Path::new(scene)
            .file_name()
            .map_or(scene.to_owned(), |s| s.to_string_lossy().into_owned());
        let root = root.titled(
            &format!(
                "{stem}: integrators against {} at dt = {:.3e} s",
                report.reference.integrator, report.reference.dt
            ),
            ("sans-serif", 26),
        )?;
        let (plots, side) = root.split_horizontally(WIDTH - LEGEND_WIDTH);
        let looks = looks(report);
        legend(&side, report, &looks)?;
        let (upper, lower) = plots.split_vertically(HEIGHT / 2 - 20);
        let t_end = report
            .runs
            .iter()
            .flat_map(|r| r.samples.last().map(|s| s.time))
            .fold(report.duration, f64::max)
            .max(1e-9);

        // Error panel: decades around the positive errors.
        let positive = || {
            report
                .runs
                .iter()
                .flat_map(|r| &r.samples)
                .map(|s| s.error)
                .filter(|e| *e > 0.0 && e.is_finite())
        };
        let lo = positive().fold(f64::INFINITY, f64::min).max(ERROR_FLOOR);
        let hi = positive().fold(0.0, f64::max);
        let (lo, hi) = if lo.is_finite() && hi > 0.0 {
            (
                10f64.powf(lo.log10().floor()),
                10f64.powf(hi.log10().ceil()).max(lo * 10.0),
            )
        } else {
            (ERROR_FLOOR, ERROR_FLOOR * 10.0)
        };
        let mut chart = ChartBuilder::on(&upper)
            .margin(12)
            .caption("position error against the reference", ("sans-serif", 20))
            .x_label_area_size(45)
            .y_label_area_size(90)
            .build_cartesian_2d(0f64..t_end, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("time [s]")
            .y_desc("max |x - x_ref| [m]")
            .y_label_formatter(&|v| format!("{v:.0e}"))
            // Major grid lines only: the fine ones cost legibility and PNG size.
            .light_line_style(WHITE)
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()?;
        for (r, look) in report.runs.iter().zip(&looks) {
            let points = r
                .samples
                .iter()
                .filter(|s| s.time > 0.0)
                .map(|s| (s.time, s.error.clamp(lo, hi)))
                .collect();
            series(&mut chart, points, look)?;
        }

        // Energy panel: the range of the stable runs (a diverging run would flatten the others
        // to a line). An unstable run's line ends where it leaves that range, at the edge, with
        // a triangle there: drawn clamped, a blow-up would look like a bounded plateau.
        let drifts = |stable_only: bool| {
            report
                .runs
                .iter()
                .filter(move |r| !stable_only || r.instability.is_none())
                .flat_map(|r| &r.samples)
                .map(|s| s.drift)
                .filter(|d| d.is_finite())
        };
        let any_stable = report.runs.iter().any(|r| r.instability.is_none());
        let d_lo = drifts(any_stable).fold(0.0, f64::min);
        let d_hi = drifts(any_stable).fold(0.0, f64::max);
        let pad = ((d_hi - d_lo) * 0.05).max(1e-6);
        let (d_lo, d_hi) = (d_lo - pad, d_hi + pad);
        let mut chart = ChartBuilder::on(&lower)
            .margin(12)
            .caption(
                format!(
                    "energy: (E - E0) / E_s, E_s = {:.3e} J (meaningful for undamped scenes)",
                    report.energy_scale
                ),
                ("sans-serif", 20),
            )
            .x_label_area_size(45)
            .y_label_area_size(90)
            .build_cartesian_2d(0f64..t_end, d_lo..d_hi)?;
        chart
            .configure_mesh()
            .x_desc("time [s]")
            .y_desc("(E - E0) / E_s")
            .y_label_formatter(&|v| drift_label(*v, d_hi - d_lo))
            .light_line_style(WHITE)
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()?;
        for (r, look) in report.runs.iter().zip(&looks) {
            let mut points = Vec::new();
            let mut left = None;
            for s in &r.samples {
                if (d_lo..=d_hi).contains(&s.drift) {
                    points.push((s.time, s.drift));
                } else {
                    // NaN too: an energy that is not a number has left every range.
                    let edge = if s.drift < d_lo { d_lo } else { d_hi };
                    points.push((s.time, edge));
                    left = Some((s.time, edge));
                    break;
                }
            }
            series(&mut chart, points, look)?;
            if let Some(at) = left {
                chart.draw_series([TriangleMarker::new(at, 7, look.colour.filled())])?;
            }
        }
        root.present()?;
        Ok(())
    }
}
