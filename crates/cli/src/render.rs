//! `softbody render`: draw a scene's frames (simulated here on the CPU, or read from a JSON Lines
//! file written by `softbody run`) as PNG files and/or an animated GIF.
//!
//! The drawing is `softbody_render::animation`'s, the staging beside each destination
//! `softbody::output::Staged`'s; a run stopped by an instability still keeps the frames before
//! it, as `softbody run` does.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, anyhow};
use clap::Args;
use glam::DVec3;
use indicatif::ProgressBar;
use softbody::output::{Frame, FrameSink, Header, Staged, jsonl};
use softbody::run::RunError;
use softbody::service::{self, Hooks, RunFailure, RunRequest, SceneSource};
use softbody::{Backend, Model, Overrides, Scene};
use softbody_render::animation::{self, Animation, Animator, CameraPlan, Follow};
use softbody_render::{GifWriter, Image, RenderOptions};

use crate::args::{StepOverrides, positive};
use crate::{
    Failure, bad_input, failure, file_stem, output_failure, output_stem, progress, run_failure,
};

#[derive(Args)]
pub struct RenderArgs {
    /// A scene (.toml: simulated on --backend) or the frames of a run (.jsonl, written by
    /// `softbody run`; its scene file must still be where the header says, or be given with
    /// --scene).
    input: PathBuf,
    /// Where to draw: a directory of PNG files (DIR/frame_000000.png, …) or an animated GIF
    /// (a name ending in .gif); give it twice for both. A name with another extension of a file
    /// type (.mp4, .png) is refused, unless it is an existing directory. Default:
    /// out/{input file stem}-pictures/ (with the overrides and a GPU backend named after the
    /// stem, as `run` names its output).
    #[arg(long)]
    out: Vec<PathBuf>,
    /// Draw only the frames whose number is a multiple of K (frame 0, K, 2K, …); a GIF shows
    /// each for K frame intervals, keeping the simulated time.
    #[arg(long, value_name = "K", default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
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
    /// Draw the frame's time (`t = 1.23 s`) in the top-left corner.
    #[arg(long)]
    label: bool,
    /// Do not draw the bodies' shadows on the terrain.
    #[arg(long)]
    no_shadows: bool,
    /// Move the camera with the bodies: it keeps its offset from their centroid (the mean
    /// particle position), and by default frames about three times the bodies' first-frame size.
    /// Without --follow, --no-follow or a camera point, the camera follows bodies that travel
    /// more than 3√3 times their size.
    #[arg(long, overrides_with = "no_follow")]
    follow: bool,
    /// Keep the automatic camera still, framing the bodies' whole path.
    #[arg(long, overrides_with = "follow")]
    no_follow: bool,
    /// The scene of a .jsonl input, when it is no longer where the frames' header says (moved,
    /// or the frames come from another machine): it gives the terrain and the surface.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Solver backend for a .toml input: cpu (f64) or gpu (wgpu compute shaders, f32).
    #[arg(long, default_value = "cpu")]
    backend: Backend,
    /// No progress bar and no summary.
    #[arg(long, short)]
    quiet: bool,
    // Last: the heading applies to every option after it.
    #[command(
        flatten,
        next_help_heading = "Overrides of the scene (.toml input only)"
    )]
    overrides: StepOverrides,
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
    if input == Input::Frames
        && (!overrides.is_empty()
            || !args.overrides.sets().is_empty()
            || args.backend != Backend::Cpu)
    {
        return Err(bad_input(anyhow!(
            "--set, --integrator, --dt, --duration, --fps and --backend apply to a scene; frames from \
             {} are drawn as they were run",
            args.input.display()
        )));
    }
    if input == Input::Scene && args.scene.is_some() {
        return Err(bad_input(anyhow!(
            "--scene names the scene of a .jsonl input; {} is a scene itself",
            args.input.display()
        )));
    }
    if let Some(out) = args.out.iter().find(|p| names_another_file_type(p)) {
        return Err(bad_input(anyhow!(
            "{}: render writes an animated GIF (a name ending in .gif) or a directory of PNG \
             files (a name without an extension, or an existing directory), not .{}",
            out.display(),
            out.extension().unwrap_or_default().to_string_lossy()
        )));
    }
    let outs = if args.out.is_empty() {
        // Not out/<stem>/, where VTK's frames go, nor out/<stem>-ply/ or -obj/.
        let stem = match input {
            Input::Scene => {
                output_stem(&args.input, args.overrides.sets(), &overrides, args.backend)
            }
            Input::Frames => file_stem(&args.input).into_owned(),
        };
        vec![PathBuf::from("out").join(format!("{stem}-pictures"))]
    } else {
        args.out.clone()
    };

    match input {
        Input::Scene => {
            // Read and changed once; the drawer needs the model before the run starts.
            let loaded = service::load(
                &SceneSource::File(args.input.clone()),
                &args.overrides.settings(),
            )
            .map_err(bad_input)?;
            let (model, _) = Model::build(&loaded.scene);
            let sim = loaded.scene.simulation;
            let mut drawer = Drawer::new(&args, &model, &outs, sim.frame_rate, sim.frame_count())?;
            let request = RunRequest {
                scene: SceneSource::Text {
                    text: loaded.text,
                    origin: loaded.path,
                },
                backend: args.backend,
                ..RunRequest::file(&args.input)
            };
            let mut sink = Sink(&mut drawer);
            let outcome = service::execute(
                &request,
                Hooks {
                    observer: Some(&mut sink),
                    ..Hooks::default()
                },
            );
            let result = match outcome.result {
                Err(RunFailure::Run(RunError::Io(e))) => {
                    return Err(anyhow::Error::new(e)
                        .context("cannot write the pictures")
                        .into());
                }
                // Refused, or no solver: nothing was drawn, and nothing is left.
                Err(e) if outcome.frames == 0 => return Err(failure(e)),
                result => result,
            };
            // The frames before an instability are drawn and kept, as `run` keeps them.
            drawer.finish(&args, "simulated and drawn", started)?;
            result.map(drop).map_err(|e| {
                run_failure(
                    e,
                    Some(sim.integrator),
                    "the frames before it are drawn",
                    true,
                )
            })
        }
        Input::Frames => {
            let path = &args.input;
            let frames = jsonl::Reader::open(path).map_err(bad_input)?;
            let header = frames.header();
            let named = args.scene.as_ref().map(|p| p.display().to_string());
            let Some(scene_path) = named.as_ref().or(header.scene.as_ref()) else {
                return Err(bad_input(anyhow!(
                    "{}: the header names no scene file (frames of a scene built in code), so the \
                     terrain and surface are unknown; give it with --scene, or render the scene \
                     itself",
                    path.display()
                )));
            };
            let scene = Scene::from_file(scene_path).map_err(|e| {
                bad_input(anyhow!(
                    "the scene of {}: {e}{}",
                    path.display(),
                    if named.is_none() {
                        " (give its new place with --scene)"
                    } else {
                        ""
                    }
                ))
            })?;
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
                    .frame(frame.index, frame.time, frame.positions)
                    .context("cannot write the pictures")?;
            }
            drawer.finish(&args, "drawn", started)
        }
    }
}

