//! Checkpoints: runs that survive a SIGKILL (`softbody run --checkpoint-every N`, `--resume`).
//!
//! A run that checkpoints keeps a directory beside its destination, `<destination>.checkpoint`
//! ([`Checkpoints::dir_for`]), holding two files:
//!
//! - `frames`, the journal: every frame written so far, as raw little-endian numbers (frame
//!   number, step, time, the three energies, then each particle's position and velocity), one
//!   fixed-size record per frame, appended as the run goes;
//! - `checkpoint`: how many of the journal's frames are safely on disk, the solver's
//!   [`History`] after the last of them, and a fingerprint of what is being run (the model,
//!   the initial state and the backend).
//!
//! Every N frames the journal is flushed and synced, and then `checkpoint` is replaced by a
//! rename, so that after a kill at any instant the directory holds a checkpoint and at least
//! the frames it counts. A resumed run checks the fingerprint, writes the counted frames to
//! its output from the journal (so the output is made from scratch, whatever its format),
//! restores the solver to the last of them ([`Solver::restore`]) and goes on: its frames are
//! those of an uninterrupted run, byte for byte (same scene, backend, thread count and format).
//! The directory is removed when the run ends, unless a signal stopped it (then it can be
//! resumed).
//!
//! The journal holds 48 + 48·N bytes per frame for N particles, beside the output itself.

use std::fmt::Write as _;
use std::fs::{self, File, OpenOptions};
use std::hash::Hasher;
use std::io::{self, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use fnv::FnvHasher;
use glam::DVec3;
use softbody_scene::{Energies, History, Solver, State, StepError};

use crate::output::Frame;

/// The first bytes of a `checkpoint` file (the format's version is its last digit).
const MAGIC: &[u8; 8] = b"SBCKPT01";
/// The checkpoint's name in its directory (beside the `frames` journal).
const FILE: &str = "checkpoint";

/// Why checkpoints cannot be written or resumed.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The checkpoint belongs to another run: the scene, an override or the backend changed.
    #[error(
        "{}: the checkpoint is of another run (the scene, its overrides or the backend \
         changed since it was written); run without --resume to start again, or remove it",
        .0.display()
    )]
    Mismatch(PathBuf),
    /// A checkpoint file that this version cannot read.
    #[error("{}: not a checkpoint of this version of softbody ({})", .0.display(), .1)]
    Corrupt(PathBuf, String),
    /// Reading or writing failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done, naming the path.
        what: String,
        /// The failure.
        source: io::Error,
    },
    /// The solver could not give or take its history.
    #[error("{0}")]
    Solver(#[from] StepError),
}

impl CheckpointError {
    /// Whether resuming was refused because of what is there (another run's checkpoint, a
    /// damaged one), rather than a failing file system.
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            CheckpointError::Mismatch(_) | CheckpointError::Corrupt(..)
        )
    }
}

fn io_context<T>(
    result: io::Result<T>,
    what: impl FnOnce() -> String,
) -> Result<T, CheckpointError> {
    result.map_err(|source| CheckpointError::Io {
        what: what(),
        source,
    })
}

/// A run's checkpoint directory, open for the run to journal its frames into.
pub struct Checkpoints {
    dir: PathBuf,
    /// Frames between checkpoints.
    every: u64,
    fingerprint: u64,
    journal: BufWriter<File>,
    /// Frames in the journal.
    journaled: u64,
    /// Bytes of one journal record.
    record: u64,
    /// Frames the run replays from the journal before stepping (a resumed run).
    resumed: u64,
    history: History,
}

/// A frame read back from the journal.
pub(crate) struct JournalFrame {
    pub index: u64,
    pub step: u64,
    pub time: f64,
    pub energies: Energies,
    pub state: State,
}

impl Checkpoints {
    /// The checkpoint directory of an output to `destination`: `<destination>.checkpoint`.
    pub fn dir_for(destination: &Path) -> PathBuf {
        let mut name = destination.as_os_str().to_owned();
        name.push(".checkpoint");
        PathBuf::from(name)
    }

