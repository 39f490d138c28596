//! JSON Lines: the header object, then one object per frame, each on its own line and flushed
//! whole; and [`Reader`], which reads such a file back.
//!
//! ```
//! use softbody::output::{self, Format, jsonl::Reader};
//! use softbody::{Backend, Scene};
//! let mut scene = Scene::from_file("scenes/jelly-on-ground.toml")?;
//! scene.simulation.duration = 0.1; // 3 frames after the first at 30 frames/s
//! let mut solver = softbody::open(&scene, Backend::Cpu, Some(1))?;
//! let mut bytes = Vec::new();
//! {
//!     let mut sink = output::sink(Format::Jsonl, Box::new(&mut bytes))?;
//!     softbody::run::run(solver.as_mut(), None, sink.as_mut(), &mut |_, _| {})?;
//!     sink.finish()?;
//! }
//! let mut reader = Reader::new(bytes.as_slice(), "frames.jsonl".as_ref())?;
//! assert_eq!(reader.header().particles, 216);
//! let first = reader.next().unwrap()?;
//! assert_eq!((first.index, first.time), (0, 0.0));
//! let (_, initial) = softbody::Model::build(&scene);
//! assert_eq!(first.positions, initial.x); // to the bit
//! assert_eq!(reader.count(), 3);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::borrow::Cow;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};
use softbody_scene::Energies;

use super::{Frame, FrameSink, Header};

/// Writes JSON Lines.
pub struct JsonlSink<'w> {
    out: Box<dyn Write + 'w>,
    line: Vec<u8>,
}

impl<'w> JsonlSink<'w> {
    /// A sink writing to `out`.
    pub fn new(out: Box<dyn Write + 'w>) -> Self {
        JsonlSink {
            out,
            line: Vec::new(),
        }
    }

    fn write_line(&mut self, value: &impl Serialize) -> std::io::Result<()> {
        self.line.clear();
        serde_json::to_writer(&mut self.line, value)?;
        self.line.push(b'\n');
        self.out.write_all(&self.line)?;
        self.out.flush()
    }
}

#[derive(Serialize, Deserialize)]
struct EnergyRecord {
    kinetic: f64,
    gravitational: f64,
    elastic: f64,
}

/// A frame line, borrowed from the run when written, owned when read.
#[derive(Serialize, Deserialize)]
struct FrameRecord<'a> {
    frame: u64,
    time: f64,
    positions: Cow<'a, [DVec3]>,
    velocities: Cow<'a, [DVec3]>,
    energy: EnergyRecord,
}

impl FrameSink for JsonlSink<'_> {
    fn header(&mut self, header: &Header) -> std::io::Result<()> {
        self.write_line(header)
    }

    fn frame(&mut self, f: &Frame<'_>) -> std::io::Result<()> {
        self.write_line(&FrameRecord {
            frame: f.index,
            time: f.time,
            positions: Cow::Borrowed(f.positions),
            velocities: Cow::Borrowed(f.velocities),
            energy: EnergyRecord {
                kinetic: f.energies.kinetic,
                gravitational: f.energies.gravitational,
                elastic: f.energies.elastic,
            },
        })
    }

    fn wants_springs(&self) -> bool {
        false
    }

    fn finish(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// The format version [`Reader`] reads (the header's `softbody_frames`).
pub const VERSION: u32 = 1;

/// A frame read back from JSON Lines.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameData {
    /// Frame number k.
    pub index: u64,
    /// Its time, seconds.
    pub time: f64,
    /// Positions, metres, one per particle.
    pub positions: Vec<DVec3>,
    /// Velocities, m/s, one per particle.
    pub velocities: Vec<DVec3>,
    /// Energies, joules.
    pub energies: Energies,
}

