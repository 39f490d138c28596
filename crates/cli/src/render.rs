//! `softbody render`: draw a scene's frames (simulated here on the CPU, or read from a JSON Lines
//! file written by `softbody run`) as PNG files and/or an animated GIF.
//!
//! With the camera given on the command line, frames are drawn as they come; otherwise the
//! automatic camera frames the bodies' box over every frame, so the frames are kept until the
//! last one is known. Outputs are written beside their destination (a temporary directory or
//! file) and moved into place at the end; a run stopped by an instability still keeps the
//! frames before it, as `softbody run` does.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, anyhow};
use clap::Args;
use glam::DVec3;
use indicatif::ProgressBar;
use softbody::output::{Frame, FrameSink, Header, jsonl};
use softbody::run::RunError;
use softbody::{Backend, Model, Overrides, Scene};
use softbody_render::{Bounds, Camera, GifWriter, RenderOptions, Renderer};

use crate::args::{SceneOverrides, positive};
use crate::{Failure, bad_input, file_stem, load_with, open_failure, progress, status};

#[derive(Args)]
pub struct RenderArgs {
    /// A scene (.toml: simulated on the CPU) or the frames of a run (.jsonl, written by
    /// `softbody run`; its scene file must still be where the header says).
    input: PathBuf,
    /// Where to draw: a directory of PNG files (DIR/frame_000000.png, …) or an animated GIF
    /// (a name ending in .gif); give it twice for both. Default: out/{input file stem}/.
    #[arg(long)]
    out: Vec<PathBuf>,
    /// Picture width, pixels (1 to 8192).
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(1..=8192))]
    width: u32,
    /// Picture height, pixels (1 to 8192).
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(1..=8192))]
    height: u32,
    /// Camera position X,Y,Z in metres. Default: in front of, right of and above what is
    /// drawn, far enough to see it all.
    #[arg(long, value_parser = point, allow_negative_numbers = true, value_name = "X,Y,Z")]
    camera_from: Option<DVec3>,
    /// The point the camera looks at, X,Y,Z in metres. Default: the centre of what is drawn.
    #[arg(long, value_parser = point, allow_negative_numbers = true, value_name = "X,Y,Z")]
    camera_to: Option<DVec3>,
    /// Vertical field of view, degrees (0 to 180).
    #[arg(long, default_value_t = softbody_render::camera::DEFAULT_FOV_Y_DEGREES, value_parser = fov)]
    fov: f64,
    /// Also draw every spring, coloured by its strain (length − rest)/rest: blue at −S
    /// (compressed), grey at 0, red at +S (stretched), under a see-through surface;
    /// a colour bar in the bottom-left corner shows the scale (ticks at −S, 0, +S).
    #[arg(long)]
    springs: bool,
    /// S, the strain drawn in full blue or red with --springs.
    #[arg(long, default_value_t = softbody_render::DEFAULT_STRAIN_RANGE, value_parser = positive, value_name = "S")]
    strain_range: f64,
    /// Do not draw the bodies' shadows on the terrain.
    #[arg(long)]
    no_shadows: bool,
    /// Move the camera with the bodies: it keeps its offset from their centroid (the mean
    /// particle position), and by default frames about three times the bodies' first-frame size.
    #[arg(long)]
    follow: bool,
    /// No progress bar and no summary.
    #[arg(long, short)]
    quiet: bool,
    // Last: the heading applies to every option after it.
    #[command(
        flatten,
        next_help_heading = "Overrides of the scene (.toml input only)"
    )]
    overrides: SceneOverrides,
}

fn point(s: &str) -> Result<DVec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let numbers: Vec<f64> = parts
        .iter()
        .filter_map(|p| p.parse::<f64>().ok())
        .filter(|x| x.is_finite())
        .collect();
    match numbers[..] {
        [x, y, z] if parts.len() == 3 => Ok(DVec3::new(x, y, z)),
        _ => Err(format!("`{s}` is not three finite numbers X,Y,Z (metres)")),
    }
}

