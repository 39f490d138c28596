//! Frame writers: JSON Lines, CSV and NPZ (one file), and VTK, PLY and OBJ (a file per frame).
//!
//! Every writer emits complete records only, so a run stopped by an instability leaves valid
//! output holding every frame before it (NPZ, an archive, is written when the sink finishes,
//! from frames spooled to temporary files; VTK's `.pvd` collection likewise). [`Output`] puts
//! a writer's files in place only when the run ends: see [`destination`].

mod csv;
pub mod destination;
pub mod jsonl;
mod npz;
mod obj;
mod ply;
mod series;
mod vtk;

use std::fmt;
use std::io::Write;
use std::path::Path;
use std::str::FromStr;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use softbody_scene::{Energies, Solver};

pub use self::csv::CsvSink;
pub use self::destination::{Output, OutputError, Staged};
pub use self::jsonl::JsonlSink;
pub use self::npz::NpzSink;
pub use self::obj::ObjSink;
pub use self::ply::PlySink;
pub use self::vtk::{KIND_SPRING, KIND_SURFACE, VtkSink};

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
    /// ParaView: a `.pvd` collection and a directory of `.vtu` files, one per frame (particles
    /// with velocities, springs with strains, the surface).
    Vtk,
    /// A directory of binary PLY surface meshes, one per frame.
    Ply,
    /// A directory of OBJ surface meshes, one per frame.
    Obj,
}

impl Format {
    /// Every format, in the order the help lists them.
    pub const ALL: [Format; 6] = [
        Format::Jsonl,
        Format::Csv,
        Format::Npz,
        Format::Vtk,
        Format::Ply,
        Format::Obj,
    ];

    /// The format's name, as `--format` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Format::Jsonl => "jsonl",
            Format::Csv => "csv",
            Format::Npz => "npz",
            Format::Vtk => "vtk",
            Format::Ply => "ply",
            Format::Obj => "obj",
        }
    }

    /// The file extension: the output file's, the `.pvd`'s for VTK, each frame file's for PLY
    /// and OBJ (whose output is a directory).
    pub fn extension(self) -> &'static str {
        match self {
            Format::Jsonl => "jsonl",
            Format::Csv => "csv",
            Format::Npz => "npz",
            Format::Vtk => "pvd",
            Format::Ply => "ply",
            Format::Obj => "obj",
        }
    }

    /// Whether the format writes a file per frame (into a directory) rather than one file.
    pub fn is_series(self) -> bool {
        matches!(self, Format::Vtk | Format::Ply | Format::Obj)
    }

    /// The format an output path names by its extension, if it names one: `.jsonl`, `.csv`,
    /// `.npz`, `.pvd` (VTK), `.ply`, `.obj`.
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?;
        Format::ALL.into_iter().find(|f| ext == f.extension())
    }

    /// The format of an output to `out` (`None`: the default path; `-`: standard output) asked
    /// for with `--format` `explicit`: the flag, else the extension's ([`Format::from_path`]),
    /// else JSON Lines for a name without an extension. Refuses a flag that the extension
    /// contradicts (`--out a.csv --format jsonl`), and an extension that names no format unless
    /// the flag chooses one (`--out run.txt --format csv` writes CSV to `run.txt`).
    pub fn for_output(explicit: Option<Format>, out: Option<&Path>) -> Result<Format, OutputError> {
        let Some(path) = out.filter(|p| *p != Path::new("-")) else {
            return Ok(explicit.unwrap_or_default());
        };
        let named = Format::from_path(path);
        match (explicit, named, path.extension()) {
            (Some(flag), Some(named), _) if flag != named => Err(OutputError::Extension {
                path: path.to_owned(),
                problem: format!(
                    "its extension is {named}'s, but --format {flag} was given; make them agree \
                     or drop one"
                ),
            }),
            (Some(flag), _, _) => Ok(flag),
            (None, Some(named), _) => Ok(named),
            (None, None, None) => Ok(Format::default()),
            (None, None, Some(ext)) => {
                let hint = match ext.to_str() {
                    Some("json") => " (JSON Lines files end in .jsonl)",
                    Some("vtu") => " (VTK output is named by its .pvd collection)",
                    _ => "",
                };
                Err(OutputError::Extension {
                    path: path.to_owned(),
                    problem: format!(
                        ".{} names no output format{hint}; use .jsonl, .csv, .npz, .pvd (vtk), \
                         .ply or .obj, or choose the format with --format",
                        ext.to_string_lossy()
                    ),
                })
            }
        }
    }

    /// The default output path of a scene whose file stem is `stem`:
    /// `out/<stem>.<extension>`, or the directory `out/<stem>-<extension>` for PLY and OBJ:
    /// not `out/<stem>`, where VTK's `out/<stem>.pvd` keeps its frames, so that every format
    /// of one scene has a default of its own.
    pub fn default_path(self, stem: &str) -> std::path::PathBuf {
        if matches!(self, Format::Ply | Format::Obj) {
            Path::new("out").join(format!("{stem}-{}", self.extension()))
        } else {
            Path::new("out").join(format!("{stem}.{}", self.extension()))
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match Format::ALL.into_iter().find(|f| f.name() == s) {
            Some(f) => Ok(f),
            None => Err(format!(
                "unknown format `{s}`; expected jsonl, csv, npz, vtk, ply or obj"
            )),
        }
    }
}