/// Why JSON Lines frames cannot be read. Each names the file, and the line where there is one.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file cannot be opened (line 0) or a line cannot be read.
    #[error("cannot read {}{}", file.display(), if *line > 0 { format!(":{line}") } else { String::new() })]
    Io {
        /// The file.
        file: PathBuf,
        /// 1-based; 0 when opening.
        line: usize,
        /// Why.
        source: io::Error,
    },
    /// The file has no header line.
    #[error("{}: empty, no header line", file.display())]
    Empty {
        /// The file.
        file: PathBuf,
    },
    /// The first line is not a frames header.
    #[error("{}:1: not a frames header", file.display())]
    Header {
        /// The file.
        file: PathBuf,
        /// What the JSON parser found.
        source: serde_json::Error,
    },
    /// The header is of another format version.
    #[error("{}:1: frames of format version {version}; this softbody reads version {VERSION}", file.display())]
    Version {
        /// The file.
        file: PathBuf,
        /// The header's `softbody_frames`.
        version: u32,
    },
    /// A line is not a frame.
    #[error("{}:{line}: not a frame", file.display())]
    Frame {
        /// The file.
        file: PathBuf,
        /// 1-based.
        line: usize,
        /// What the JSON parser found.
        source: serde_json::Error,
    },
    /// A frame's number is not above the previous frame's (a duplicated or reordered line):
    /// its picture or record would silently replace the earlier one's.
    #[error(
        "{}:{line}: frame {index} after frame {previous}: frame numbers must increase",
        file.display()
    )]
    Order {
        /// The file.
        file: PathBuf,
        /// 1-based.
        line: usize,
        /// This frame's number.
        index: u64,
        /// The previous frame's.
        previous: u64,
    },
    /// A frame holds another number of positions or velocities than the header's particles.
    #[error("{}:{line}: {found} {what} for {particles} particles", file.display())]
    Particles {
        /// The file.
        file: PathBuf,
        /// 1-based.
        line: usize,
        /// `"positions"` or `"velocities"`.
        what: &'static str,
        /// How many the frame holds.
        found: usize,
        /// The header's particle count.
        particles: usize,
    },
}

/// Reads frames written by [`JsonlSink`] (`softbody run`'s default output): the header first,
/// then the frames in file order as an iterator. Numbers come back to the bit as they were
/// written. Blank lines are skipped; the header's springs, rest lengths and surface are not in
/// the file and stay empty. Frame numbers must increase from line to line (they need not start
/// at 0 or be consecutive: a trimmed file reads).
pub struct Reader<R> {
    lines: io::Lines<R>,
    file: PathBuf,
    /// The last line read, 1-based.
    line: usize,
    header: Header,
    /// The last frame's number.
    previous: Option<u64>,
}

impl Reader<BufReader<File>> {
    /// Opens the file `path` and reads its header.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let file = File::open(path).map_err(|source| ReadError::Io {
            file: path.to_owned(),
            line: 0,
            source,
        })?;
        Reader::new(BufReader::new(file), path)
    }
}