    /// Starts checkpointing a run of `solver` (at its first step) every `every` frames into
    /// `dir`, replacing a checkpoint already there.
    pub fn create(
        dir: &Path,
        every: u64,
        solver: &mut dyn Solver,
    ) -> Result<Checkpoints, CheckpointError> {
        let fingerprint = fingerprint(solver)?;
        if dir.exists() {
            io_context(fs::remove_dir_all(dir), || {
                format!("cannot replace the checkpoint {}", dir.display())
            })?;
        }
        io_context(fs::create_dir_all(dir), || {
            format!("cannot create the checkpoint {}", dir.display())
        })?;
        let journal = io_context(File::create(dir.join("frames")), || {
            format!("cannot create {}", dir.join("frames").display())
        })?;
        let checkpoints = Checkpoints {
            dir: dir.to_owned(),
            every: every.max(1),
            fingerprint,
            journal: BufWriter::new(journal),
            journaled: 0,
            record: record_bytes(solver.model().len()),
            resumed: 0,
            history: History::default(),
        };
        // A checkpoint of no frames: a kill before the first one resumes from the start.
        checkpoints.write_checkpoint(0)?;
        Ok(checkpoints)
    }

    /// Resumes the run of `solver` (freshly opened, at its first step) checkpointed in `dir`:
    /// `None` when there is no checkpoint there. Checkpoints go on every `every` frames, or as
    /// often as before when `None`.
    pub fn resume(
        dir: &Path,
        every: Option<u64>,
        solver: &mut dyn Solver,
    ) -> Result<Option<Checkpoints>, CheckpointError> {
        let path = dir.join(FILE);
        let bytes = match fs::read(&path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(e) => {
                return Err(CheckpointError::Io {
                    what: format!("cannot read {}", path.display()),
                    source: e,
                });
            }
        };
        let saved =
            Saved::parse(&bytes).map_err(|why| CheckpointError::Corrupt(path.clone(), why))?;
        if saved.fingerprint != fingerprint(solver)? {
            return Err(CheckpointError::Mismatch(dir.to_owned()));
        }
        let record = record_bytes(solver.model().len());
        let frames_path = dir.join("frames");
        // A checkpoint without its journal is damaged, not a failing disk.
        let mut journal = match OpenOptions::new().read(true).write(true).open(&frames_path) {
            Err(e) if e.kind() == io::ErrorKind::NotFound => {
                return Err(CheckpointError::Corrupt(
                    frames_path,
                    "the journal of its frames is missing".into(),
                ));
            }
            opened => io_context(opened, || format!("cannot open {}", frames_path.display()))?,
        };
        let len = io_context(journal.metadata(), || {
            format!("cannot read {}", frames_path.display())
        })?
        .len();
        // A damaged count must not wrap the product into a length the journal has.
        if saved
            .frames
            .checked_mul(record)
            .is_none_or(|bytes| len < bytes)
        {
            return Err(CheckpointError::Corrupt(
                frames_path,
                format!(
                    "it holds {len} bytes, fewer than the {} frames the checkpoint counts",
                    saved.frames
                ),
            ));
        }
        // Frames journaled after the checkpoint are computed again.
        io_context(
            journal
                .set_len(saved.frames * record)
                .and_then(|()| journal.seek(SeekFrom::End(0)).map(drop)),
            || format!("cannot write {}", frames_path.display()),
        )?;
        Ok(Some(Checkpoints {
            dir: dir.to_owned(),
            every: every.unwrap_or(saved.every).max(1),
            fingerprint: saved.fingerprint,
            journal: BufWriter::new(journal),
            journaled: saved.frames,
            record,
            resumed: saved.frames,
            history: saved.history,
        }))
    }

    /// Where the checkpoint is.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The checkpoint file.
    pub fn file(&self) -> PathBuf {
        self.dir.join(FILE)
    }

    /// Frames a resumed run takes from the journal (0 for a fresh run).
    pub fn resumed_frames(&self) -> u64 {
        self.resumed
    }

    /// Removes the checkpoint (the run is over).
    pub fn remove(self) -> Result<(), CheckpointError> {
        drop(self.journal);
        io_context(fs::remove_dir_all(&self.dir), || {
            format!("cannot remove the checkpoint {}", self.dir.display())
        })
    }