/// A body's particle range, as the header lists it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeaderBody {
    /// Body name.
    pub name: String,
    /// First particle index.
    pub first: u32,
    /// Particle count.
    pub count: u32,
}

/// What a frame file says about its run, before the frames (read back from JSON Lines by
/// [`jsonl::Reader`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    pub backend: String,
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
    /// The text of the scene that ran (TOML): the scene file's, with the `--set`s and
    /// overrides written in when there are any ([`crate::scene_text`]), so that a frames file
    /// says how to run it again. Absent for scenes built in code.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene_text: Option<String>,
    /// Particle masses, kg; not serialised in the JSON header (empty when read).
    #[serde(skip)]
    pub masses: Vec<f64>,
    /// Springs as (a, b) particle pairs; not serialised in the JSON header (empty when read).
    #[serde(skip)]
    pub springs: Vec<[u32; 2]>,
    /// Springs' rest lengths, metres, in the order of `springs`; not serialised in the JSON
    /// header (empty when read).
    #[serde(skip)]
    pub rest: Vec<f64>,
    /// Springs' stiffness k_s, N/m, in the order of `springs`; not serialised in the JSON
    /// header (empty when read).
    #[serde(skip)]
    pub stiffness: Vec<f64>,
    /// Springs' damping k_d, N·s/m, in the order of `springs`; not serialised in the JSON
    /// header (empty when read).
    #[serde(skip)]
    pub damping: Vec<f64>,
    /// The bodies' outer surface ([`softbody_scene::Model::surface`]); not serialised in the
    /// JSON header (empty when read).
    #[serde(skip)]
    pub surface: Vec<[u32; 3]>,
    /// The mesh bodies' input meshes, carried by their particles
    /// ([`softbody_scene::Model::embedded`]); not serialised in the JSON header (empty when
    /// read).
    #[serde(skip)]
    pub embedded: softbody_scene::model::Embedded,
}

impl Header {
    /// The header of a run of `solver` writing `frames` frames of `scene` (its path made
    /// absolute when it can be, and its text). Its spring arrays are empty unless `springs`
    /// ([`FrameSink::wants_springs`]).
    pub fn new(
        solver: &dyn Solver,
        frames: u64,
        scene: Option<crate::run::SceneFile<'_>>,
        springs: bool,
    ) -> Header {
        let model = solver.model();
        // Visited rather than taken from `Model::springs`, which would keep the list for the
        // rest of the run: a cuboid's model holds its springs as a stencil only.
        let count = if springs { model.spring_count() } else { 0 };
        let (mut springs, mut rest) = (Vec::with_capacity(count), Vec::with_capacity(count));
        let (mut stiffness, mut damping) = (Vec::with_capacity(count), Vec::with_capacity(count));
        if count > 0 {
            model.for_each_spring(|a, b, r, k, d| {
                springs.push([a, b]);
                rest.push(r);
                stiffness.push(k);
                damping.push(d);
            });
        }
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
            backend: solver.backend().to_string(),
            device: solver.device(),
            dt: model.simulation.dt,
            frame_rate: model.simulation.frame_rate,
            frames,
            steps: model.simulation.steps(),
            scene: scene.map(|s| {
                std::path::absolute(s.path)
                    .unwrap_or_else(|_| s.path.to_owned())
                    .display()
                    .to_string()
            }),
            scene_text: scene.map(|s| s.text.to_owned()),
            masses: model.mass.clone(),
            springs,
            rest,
            stiffness,
            damping,
            surface: model.surface.clone(),
            embedded: model.embedded.clone(),
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
    /// Called once, first (or [`FrameSink::take_header`] is).
    fn header(&mut self, header: &Header) -> std::io::Result<()>;
    /// [`FrameSink::header`], given the header to keep: what a run calls, so that a sink that
    /// keeps large parts of it (the springs) moves them instead of copying them.
    fn take_header(&mut self, header: Header) -> std::io::Result<()> {
        self.header(&header)
    }
    /// Called per frame, in order.
    fn frame(&mut self, frame: &Frame<'_>) -> std::io::Result<()>;
    /// Completes the output (also after a run stopped early).
    fn finish(&mut self) -> std::io::Result<()>;
    /// Whether the sink reads the header's spring arrays (`springs`, `rest`, `stiffness`,
    /// `damping`). A sink that does not says false, and the run leaves them empty: they take
    /// 40 bytes a spring, about three times a lattice body's whole model.
    fn wants_springs(&self) -> bool {
        true
    }
}

/// A staged file, buffered, whose failures name the destination it is staged for: the sinks
/// only see a writer.
pub(crate) struct Named {
    file: std::io::BufWriter<std::fs::File>,
    destination: std::path::PathBuf,
}

impl Named {
    pub(crate) fn new(file: std::fs::File, destination: &Path) -> Named {
        Named {
            file: std::io::BufWriter::new(file),
            destination: destination.to_owned(),
        }
    }

    fn named(&self, e: std::io::Error) -> std::io::Error {
        std::io::Error::new(e.kind(), format!("{}: {e}", self.destination.display()))
    }
}

impl std::io::Write for Named {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.file.write(buf).map_err(|e| self.named(e))
    }

    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.file.write_all(buf).map_err(|e| self.named(e))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush().map_err(|e| self.named(e))
    }
}