impl<R: BufRead> Reader<R> {
    /// Reads the header from `input`; `file` names the input in errors.
    pub fn new(input: R, file: &Path) -> Result<Self, ReadError> {
        let mut lines = input.lines();
        let file = file.to_owned();
        let text = match lines.next() {
            None => return Err(ReadError::Empty { file }),
            Some(Err(source)) => {
                return Err(ReadError::Io {
                    file,
                    line: 1,
                    source,
                });
            }
            Some(Ok(text)) => text,
        };
        let header: Header = match serde_json::from_str(&text) {
            Ok(header) => header,
            Err(source) => return Err(ReadError::Header { file, source }),
        };
        if header.softbody_frames != VERSION {
            return Err(ReadError::Version {
                file,
                version: header.softbody_frames,
            });
        }
        Ok(Reader {
            lines,
            file,
            line: 1,
            header,
            previous: None,
        })
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    fn parse(&mut self, text: &str) -> Result<FrameData, ReadError> {
        let record: FrameRecord<'static> =
            serde_json::from_str(text).map_err(|source| ReadError::Frame {
                file: self.file.clone(),
                line: self.line,
                source,
            })?;
        if let Some(previous) = self.previous.filter(|&p| record.frame <= p) {
            return Err(ReadError::Order {
                file: self.file.clone(),
                line: self.line,
                index: record.frame,
                previous,
            });
        }
        self.previous = Some(record.frame);
        let particles = self.header.particles;
        for (what, found) in [
            ("positions", record.positions.len()),
            ("velocities", record.velocities.len()),
        ] {
            if found != particles {
                return Err(ReadError::Particles {
                    file: self.file.clone(),
                    line: self.line,
                    what,
                    found,
                    particles,
                });
            }
        }
        Ok(FrameData {
            index: record.frame,
            time: record.time,
            positions: record.positions.into_owned(),
            velocities: record.velocities.into_owned(),
            energies: Energies {
                kinetic: record.energy.kinetic,
                gravitational: record.energy.gravitational,
                elastic: record.energy.elastic,
            },
        })
    }
}

impl<R: BufRead> Iterator for Reader<R> {
    type Item = Result<FrameData, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let text = self.lines.next()?;
            self.line += 1;
            let text = match text {
                Ok(text) => text,
                Err(source) => {
                    return Some(Err(ReadError::Io {
                        file: self.file.clone(),
                        line: self.line,
                        source,
                    }));
                }
            };
            if !text.trim().is_empty() {
                return Some(self.parse(&text));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::series::tests::header;

    /// Values that a float printer without round-trip care gets wrong in the last bit.
    fn awkward(k: usize) -> DVec3 {
        let x = k as f64;
        DVec3::new(0.1 + 0.2 * x, -1.0 / (3.0 + x), 1e-300 * (x + 1.0).sqrt())
    }

    /// Writes `frames` frames of 3 particles as the sink does and returns the text.
    fn written(frames: usize) -> (Header, Vec<FrameData>, Vec<u8>) {
        let header = header(3, &[("b", 0, 3)], vec![[0, 1]], vec![1.0], vec![]);
        let data: Vec<FrameData> = (0..frames)
            .map(|f| FrameData {
                index: f as u64,
                time: f as f64 / 30.0,
                positions: (0..3).map(|p| awkward(3 * f + p)).collect(),
                velocities: (0..3).map(|p| -awkward(3 * f + p + 7)).collect(),
                energies: Energies {
                    kinetic: 0.1 * f as f64,
                    gravitational: std::f64::consts::PI,
                    elastic: -0.0,
                },
            })
            .collect();
        let mut bytes = Vec::new();
        let mut sink = JsonlSink::new(Box::new(&mut bytes));
        sink.header(&header).unwrap();
        for (k, d) in data.iter().enumerate() {
            sink.frame(&Frame {
                index: d.index,
                step: 10 * k as u64,
                time: d.time,
                positions: &d.positions,
                velocities: &d.velocities,
                energies: d.energies,
            })
            .unwrap();
        }
        sink.finish().unwrap();
        drop(sink);
        (header, data, bytes)
    }

    fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
        v.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
    }

    #[test]
    fn reads_back_what_the_sink_writes_to_the_bit() {
        let (header, data, bytes) = written(4);
        let reader = Reader::new(bytes.as_slice(), Path::new("f.jsonl")).unwrap();
        let h = reader.header().clone();
        assert_eq!(
            (h.particles, h.frames, h.steps, h.frame_rate, h.dt),
            (3, 2, 10, 100.0, 0.001)
        );
        assert_eq!((h.integrator.as_str(), h.backend.as_str()), ("rk4", "cpu"));
        assert_eq!((h.bodies[0].name.as_str(), h.bodies[0].count), ("b", 3));
        assert_eq!(h.scene, None);
        // Not in the file.
        assert!(h.springs.is_empty() && header.springs.len() == 1);
        let back: Vec<FrameData> = reader.map(Result::unwrap).collect();
        assert_eq!(back.len(), data.len());
        for (b, d) in back.iter().zip(&data) {
            assert_eq!(b.index, d.index);
            assert_eq!(b.time.to_bits(), d.time.to_bits());
            assert_eq!(bits(&b.positions), bits(&d.positions));
            assert_eq!(bits(&b.velocities), bits(&d.velocities));
            assert_eq!(b.energies.kinetic.to_bits(), d.energies.kinetic.to_bits());
            assert_eq!(b.energies.elastic.to_bits(), (-0.0f64).to_bits());
        }
    }