fn fov(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x > 0.0 && x < 180.0 => Ok(x),
        _ => Err(format!("`{s}` is not an angle between 0 and 180 degrees")),
    }
}

pub fn render(args: RenderArgs) -> Result<(), Failure> {
    let started = Instant::now();
    let input = match args.input.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("toml") => Input::Scene,
        Some(e) if e.eq_ignore_ascii_case("jsonl") => Input::Frames,
        _ => {
            return Err(bad_input(anyhow!(
                "{}: expected a scene (.toml) or frames written by `softbody run` (.jsonl)",
                args.input.display()
            )));
        }
    };
    let overrides = Overrides::from(&args.overrides);
    if input == Input::Frames && !overrides.is_empty() {
        return Err(bad_input(anyhow!(
            "--duration and --fps apply to a scene; frames from {} are drawn as they were run",
            args.input.display()
        )));
    }
    let outs = if args.out.is_empty() {
        vec![PathBuf::from("out").join(file_stem(&args.input).as_ref())]
    } else {
        args.out.clone()
    };

    match input {
        Input::Scene => {
            let scene = load_with(&args.input, &overrides)?;
            let (model, _) = Model::build(&scene);
            let sim = scene.simulation;
            let mut drawer = Drawer::new(&args, &model, &outs, sim.frame_rate, sim.frame_count())?;
            drawer.simulated = true;
            let mut solver = softbody::open(&scene, Backend::Cpu, None).map_err(open_failure)?;
            let result = softbody::run::run(
                solver.as_mut(),
                Some(&args.input),
                &mut Sink(&mut drawer),
                &mut |_, _| {},
            );
            match result {
                Ok(_) => drawer.finish(&args, started),
                Err(RunError::Unstable(i)) => {
                    // The frames before the instability are drawn and kept, as `run` keeps
                    // them.
                    drawer.finish(&args, started)?;
                    Err(Failure {
                        status: status::UNSTABLE,
                        error: anyhow!(
                            "{i}; {}\nthe frames before it are drawn",
                            softbody::Instability::advice(sim.integrator)
                        ),
                    })
                }
                Err(RunError::Device(d)) => Err(Failure {
                    status: status::NO_ADAPTER,
                    error: anyhow!("device failure: {d}"),
                }),
                Err(RunError::Io(e)) => Err(anyhow::Error::new(e)
                    .context("cannot write the pictures")
                    .into()),
            }
        }
        Input::Frames => {
            let path = &args.input;
            let frames = jsonl::Reader::open(path).map_err(bad_input)?;
            let header = frames.header();
            let Some(scene_path) = &header.scene else {
                return Err(bad_input(anyhow!(
                    "{}: the header names no scene file (frames of a scene built in code), so the \
                     terrain and surface are unknown; render the scene itself instead",
                    path.display()
                )));
            };
            let scene = Scene::from_file(scene_path)
                .map_err(|e| bad_input(anyhow!("the scene of {}: {e}", path.display())))?;
            let (model, _) = Model::build(&scene);
            if model.len() != header.particles {
                return Err(bad_input(anyhow!(
                    "{}: {} particles, but its scene {scene_path} has {} now",
                    path.display(),
                    header.particles,
                    model.len()
                )));
            }
            let mut drawer = Drawer::new(&args, &model, &outs, header.frame_rate, header.frames)?;
            for frame in frames {
                let frame = frame.map_err(bad_input)?;
                drawer
                    .frame(frame.index, frame.positions)
                    .context("cannot write the pictures")?;
            }
            drawer.finish(&args, started)
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Input {
    Scene,
    Frames,
}

/// One destination, being written beside its final place.
enum Output {
    /// PNG files in a temporary directory, moved to `path` at the end.
    Pngs {
        path: PathBuf,
        temp: tempfile::TempDir,
    },
    /// A GIF in a temporary file, renamed to `path` at the end.
    Gif {
        path: PathBuf,
        temp: tempfile::TempPath,
        writer: GifWriter<BufWriter<File>>,
    },
}

fn is_gif(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gif"))
}

/// The folder a destination's temporary twin is made in: its parent (created if missing).
fn parent_of(path: &Path) -> Result<PathBuf, Failure> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir.to_owned())
}