/// A sink of single-file `format` writing to `out`; the series formats (VTK, PLY, OBJ) write
/// into a directory and are made by [`Output::create`].
pub fn sink<'w>(
    format: Format,
    out: Box<dyn Write + 'w>,
) -> std::io::Result<Box<dyn FrameSink + 'w>> {
    Ok(match format {
        Format::Jsonl => Box::new(JsonlSink::new(out)),
        Format::Csv => Box::new(CsvSink::new(out)),
        Format::Npz => Box::new(NpzSink::new(out)?),
        Format::Vtk | Format::Ply | Format::Obj => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("{format} output is a directory of files, not a stream"),
            ));
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_parse_print_and_follow_the_out_path() {
        for f in Format::ALL {
            assert_eq!(f.name().parse::<Format>(), Ok(f));
            assert_eq!(f.to_string(), f.name());
        }
        let e = "vtu".parse::<Format>().unwrap_err();
        assert_eq!(
            e,
            "unknown format `vtu`; expected jsonl, csv, npz, vtk, ply or obj"
        );
        assert_eq!(Format::from_path(Path::new("a/b.pvd")), Some(Format::Vtk));
        assert_eq!(Format::from_path(Path::new("b.npz")), Some(Format::Npz));
        assert_eq!(Format::from_path(Path::new("b.ply")), Some(Format::Ply));
        assert_eq!(Format::from_path(Path::new("b.vtu")), None);
        assert_eq!(Format::from_path(Path::new("b")), None);
        assert_eq!(Format::Vtk.default_path("s"), Path::new("out/s.pvd"));
        assert_eq!(Format::Obj.default_path("s"), Path::new("out/s-obj"));
        assert_eq!(Format::Ply.default_path("s"), Path::new("out/s-ply"));
        assert!(Format::Ply.is_series() && !Format::Csv.is_series());
    }

    #[test]
    fn the_output_format_is_the_flag_or_the_extension_and_they_agree() {
        let format = |flag: Option<Format>, out: Option<&str>| {
            Format::for_output(flag, out.map(Path::new)).map_err(|e| e.to_string())
        };
        for f in Format::ALL {
            let name = format!("out/run.{}", f.extension());
            assert_eq!(format(None, Some(&name)), Ok(f));
            assert_eq!(format(Some(f), Some(&name)), Ok(f));
        }
        assert_eq!(format(None, None), Ok(Format::Jsonl));
        assert_eq!(format(None, Some("-")), Ok(Format::Jsonl));
        assert_eq!(format(Some(Format::Csv), Some("-")), Ok(Format::Csv));
        assert_eq!(format(None, Some("frames")), Ok(Format::Jsonl));
        assert_eq!(format(Some(Format::Csv), Some("run.txt")), Ok(Format::Csv));
        assert_eq!(
            format(Some(Format::Ply), Some("out/run.v2")),
            Ok(Format::Ply)
        );
        let e = format(Some(Format::Jsonl), Some("b.npz")).unwrap_err();
        assert_eq!(
            e,
            "b.npz: its extension is npz's, but --format jsonl was given; make them agree or \
             drop one"
        );
        let e = format(None, Some("a.json")).unwrap_err();
        assert!(
            e.starts_with("a.json: .json names no output format (JSON Lines files end in .jsonl)"),
            "{e}"
        );
        let e = format(None, Some("a.vtu")).unwrap_err();
        assert!(
            e.contains("(VTK output is named by its .pvd collection)"),
            "{e}"
        );
        assert!(format(None, Some("c.dat")).is_err());
    }
}