    /// The frames to replay and the solver's history after the last of them.
    pub(crate) fn replay(&self) -> Result<(Vec<JournalFrame>, History), CheckpointError> {
        let path = self.dir.join("frames");
        let cannot = || format!("cannot read {}", path.display());
        let file = io_context(File::open(&path), cannot)?;
        let mut reader = BufReader::new(file);
        let n = ((self.record - 48) / 48) as usize;
        let mut frames = Vec::with_capacity(self.resumed as usize);
        let mut buf = vec![0u8; self.record as usize];
        for _ in 0..self.resumed {
            io_context(reader.read_exact(&mut buf), cannot)?;
            let word = |k: usize| u64::from_le_bytes(buf[8 * k..8 * k + 8].try_into().expect("8"));
            let float = |k: usize| f64::from_bits(word(k));
            let vectors = |first: usize| {
                (0..n)
                    .map(|i| {
                        DVec3::new(
                            float(first + 3 * i),
                            float(first + 3 * i + 1),
                            float(first + 3 * i + 2),
                        )
                    })
                    .collect()
            };
            frames.push(JournalFrame {
                index: word(0),
                step: word(1),
                time: float(2),
                energies: Energies {
                    kinetic: float(3),
                    gravitational: float(4),
                    elastic: float(5),
                },
                state: State {
                    x: vectors(6),
                    v: vectors(6 + 3 * n),
                },
            });
        }
        Ok((frames, self.history.clone()))
    }

    /// Appends `frame` to the journal, and checkpoints `solver` (which is at that frame) every
    /// `every` frames.
    pub(crate) fn frame(
        &mut self,
        frame: &Frame<'_>,
        solver: &mut dyn Solver,
    ) -> Result<(), CheckpointError> {
        let cannot = || format!("cannot write {}", self.dir.join("frames").display());
        let mut record = Vec::with_capacity(self.record as usize);
        for word in [frame.index, frame.step] {
            record.extend(word.to_le_bytes());
        }
        let e = frame.energies;
        for x in [frame.time, e.kinetic, e.gravitational, e.elastic] {
            record.extend(x.to_le_bytes());
        }
        for v in frame.positions.iter().chain(frame.velocities) {
            record.extend(v.to_array().into_iter().flat_map(f64::to_le_bytes));
        }
        io_context(self.journal.write_all(&record), cannot)?;
        self.journaled += 1;
        if self.journaled.is_multiple_of(self.every) {
            io_context(
                self.journal
                    .flush()
                    .and_then(|()| self.journal.get_ref().sync_data()),
                cannot,
            )?;
            self.history = solver.history()?;
            self.write_checkpoint(self.journaled)?;
        }
        Ok(())
    }

    /// Replaces `checkpoint` with one counting `frames` journaled frames, atomically.
    fn write_checkpoint(&self, frames: u64) -> Result<(), CheckpointError> {
        let path = self.file();
        let mut bytes = MAGIC.to_vec();
        for word in [
            self.fingerprint,
            self.every,
            frames,
            self.history.parts.len() as u64,
        ] {
            bytes.extend(word.to_le_bytes());
        }
        for (name, data) in &self.history.parts {
            bytes.extend((name.len() as u64).to_le_bytes());
            bytes.extend(name.as_bytes());
            bytes.extend((data.len() as u64).to_le_bytes());
            bytes.extend(data);
        }
        let staged = self.dir.join("checkpoint.new");
        io_context(
            File::create(&staged)
                .and_then(|mut f| f.write_all(&bytes).and_then(|()| f.sync_all()))
                .and_then(|()| fs::rename(&staged, &path))
                .and_then(|()| File::open(&self.dir).and_then(|d| d.sync_all())),
            || format!("cannot write {}", path.display()),
        )
    }
}

/// Bytes of a journal record for `n` particles.
fn record_bytes(n: usize) -> u64 {
    48 + 48 * n as u64
}

/// What a `checkpoint` file says.
struct Saved {
    fingerprint: u64,
    every: u64,
    frames: u64,
    history: History,
}

impl Saved {
    fn parse(bytes: &[u8]) -> Result<Saved, String> {
        let mut cursor = Cursor(
            bytes
                .strip_prefix(MAGIC.as_slice())
                .ok_or("it does not start as one")?,
        );
        let (fingerprint, every, frames, parts) = (
            cursor.word()?,
            cursor.word()?,
            cursor.word()?,
            cursor.word()?,
        );
        let mut history = History::default();
        for _ in 0..parts {
            let len = cursor.word()?;
            let name =
                std::str::from_utf8(cursor.take(len)?).map_err(|_| "a part's name is not UTF-8")?;
            let len = cursor.word()?;
            history.push(name, cursor.take(len)?.to_vec());
        }
        Ok(Saved {
            fingerprint,
            every,
            frames,
            history,
        })
    }
}