/// Whether `out` ends in an extension of a file type other than GIF (1 to 4 ASCII letters and
/// digits after a letter: `.mp4`, `.png`, `.webm`), so that `render` would write a directory
/// of PNG files under a name that promises something else. An existing directory is taken as
/// one, and so is a name whose "extension" is not one (`run-dt0.001`, `take.final-cut`).
fn names_another_file_type(out: &Path) -> bool {
    let Some(ext) = out.extension().and_then(|e| e.to_str()) else {
        return false;
    };
    let looks_like_a_type = (1..=4).contains(&ext.len())
        && ext.starts_with(|c: char| c.is_ascii_alphabetic())
        && ext.chars().all(|c| c.is_ascii_alphanumeric());
    looks_like_a_type && !ext.eq_ignore_ascii_case("gif") && !out.is_dir()
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Input {
    Scene,
    Frames,
}

/// One `--out`: the pictures, and where they are staged until the end.
struct Destination {
    pictures: Animation<BufWriter<File>>,
    staged: Staged,
    /// How the summary names it.
    label: String,
}

impl Destination {
    /// A GIF for a name ending in `.gif`, else a directory of PNG files.
    fn create(path: &Path, options: &RenderOptions, frame_rate: f64) -> Result<Self, Failure> {
        let is_gif = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("gif"));
        if is_gif {
            let (staged, file) = Staged::file(path).map_err(output_failure)?;
            let gif = GifWriter::new(
                BufWriter::new(file),
                options.width,
                options.height,
                frame_rate,
            )?;
            Ok(Destination {
                pictures: Animation::Gif(gif),
                staged,
                label: path.display().to_string(),
            })
        } else {
            let staged =
                Staged::numbered_files(path, animation::PNG_STEM, "png").map_err(output_failure)?;
            Ok(Destination {
                pictures: Animation::Pngs(staged.path().to_owned()),
                staged,
                label: format!("{}/", path.display()),
            })
        }
    }
}

