//! Frame writers: JSON Lines, CSV and NPZ.
//!
//! Every writer emits complete records only, so a run stopped by an instability leaves a valid
//! file holding every frame before it (NPZ, an archive, is written when the sink finishes, from
//! frames spooled to temporary files).

mod csv;
mod jsonl;
mod npz;

use std::fmt;
use std::io::Write;
use std::path::Path;
use std::str::FromStr;

use glam::DVec3;
use serde::Serialize;
use softbody_scene::{Energies, Solver};

pub use self::csv::CsvSink;
pub use self::jsonl::JsonlSink;
pub use self::npz::NpzSink;

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Format {
    /// JSON Lines: a header line, then one object per frame.
    #[default]
    Jsonl,
    /// `frame,time,particle,x,y,z,vx,vy,vz`.
    Csv,
    /// NumPy archive: `time [F]`, `positions [F,N,3]`, `velocities [F,N,3]`, `springs [S,2]`.
    Npz,
}

impl Format {
    /// The file extension.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Jsonl => "jsonl",
            Format::Csv => "csv",
            Format::Npz => "npz",
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.extension())
    }
}

impl FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "jsonl" => Ok(Format::Jsonl),
            "csv" => Ok(Format::Csv),
            "npz" => Ok(Format::Npz),
            _ => Err(format!("unknown format `{s}`; expected jsonl, csv or npz")),
        }
    }
}

/// A body's particle range, as the header lists it.
#[derive(Debug, Clone, Serialize)]
pub struct HeaderBody {
    /// Body name.
    pub name: String,
    /// First particle index.
    pub first: u32,
    /// Particle count.
    pub count: u32,
}

/// What a frame file says about its run, before the frames.
#[derive(Debug, Clone, Serialize)]
pub struct Header {
    /// Format version.
    pub softbody_frames: u32,
    /// Particle count N.
    pub particles: usize,
    /// Bodies in particle order.
    pub bodies: Vec<HeaderBody>,
    /// Integrator name.
    pub integrator: String,
    /// `"cpu"` or `"gpu"`.
    pub backend: &'static str,
    /// What ran it (threads, adapter).
    pub device: String,
    /// Time step, seconds.
    pub dt: f64,
    /// Frames per simulated second.
    pub frame_rate: f64,
    /// Frames the run will write if it completes.
    pub frames: u64,
    /// Steps the run will take if it completes.
    pub steps: u64,
    /// The scene file the run came from (absolute), when it came from one: readers of the frames
    /// (`softbody render`) rebuild the terrain and the topology from it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scene: Option<String>,
    /// Springs as (a, b) particle pairs; not serialised in the JSON header.
    #[serde(skip)]
    pub springs: Vec<[u32; 2]>,
    /// Springs' rest lengths, metres, in the order of `springs`; not serialised in the JSON
    /// header.
    #[serde(skip)]
    pub rest: Vec<f64>,
    /// The bodies' outer surface ([`softbody_scene::Model::surface`]); not serialised in the
    /// JSON header.
    #[serde(skip)]
    pub surface: Vec<[u32; 3]>,
}

impl Header {
    /// The header of a run of `solver` writing `frames` frames of the scene in file `scene`
    /// (made absolute when it can be).
    pub fn new(solver: &dyn Solver, frames: u64, scene: Option<&Path>) -> Header {
        let model = solver.model();
        Header {
            softbody_frames: 1,
            particles: model.len(),
            bodies: model
                .bodies
                .iter()
                .map(|b| HeaderBody {
                    name: b.name.clone(),
                    first: b.first,
                    count: b.count,
                })
                .collect(),
            integrator: model.simulation.integrator.name().to_owned(),
            backend: solver.backend(),
            device: solver.device(),
            dt: model.simulation.dt,
            frame_rate: model.simulation.frame_rate,
            frames,
            steps: model.simulation.steps(),
            scene: scene.map(|p| {
                std::path::absolute(p)
                    .unwrap_or_else(|_| p.to_owned())
                    .display()
                    .to_string()
            }),
            springs: model
                .springs
                .a
                .iter()
                .zip(&model.springs.b)
                .map(|(&a, &b)| [a, b])
                .collect(),
            rest: model.springs.rest.clone(),
            surface: model.surface.clone(),
        }
    }
}

/// One frame.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    /// Frame number k.
    pub index: u64,
    /// Step it was taken at.
    pub step: u64,
    /// step·dt, seconds.
    pub time: f64,
    /// Positions, metres.
    pub positions: &'a [DVec3],
    /// Velocities, m/s.
    pub velocities: &'a [DVec3],
    /// Energies, joules.
    pub energies: Energies,
}

/// Where frames go.
pub trait FrameSink {
    /// Called once, first.
    fn header(&mut self, header: &Header) -> std::io::Result<()>;
    /// Called per frame, in order.
    fn frame(&mut self, frame: &Frame<'_>) -> std::io::Result<()>;
    /// Completes the output (also after a run stopped early).
    fn finish(&mut self) -> std::io::Result<()>;
}

/// A sink of `format` writing to `out`.
pub fn sink<'w>(
    format: Format,
    out: Box<dyn Write + 'w>,
) -> std::io::Result<Box<dyn FrameSink + 'w>> {
    Ok(match format {
        Format::Jsonl => Box::new(JsonlSink::new(out)),
        Format::Csv => Box::new(CsvSink::new(out)),
        Format::Npz => Box::new(NpzSink::new(out)?),
    })
}