    #[test]
    fn blank_lines_are_skipped_and_errors_name_file_and_line() {
        let (_, _, bytes) = written(3);
        let text = String::from_utf8(bytes).unwrap();
        let mut lines: Vec<&str> = text.lines().collect();
        lines.insert(2, "   ");
        let broken = lines.join("\n").replace("\"frame\":2", "\"frame\":oops");
        let mut reader = Reader::new(broken.as_bytes(), Path::new("d/f.jsonl")).unwrap();
        assert_eq!(reader.next().unwrap().unwrap().index, 0);
        assert_eq!(reader.next().unwrap().unwrap().index, 1);
        let e = reader.next().unwrap().unwrap_err();
        assert!(matches!(e, ReadError::Frame { line: 5, .. }), "{e:?}");
        assert_eq!(e.to_string(), "d/f.jsonl:5: not a frame");
    }

    #[test]
    fn frame_numbers_must_increase_but_may_start_anywhere() {
        let (_, _, bytes) = written(4);
        let text = String::from_utf8(bytes).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let path = Path::new("f.jsonl");
        let read = |order: &[usize]| -> Vec<Result<u64, String>> {
            let text: Vec<&str> = std::iter::once(lines[0])
                .chain(order.iter().map(|&k| lines[k + 1]))
                .collect();
            Reader::new(text.join("\n").as_bytes(), path)
                .unwrap()
                .map(|f| f.map(|f| f.index).map_err(|e| e.to_string()))
                .collect()
        };
        assert_eq!(read(&[2, 3]), [Ok(2), Ok(3)], "trimmed at the start");
        assert_eq!(read(&[0, 3]), [Ok(0), Ok(3)], "a gap");
        assert_eq!(
            read(&[0, 1, 1]).last().unwrap(),
            &Err("f.jsonl:4: frame 1 after frame 1: frame numbers must increase".to_owned())
        );
        assert_eq!(
            read(&[2, 0]).last().unwrap(),
            &Err("f.jsonl:3: frame 0 after frame 2: frame numbers must increase".to_owned())
        );
    }

    #[test]
    fn headers_that_are_not_ours_are_refused() {
        let path = Path::new("f.jsonl");
        let e = Reader::new(&b""[..], path).err().unwrap();
        assert_eq!(e.to_string(), "f.jsonl: empty, no header line");
        let e = Reader::new(&b"{\"frame\":0}\n"[..], path).err().unwrap();
        assert!(matches!(e, ReadError::Header { .. }), "{e:?}");
        assert_eq!(e.to_string(), "f.jsonl:1: not a frames header");

        let (_, _, bytes) = written(1);
        let text = String::from_utf8(bytes).unwrap();
        let v2 = text.replace("\"softbody_frames\":1", "\"softbody_frames\":2");
        let e = Reader::new(v2.as_bytes(), path).err().unwrap();
        assert!(matches!(e, ReadError::Version { version: 2, .. }), "{e:?}");

        let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
        lines[1] = lines[1].replacen("[[", "[[9.0,9.0,9.0],[", 1);
        let e = Reader::new(lines.join("\n").as_bytes(), path)
            .unwrap()
            .next()
            .unwrap()
            .unwrap_err();
        assert_eq!(e.to_string(), "f.jsonl:2: 4 positions for 3 particles");

        let e = Reader::open(Path::new("/nonexistent/f.jsonl"))
            .err()
            .unwrap();
        assert!(matches!(e, ReadError::Io { line: 0, .. }), "{e:?}");
        assert_eq!(e.to_string(), "cannot read /nonexistent/f.jsonl");
    }
}