/// Every `--out`, and how many pictures each holds.
struct Pictures {
    outputs: Vec<Destination>,
    drawn: u64,
}

impl Pictures {
    fn write(&mut self, index: u64, image: &Image) -> anyhow::Result<()> {
        for out in &mut self.outputs {
            out.pictures
                .add(index, image)
                .with_context(|| format!("cannot write {}", out.label))?;
        }
        self.drawn += 1;
        Ok(())
    }

    /// Completes the files and puts them in place; returns how the summary names them.
    fn commit(self) -> Result<String, Failure> {
        let labels: Vec<String> = self.outputs.iter().map(|o| o.label.clone()).collect();
        for out in self.outputs {
            out.pictures
                .finish()
                .with_context(|| format!("cannot write {}", out.label))?;
            out.staged.commit().map_err(output_failure)?;
        }
        Ok(labels.join(" and "))
    }
}

/// Draws frames into the pictures, with progress.
struct Drawer<'m> {
    animator: Animator<'m>,
    options: RenderOptions,
    pictures: Pictures,
    bar: ProgressBar,
    /// Draw frames whose number is a multiple of this.
    every: u64,
    /// With --label, the time of each frame drawn, by frame number: the automatic camera's
    /// pictures come at the end, with their numbers alone.
    times: Option<std::collections::HashMap<u64, f64>>,
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
        let plan = CameraPlan {
            from: args.camera_from,
            to: args.camera_to,
            fov_y_degrees: args.fov,
            follow: match (args.follow, args.no_follow) {
                (true, _) => Follow::Always,
                (_, true) => Follow::Never,
                _ => Follow::Automatic,
            },
        };
        let animator = Animator::new(model, options, plan)
            .map_err(|e| bad_input(anyhow!("--camera-from/--camera-to: {e}")))?;
        let outputs = outs
            .iter()
            .map(|p| Destination::create(p, &options, frame_rate / args.every as f64))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Drawer {
            animator,
            options,
            pictures: Pictures { outputs, drawn: 0 },
            bar: progress::bar(frames.div_ceil(args.every), "frames", args.quiet),
            every: args.every,
            times: args.label.then(Default::default),
        })
    }

    fn frame(&mut self, index: u64, time: f64, positions: Vec<DVec3>) -> anyhow::Result<()> {
        if !index.is_multiple_of(self.every) {
            return Ok(());
        }
        if let Some(times) = &mut self.times {
            times.insert(index, time);
        }
        if let Some(mut image) = self.animator.frame(index, positions)? {
            label(&mut image, index, self.times.as_ref());
            self.pictures.write(index, &image)?;
        }
        self.bar.inc(1);
        Ok(())
    }

    /// Draws the frames kept for the automatic camera, puts the pictures in place and sums up
    /// what was `done`.
    fn finish(self, args: &RenderArgs, done: &str, started: Instant) -> Result<(), Failure> {
        let Drawer {
            animator,
            options,
            mut pictures,
            bar,
            every: _,
            times,
        } = self;
        let kept = animator.finish().map_err(|e| {
            bad_input(anyhow!(
                "cannot draw with this camera: {e} (see --camera-from/--camera-to)"
            ))
        })?;
        if kept.len() > 0 {
            bar.set_position(0);
            bar.set_message("drawing");
        }
        for picture in kept {
            let (index, mut image) = picture.map_err(anyhow::Error::new)?;
            label(&mut image, index, times.as_ref());
            pictures.write(index, &image)?;
            bar.inc(1);
        }
        bar.finish_and_clear();
        let drawn = pictures.drawn;
        let labels = pictures.commit()?;
        let seconds = started.elapsed().as_secs_f64();
        if !args.quiet {
            say!(
                "{drawn} frames of {}×{} {done} in {seconds:.2} s ({:.1} ms per frame): {labels}",
                options.width,
                options.height,
                1e3 * seconds / (drawn.max(1) as f64),
            );
        }
        Ok(())
    }
}

/// Draws frame `index`'s time on its picture, when `times` (--label) holds it.
fn label(image: &mut Image, index: u64, times: Option<&std::collections::HashMap<u64, f64>>) {
    if let Some(time) = times.and_then(|t| t.get(&index)) {
        softbody_render::label(image, &format!("t = {time:.2} s"));
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
            .frame(frame.index, frame.time, frame.positions.to_vec())
            .map_err(std::io::Error::other)
    }

    fn wants_springs(&self) -> bool {
        false
    }

    fn finish(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}