impl Output {
    fn create(path: &Path, width: u32, height: u32, frame_rate: f64) -> Result<Output, Failure> {
        let dir = parent_of(path)?;
        let mut builder = tempfile::Builder::new();
        builder.prefix(".softbody-").suffix(".part");
        if is_gif(path) {
            if path.is_dir() {
                return Err(anyhow!("cannot write {}: it is a directory", path.display()).into());
            }
            // An ordinary file once renamed into place: 0666 less the umask.
            #[cfg(unix)]
            builder.permissions(
                <std::fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o666),
            );
            let file = builder
                .tempfile_in(&dir)
                .with_context(|| format!("cannot write in {}", dir.display()))?;
            let (file, temp) = file.into_parts();
            let writer = GifWriter::new(BufWriter::new(file), width, height, frame_rate)?;
            Ok(Output::Gif {
                path: path.to_owned(),
                temp,
                writer,
            })
        } else {
            if path.exists() && !path.is_dir() {
                return Err(anyhow!(
                    "cannot write pictures into {}: it is not a directory",
                    path.display()
                )
                .into());
            }
            let temp = builder
                .tempdir_in(&dir)
                .with_context(|| format!("cannot write in {}", dir.display()))?;
            Ok(Output::Pngs {
                path: path.to_owned(),
                temp,
            })
        }
    }

    fn add(&mut self, index: u64, image: &softbody_render::Image) -> std::io::Result<()> {
        match self {
            Output::Pngs { temp, .. } => {
                let file = File::create(temp.path().join(png_name(index)))?;
                let mut w = BufWriter::new(file);
                image.write_png(&mut w)?;
                std::io::Write::flush(&mut w)
            }
            Output::Gif { writer, .. } => writer.add(image),
        }
    }

    /// Moves the output into place; a directory that exists already keeps its other files
    /// but loses the frame files of an earlier, longer render.
    fn persist(self, frames: u64) -> anyhow::Result<()> {
        match self {
            Output::Gif { path, temp, writer } => {
                let mut w = writer.finish()?;
                std::io::Write::flush(&mut w)?;
                drop(w);
                temp.persist(&path)
                    .with_context(|| format!("cannot write {}", path.display()))?;
            }
            Output::Pngs { path, temp } => {
                if !path.exists() {
                    let kept = temp.keep();
                    if let Err(e) = std::fs::rename(&kept, &path) {
                        let _ = std::fs::remove_dir_all(&kept);
                        return Err(e).with_context(|| format!("cannot write {}", path.display()));
                    }
                    #[cfg(unix)]
                    {
                        // A directory like any other once in place, not a private 0700 one.
                        use std::os::unix::fs::PermissionsExt;
                        let _ =
                            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755));
                    }
                } else {
                    for entry in std::fs::read_dir(temp.path())? {
                        let entry = entry?;
                        std::fs::rename(entry.path(), path.join(entry.file_name()))
                            .with_context(|| format!("cannot write in {}", path.display()))?;
                    }
                    for entry in std::fs::read_dir(&path)? {
                        let name = entry?.file_name();
                        let stale = name
                            .to_str()
                            .and_then(|n| n.strip_prefix("frame_"))
                            .and_then(|n| n.strip_suffix(".png"))
                            .and_then(|n| n.parse::<u64>().ok())
                            .is_some_and(|k| k >= frames);
                        if stale {
                            std::fs::remove_file(path.join(name))?;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn describe(&self) -> String {
        match self {
            Output::Pngs { path, .. } => format!("{}/", path.display()),
            Output::Gif { path, .. } => path.display().to_string(),
        }
    }
}

fn png_name(index: u64) -> String {
    format!("frame_{index:06}.png")
}

/// Draws frames into the outputs, as they come when the camera is known, else at the end.
struct Drawer<'m> {
    model: &'m Model,
    options: RenderOptions,
    camera_from: Option<DVec3>,
    camera_to: Option<DVec3>,
    fov: f64,
    renderer: Option<Renderer>,
    /// With --follow: the camera's eye minus its target, and its target minus the bodies'
    /// centroid, fixed at the first frame.
    follow: Option<Option<(DVec3, DVec3)>>,
    /// Frames waiting for the automatic camera (index, positions).
    pending: Vec<(u64, Vec<DVec3>)>,
    bodies: Bounds,
    outputs: Vec<Output>,
    bar: ProgressBar,
    drawn: u64,
    /// Whether the frames were simulated here (the summary's time includes it).
    simulated: bool,
}

impl<'m> Drawer<'m> {
    fn new(
        args: &RenderArgs,
        model: &'m Model,
        outs: &[PathBuf],
        frame_rate: f64,
        frames: u64,
    ) -> Result<Drawer<'m>, Failure> {
        let options = RenderOptions {
            width: args.width,
            height: args.height,
            camera: None,
            springs: args.springs,
            strain_range: args.strain_range,
            shadows: !args.no_shadows,
        };
        if let (Some(from), Some(to)) = (args.camera_from, args.camera_to) {
            let camera = Camera {
                fov_y_degrees: args.fov,
                ..Camera::look_at(from, to)
            };
            camera
                .validate()
                .map_err(|e| bad_input(anyhow!("--camera-from/--camera-to: {e}")))?;
        }
        let outputs = outs
            .iter()
            .map(|p| Output::create(p, args.width, args.height, frame_rate))
            .collect::<Result<Vec<_>, _>>()?;
        let bar = progress::bar(frames, "frames", args.quiet);
        Ok(Drawer {
            model,
            options,
            camera_from: args.camera_from,
            camera_to: args.camera_to,
            fov: args.fov,
            follow: args.follow.then_some(None),
            renderer: None,
            pending: Vec::new(),
            bodies: Bounds::default(),
            outputs,
            bar,
            drawn: 0,
            simulated: false,
        })
    }

    /// The renderer for the camera: the automatic one with the given parts replaced.
    fn renderer(&self) -> Result<Renderer, Failure> {
        let content = softbody_render::content_bounds(self.model, self.bodies);
        let auto = Camera::framing(
            content.lo,
            content.hi,
            self.options.width,
            self.options.height,
        );
        let camera = Camera {
            from: self.camera_from.unwrap_or(auto.from),
            to: self.camera_to.unwrap_or(auto.to),
            up: auto.up,
            fov_y_degrees: self.fov,
        };
        // Only --camera-to moved towards the automatic eye can make them meet.
        let options = RenderOptions {
            camera: Some(camera),
            ..self.options
        };
        Renderer::new(self.model, self.bodies, options).map_err(|e| {
            bad_input(anyhow!(
                "cannot draw with this camera: {e} (see --camera-from/--camera-to)"
            ))
        })
    }

    fn frame(&mut self, index: u64, positions: Vec<DVec3>) -> anyhow::Result<()> {
        if let Some(follow) = self.follow {
            return self.follow_frame(follow, index, &positions);
        }
        if self.renderer.is_none() && self.camera_from.is_some() && self.camera_to.is_some() {
            // The camera is known: the first frame sizes the ground planes.
            self.bodies.add(&positions);
            self.renderer = Some(self.renderer().map_err(|f| f.error)?);
        }
        match &self.renderer {
            Some(_) => self.draw(index, &positions),
            None => {
                self.bodies.add(&positions);
                self.pending.push((index, positions));
                self.bar.inc(1);
                Ok(())
            }
        }
    }

    /// Draws a frame with the camera moved along with the bodies' centroid.
    fn follow_frame(
        &mut self,
        follow: Option<(DVec3, DVec3)>,
        index: u64,
        positions: &[DVec3],
    ) -> anyhow::Result<()> {
        let finite: Vec<DVec3> = positions
            .iter()
            .copied()
            .filter(|p| p.is_finite())
            .collect();
        let centroid = finite.iter().sum::<DVec3>() / finite.len().max(1) as f64;
        let (offset, shift) = match follow {
            Some(f) => f,
            None => {
                // The first frame: the camera given, or one framing a box three times the
                // bodies' size around them.
                let b = Bounds::of(&finite);
                let r = if b.is_empty() {
                    0.5
                } else {
                    (0.5 * (b.hi - b.lo).length()).max(0.1)
                };
                let auto = Camera::framing(
                    centroid - DVec3::splat(3.0 * r),
                    centroid + DVec3::splat(3.0 * r),
                    self.options.width,
                    self.options.height,
                );
                let to = self.camera_to.unwrap_or(auto.to);
                let from = self.camera_from.unwrap_or(auto.from);
                let f = (from - to, to - centroid);
                self.follow = Some(Some(f));
                f
            }
        };
        let to = centroid + shift;
        let camera = Camera {
            fov_y_degrees: self.fov,
            ..Camera::look_at(to + offset, to)
        };
        let options = RenderOptions {
            camera: Some(camera),
            ..self.options
        };
        self.renderer = Some(
            Renderer::new(self.model, Bounds::of(positions), options)
                .map_err(|e| anyhow!("cannot draw with this camera: {e}"))?,
        );
        self.draw(index, positions)
    }

    fn draw(&mut self, index: u64, positions: &[DVec3]) -> anyhow::Result<()> {
        let renderer = self.renderer.as_ref().expect("a renderer");
        let image = renderer.render_frame(positions)?;
        for out in &mut self.outputs {
            out.add(index, &image)
                .with_context(|| format!("cannot write {}", out.describe()))?;
        }
        self.drawn += 1;
        self.bar.inc(1);
        Ok(())
    }

    fn finish(&mut self, args: &RenderArgs, started: Instant) -> Result<(), Failure> {
        if self.renderer.is_none() {
            self.renderer = Some(self.renderer()?);
            self.bar.set_position(0);
            self.bar.set_message("drawing");
            for (index, positions) in std::mem::take(&mut self.pending) {
                self.draw(index, &positions)?;
            }
        }
        self.bar.finish_and_clear();
        let outputs = std::mem::take(&mut self.outputs);
        let described: Vec<String> = outputs.iter().map(Output::describe).collect();
        for out in outputs {
            out.persist(self.drawn)?;
        }
        let seconds = started.elapsed().as_secs_f64();
        if !args.quiet {
            eprintln!(
                "{} frames of {}×{} {} in {seconds:.2} s ({:.1} ms per frame): {}",
                self.drawn,
                self.options.width,
                self.options.height,
                if self.simulated {
                    "simulated and drawn"
                } else {
                    "drawn"
                },
                1e3 * seconds / (self.drawn.max(1) as f64),
                described.join(" and ")
            );
        }
        Ok(())
    }
}

/// Feeds the simulation's frames to the drawer.
struct Sink<'a, 'm>(&'a mut Drawer<'m>);

impl FrameSink for Sink<'_, '_> {
    fn header(&mut self, _: &Header) -> std::io::Result<()> {
        Ok(())
    }

    fn frame(&mut self, frame: &Frame<'_>) -> std::io::Result<()> {
        self.0
            .frame(frame.index, frame.positions.to_vec())
            .map_err(std::io::Error::other)
    }

    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}