/// The bytes of a `checkpoint` file not read yet.
struct Cursor<'a>(&'a [u8]);

impl<'a> Cursor<'a> {
    fn take(&mut self, len: u64) -> Result<&'a [u8], String> {
        let len = usize::try_from(len)
            .ok()
            .filter(|&l| l <= self.0.len())
            .ok_or("it is cut short")?;
        let (head, tail) = self.0.split_at(len);
        self.0 = tail;
        Ok(head)
    }

    fn word(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
}

/// An FNV-1a hash of what `solver` runs: its model and its current (initial) state as `Debug`
/// prints them (every number to the bit: Rust prints the shortest text that reads back to the
/// same float), and its backend.
fn fingerprint(solver: &mut dyn Solver) -> Result<u64, StepError> {
    struct Hash(FnvHasher);
    impl std::fmt::Write for Hash {
        fn write_str(&mut self, s: &str) -> std::fmt::Result {
            self.0.write(s.as_bytes());
            Ok(())
        }
    }
    let mut hash = Hash(FnvHasher::default());
    let backend = solver.backend();
    let _ = write!(hash, "{backend} {:?}", solver.model());
    let _ = write!(hash, "{:?}", solver.state()?);
    Ok(hash.0.finish())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Backend;

    /// A jelly's solver, checkpointed every frame into `f.jsonl.checkpoint` in a fresh
    /// directory.
    fn checkpointed() -> (tempfile::TempDir, Box<dyn Solver>) {
        let scene = softbody_scene::Scene::from_file(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenes/jelly-on-ground.toml"
        ))
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let mut solver = crate::open(&scene, Backend::Cpu, Some(1)).unwrap();
        Checkpoints::create(&dir.path().join("f.jsonl.checkpoint"), 1, solver.as_mut()).unwrap();
        (dir, solver)
    }

    /// A frame count damaged so that frames × record wraps around u64 is refused as corrupt,
    /// and the journal is left as it was (not cut to the wrapped length).
    #[test]
    fn a_damaged_frame_count_is_refused_without_touching_the_journal() {
        let (dir, mut solver) = checkpointed();
        let at = dir.path().join("f.jsonl.checkpoint");
        let journal = at.join("frames");
        let record = record_bytes(solver.model().len());
        // The smallest count whose product with the record wraps, and a journal that long:
        // the unchecked size check passed it and cut the journal to that length.
        let wrapping = u64::MAX / record + 1;
        let wrapped = wrapping.wrapping_mul(record) as usize;
        std::fs::write(&journal, vec![0u8; wrapped + 4096]).unwrap();
        let mut saved = std::fs::read(at.join(FILE)).unwrap();
        let count = MAGIC.len() + 16;
        saved[count..count + 8].copy_from_slice(&wrapping.to_le_bytes());
        std::fs::write(at.join(FILE), &saved).unwrap();
        let refused = Checkpoints::resume(&at, None, solver.as_mut());
        let Err(CheckpointError::Corrupt(path, why)) = refused else {
            panic!(
                "accepted: {:?}",
                refused.map(|c| c.map(|c| c.resumed_frames()))
            );
        };
        assert_eq!(path, journal);
        assert!(why.contains("fewer than the"), "{why}");
        let len = std::fs::metadata(&journal).unwrap().len();
        assert_eq!(len, wrapped as u64 + 4096);
    }

    /// A checkpoint whose journal is gone is refused as damaged (bad input, exit status 2),
    /// not as a failure to read a file (1).
    #[test]
    fn a_missing_journal_is_a_damaged_checkpoint() {
        let (dir, mut solver) = checkpointed();
        let at = dir.path().join("f.jsonl.checkpoint");
        std::fs::remove_file(at.join("frames")).unwrap();
        let e = Checkpoints::resume(&at, None, solver.as_mut())
            .map(|c| c.map(|c| c.resumed_frames()))
            .unwrap_err();
        assert!(e.is_bad_input(), "{e}");
        assert!(e.to_string().contains("missing"), "{e}");
    }
}
