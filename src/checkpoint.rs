//! Checkpoints: runs that survive a SIGKILL (`softbody run --checkpoint-every N`, `--resume`).
//!
//! A run that checkpoints keeps a directory beside its destination, `<destination>.checkpoint`
//! ([`Checkpoints::dir_for`]), holding two files:
//!
//! - `frames`, the journal: every frame written so far, as raw little-endian numbers (frame
//!   number, step, time, the three energies, then each particle's position and velocity) and
//!   the CRC-32 of those bytes, one fixed-size record per frame, appended as the run goes;
//! - `checkpoint`: the format's version (`SBCKPT02`), how many of the journal's frames are
//!   safely on disk, the solver's [`History`] after the last of them, and a fingerprint of what
//!   is being run (the model, the initial state and the backend), ending in the CRC-32 of the
//!   bytes before it.
//!
//! Every N frames the journal is flushed and synced, and then `checkpoint` is replaced by a
//! rename (through `checkpoint.new`), so that after a kill at any instant the directory holds a
//! checkpoint and at least the frames it counts. A resumed run checks the fingerprint, streams
//! the counted frames from the journal to its output a record at a time (`Replay`: the output
//! is made from scratch, whatever its format, in the memory of one frame), restores the solver
//! to the last of them ([`Solver::restore`]) and goes on: its frames are those of an
//! uninterrupted run, byte for byte (same scene, backend, thread count and format).
//!
//! A checkpoint is refused, and left as it was, when it is of another run
//! ([`CheckpointError::Mismatch`]), of another version of the format
//! ([`CheckpointError::Corrupt`]), or damaged: a checksum that does not match, a journal
//! shorter than its count ([`CheckpointError::Damaged`]). The journal's frames beyond the count
//! are cut off only once the resumed run appends its first frame.
//!
//! The directory is removed when the run ends, unless a signal stopped it (then it can be
//! resumed), and only file by file: a directory of that name holding anything but a
//! checkpoint's own files is not one, and is refused ([`CheckpointError::Foreign`]) rather than
//! replaced.
//!
//! The journal holds 52 + 48·N bytes per frame for N particles, beside the output itself.

use std::fmt::Write as _;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use glam::DVec3;
use softbody_scene::{Energies, History, Solver, State, StepError};

use crate::fingerprint::Fingerprint;
use crate::output::Frame;

/// The first bytes of a `checkpoint` file: [`PREFIX`] and the format's version, two digits.
const MAGIC: &[u8; 8] = b"SBCKPT02";
const PREFIX: &[u8; 6] = b"SBCKPT";
const VERSION: u32 = 2;
/// The checkpoint's name in its directory.
const FILE: &str = "checkpoint";
/// The journal's name in its directory.
const JOURNAL: &str = "frames";
/// The next checkpoint, before it is renamed over the last.
const STAGED: &str = "checkpoint.new";
/// Bytes of the CRC-32 that ends each journal record and the `checkpoint` file.
const CHECKSUM: usize = 4;

/// Why checkpoints cannot be written or resumed.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The checkpoint belongs to another run: the scene, an override, the control forces or the
    /// backend changed.
    #[error(
        "{}: the checkpoint is of another run (the scene, its overrides, its control forces or \
         the backend changed since it was written); run without --resume to start again, or \
         remove it",
        .0.display()
    )]
    Mismatch(PathBuf),
    /// A checkpoint file that this version cannot read.
    #[error("{}: not a checkpoint of this version of softbody ({})", .0.display(), .1)]
    Corrupt(PathBuf, String),
    /// A checkpoint file whose bytes are not those written: a checksum that does not match, a
    /// file cut short or missing.
    #[error(
        "{}: the checkpoint is damaged ({}); run without --resume to start again, or remove it",
        .0.display(), .1
    )]
    Damaged(PathBuf, String),
    /// The checkpoint's directory exists and is not one: it holds other files, or it is not a
    /// directory.
    #[error(
        "refusing to use {} as a checkpoint: {why}; choose another --out or remove it",
        dir.display()
    )]
    Foreign {
        /// The directory.
        dir: PathBuf,
        /// What it is, or holds.
        why: String,
    },
    /// Reading or writing failed.
    #[error("{what}: {cause}")]
    Io {
        /// What was being done, naming the path.
        what: String,
        /// Why (in the message already, so not a `source`: error chains would repeat it).
        cause: io::Error,
    },
    /// The solver could not give or take its history.
    #[error("{0}")]
    Solver(#[from] StepError),
}

impl CheckpointError {
    /// Whether resuming was refused because of what is there (another run's checkpoint, one of
    /// another version, a damaged one), rather than a failing file system: the checkpoint is
    /// left as it was, and it is not one to go on from.
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            CheckpointError::Mismatch(_)
                | CheckpointError::Corrupt(..)
                | CheckpointError::Damaged(..)
        )
    }
}

fn io_context<T>(
    result: io::Result<T>,
    what: impl FnOnce() -> String,
) -> Result<T, CheckpointError> {
    result.map_err(|cause| CheckpointError::Io {
        what: what(),
        cause,
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
    /// A resumed journal not yet cut to the frames its checkpoint counts.
    uncut: bool,
    history: History,
    /// The record being written, kept between frames.
    bytes: Vec<u8>,
}

/// A frame read back from the journal.
#[derive(Debug, Default)]
pub(crate) struct JournalFrame {
    pub index: u64,
    pub step: u64,
    pub time: f64,
    pub energies: Energies,
    pub state: State,
}

/// The frames a resumed run takes from its journal, read one record at a time.
pub(crate) struct Replay {
    reader: BufReader<File>,
    path: PathBuf,
    record: Vec<u8>,
    /// Frames read so far.
    read: u64,
    /// Frames the checkpoint counts.
    frames: u64,
}

impl Replay {
    /// Reads the next counted frame into `frame`, reusing its vectors; false after the last.
    /// A frame whose checksum does not match is refused as damaged.
    pub(crate) fn next(&mut self, frame: &mut JournalFrame) -> Result<bool, CheckpointError> {
        if self.read == self.frames {
            return Ok(false);
        }
        let k = self.read;
        match self.reader.read_exact(&mut self.record) {
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => {
                return Err(CheckpointError::Damaged(
                    self.path.clone(),
                    format!("it ends in frame {k}, before the frames the checkpoint counts"),
                ));
            }
            read => io_context(read, || format!("cannot read {}", self.path.display()))?,
        }
        let (data, sum) = self.record.split_at(self.record.len() - CHECKSUM);
        if crc32fast::hash(data).to_le_bytes() != sum {
            return Err(CheckpointError::Damaged(
                self.path.clone(),
                format!("frame {k} does not match its checksum"),
            ));
        }
        let word = |k: usize| u64::from_le_bytes(data[8 * k..8 * k + 8].try_into().expect("8"));
        let float = |k: usize| f64::from_bits(word(k));
        let n = (data.len() - 48) / 48;
        let vectors = |into: &mut Vec<DVec3>, first: usize| {
            into.clear();
            into.extend((0..n).map(|i| {
                let at = first + 3 * i;
                DVec3::new(float(at), float(at + 1), float(at + 2))
            }));
        };
        frame.index = word(0);
        frame.step = word(1);
        frame.time = float(2);
        frame.energies = Energies {
            kinetic: float(3),
            gravitational: float(4),
            elastic: float(5),
        };
        vectors(&mut frame.state.x, 6);
        vectors(&mut frame.state.v, 6 + 3 * n);
        self.read += 1;
        Ok(true)
    }
}

impl Checkpoints {
    /// The checkpoint directory of an output to `destination`: `<destination>.checkpoint`.
    pub fn dir_for(destination: &Path) -> PathBuf {
        let mut name = destination.as_os_str().to_owned();
        name.push(".checkpoint");
        PathBuf::from(name)
    }

    /// Starts checkpointing a run of `solver` (at its first step) every `every` frames into
    /// `dir`, replacing a checkpoint already there; a directory there that is not a checkpoint
    /// is refused ([`CheckpointError::Foreign`]).
    pub fn create(
        dir: &Path,
        every: u64,
        solver: &mut dyn Solver,
    ) -> Result<Checkpoints, CheckpointError> {
        let fingerprint = fingerprint(solver)?;
        remove_files(dir, true)?;
        io_context(fs::create_dir_all(dir), || {
            format!("cannot create the checkpoint {}", dir.display())
        })?;
        let path = dir.join(JOURNAL);
        let journal = io_context(File::create(&path), || {
            format!("cannot create {}", path.display())
        })?;
        let checkpoints = Checkpoints {
            dir: dir.to_owned(),
            every: every.max(1),
            fingerprint,
            journal: BufWriter::new(journal),
            journaled: 0,
            record: record_bytes(solver.model().len()),
            resumed: 0,
            uncut: false,
            history: History::default(),
            bytes: Vec::new(),
        };
        // A checkpoint of no frames: a kill before the first one resumes from the start.
        checkpoints.write_checkpoint(0)?;
        Ok(checkpoints)
    }

    /// Resumes the run of `solver` (freshly opened, at its first step) checkpointed in `dir`:
    /// `None` when there is no checkpoint there. Checkpoints go on every `every` frames, or as
    /// often as before when `None`. Nothing in `dir` changes until the run appends a frame.
    pub fn resume(
        dir: &Path,
        every: Option<u64>,
        solver: &mut dyn Solver,
    ) -> Result<Option<Checkpoints>, CheckpointError> {
        let path = dir.join(FILE);
        let bytes = match fs::read(&path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            read => io_context(read, || format!("cannot read {}", path.display()))?,
        };
        let saved = Saved::parse(&path, &bytes)?;
        if saved.fingerprint != fingerprint(solver)? {
            return Err(CheckpointError::Mismatch(dir.to_owned()));
        }
        let record = record_bytes(solver.model().len());
        let frames_path = dir.join(JOURNAL);
        // A checkpoint without its journal is damaged, not a failing disk.
        let journal = match OpenOptions::new().read(true).write(true).open(&frames_path) {
            Err(e) if e.kind() == io::ErrorKind::NotFound => {
                return Err(CheckpointError::Damaged(
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
            return Err(CheckpointError::Damaged(
                frames_path,
                format!(
                    "it holds {len} bytes, fewer than the {} frames the checkpoint counts",
                    saved.frames
                ),
            ));
        }
        Ok(Some(Checkpoints {
            dir: dir.to_owned(),
            every: every.unwrap_or(saved.every).max(1),
            fingerprint: saved.fingerprint,
            journal: BufWriter::new(journal),
            journaled: saved.frames,
            record,
            resumed: saved.frames,
            uncut: true,
            history: saved.history,
            bytes: Vec::new(),
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

    /// Removes the checkpoint (the run is over): its own files, and the directory unless
    /// something else was put in it meanwhile.
    pub fn remove(self) -> Result<(), CheckpointError> {
        drop(self.journal);
        remove_files(&self.dir, false)?;
        match fs::remove_dir(&self.dir) {
            Err(e) if e.kind() == io::ErrorKind::DirectoryNotEmpty => Ok(()),
            removed => io_context(removed, || {
                format!("cannot remove the checkpoint {}", self.dir.display())
            }),
        }
    }

    /// The frames to replay, and the solver's history after the last of them (taken: the
    /// next checkpoint has the solver's own).
    pub(crate) fn replay(&mut self) -> Result<(Replay, History), CheckpointError> {
        let path = self.dir.join(JOURNAL);
        let file = io_context(File::open(&path), || {
            format!("cannot read {}", path.display())
        })?;
        let replay = Replay {
            reader: BufReader::new(file),
            path,
            record: vec![0; self.record as usize],
            read: 0,
            frames: self.resumed,
        };
        Ok((replay, std::mem::take(&mut self.history)))
    }

    /// Appends `frame` to the journal, and checkpoints `solver` (which is at that frame) every
    /// `every` frames.
    pub(crate) fn frame(
        &mut self,
        frame: &Frame<'_>,
        solver: &mut dyn Solver,
    ) -> Result<(), CheckpointError> {
        let path = self.dir.join(JOURNAL);
        let cannot = || format!("cannot write {}", path.display());
        if self.uncut {
            // Frames journaled after the checkpoint are computed again.
            let counted = self.journaled * self.record;
            let file = self.journal.get_mut();
            io_context(
                file.set_len(counted)
                    .and_then(|()| file.seek(SeekFrom::Start(counted)).map(drop)),
                cannot,
            )?;
            self.uncut = false;
        }
        let record = &mut self.bytes;
        record.clear();
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
        record.extend(crc32fast::hash(record).to_le_bytes());
        io_context(self.journal.write_all(record), cannot)?;
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
        bytes.extend(crc32fast::hash(&bytes).to_le_bytes());
        let staged = self.dir.join(STAGED);
        io_context(
            File::create(&staged)
                .and_then(|mut f| f.write_all(&bytes).and_then(|()| f.sync_all()))
                .and_then(|()| fs::rename(&staged, &path))
                .and_then(|()| File::open(&self.dir).and_then(|d| d.sync_all())),
            || format!("cannot write {}", path.display()),
        )
    }
}

/// Removes a checkpoint's own files from `dir`, if it exists. With `refuse_others`, a `dir`
/// that holds anything else, or is not a directory, is refused first, and nothing is removed.
fn remove_files(dir: &Path, refuse_others: bool) -> Result<(), CheckpointError> {
    let cannot = || format!("cannot read {}", dir.display());
    let meta = match fs::symlink_metadata(dir) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        read => io_context(read, cannot)?,
    };
    let foreign = |why: String| CheckpointError::Foreign {
        dir: dir.to_owned(),
        why,
    };
    if !meta.is_dir() {
        return Err(foreign("it is not a directory".into()));
    }
    let mut own = Vec::new();
    for entry in io_context(fs::read_dir(dir), cannot)? {
        let entry = io_context(entry, cannot)?;
        let name = entry.file_name();
        let is_own = [FILE, JOURNAL, STAGED].iter().any(|f| name == *f)
            && entry.file_type().is_ok_and(|t| t.is_file());
        if is_own {
            own.push(entry.path());
        } else if refuse_others {
            return Err(foreign(format!(
                "it holds {}, which is not one of a checkpoint's files",
                entry.path().display()
            )));
        }
    }
    for path in own {
        io_context(fs::remove_file(&path), || {
            format!("cannot remove {}", path.display())
        })?;
    }
    Ok(())
}

/// Bytes of a journal record for `n` particles.
fn record_bytes(n: usize) -> u64 {
    48 + 48 * n as u64 + CHECKSUM as u64
}

/// What a `checkpoint` file says.
struct Saved {
    fingerprint: u64,
    every: u64,
    frames: u64,
    history: History,
}

impl Saved {
    /// The checkpoint file `path`, whose bytes are `bytes`.
    fn parse(path: &Path, bytes: &[u8]) -> Result<Saved, CheckpointError> {
        let corrupt = |why: String| CheckpointError::Corrupt(path.to_owned(), why);
        let damaged = |why: &str| CheckpointError::Damaged(path.to_owned(), why.to_owned());
        let Some(version) = bytes.strip_prefix(PREFIX.as_slice()) else {
            return Err(corrupt("it does not start as one".into()));
        };
        let version = version.get(..2).and_then(|v| std::str::from_utf8(v).ok());
        if version != std::str::from_utf8(&MAGIC[PREFIX.len()..]).ok() {
            return Err(corrupt(match version.and_then(|v| v.parse::<u32>().ok()) {
                Some(v) => {
                    format!(
                        "it is of version {v} of the format, and this version reads version {VERSION}"
                    )
                }
                None => "it does not start as one".into(),
            }));
        }
        let Some((body, sum)) = bytes
            .split_at_checked(bytes.len().saturating_sub(CHECKSUM))
            .filter(|(body, _)| body.len() >= MAGIC.len())
        else {
            return Err(damaged("it is cut short"));
        };
        if crc32fast::hash(body).to_le_bytes() != sum {
            return Err(damaged("it does not match its checksum"));
        }
        // Past the checksum, what does not parse was written by another layout.
        let mut cursor = Cursor(&body[MAGIC.len()..]);
        let read = |cursor: &mut Cursor<'_>| -> Result<Saved, String> {
            let (fingerprint, every, frames, parts) = (
                cursor.word()?,
                cursor.word()?,
                cursor.word()?,
                cursor.word()?,
            );
            let mut history = History::default();
            for _ in 0..parts {
                let len = cursor.word()?;
                let name = std::str::from_utf8(cursor.take(len)?)
                    .map_err(|_| "a part's name is not UTF-8")?;
                let len = cursor.word()?;
                history.push(name, cursor.take(len)?.to_vec());
            }
            Ok(Saved {
                fingerprint,
                every,
                frames,
                history,
            })
        };
        read(&mut cursor).map_err(corrupt)
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

/// The fingerprint of what `solver` runs: its backend, its model, its control forces and its
/// current (initial) state.
fn fingerprint(solver: &mut dyn Solver) -> Result<u64, StepError> {
    let mut hash = Fingerprint::default();
    let backend = solver.backend();
    let _ = write!(hash, "{backend} {:?}", solver.model());
    // A run without controls hashes as it did before they existed: its checkpoints stay valid.
    if let Some(controls) = solver.controls() {
        let _ = write!(hash, "{:?}", controls.forces());
    }
    let _ = write!(hash, "{:?}", solver.state()?);
    Ok(hash.finish())
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

    /// `bytes` of a checkpoint file edited in place, with their checksum made to match again.
    fn reseal(bytes: &mut [u8]) {
        let end = bytes.len() - CHECKSUM;
        let sum = crc32fast::hash(&bytes[..end]);
        bytes[end..].copy_from_slice(&sum.to_le_bytes());
    }

    /// A frame count damaged so that frames × record wraps around u64 is refused as damaged,
    /// and the journal is left as it was (not cut to the wrapped length).
    #[test]
    fn a_damaged_frame_count_is_refused_without_touching_the_journal() {
        let (dir, mut solver) = checkpointed();
        let at = dir.path().join("f.jsonl.checkpoint");
        let journal = at.join(JOURNAL);
        let record = record_bytes(solver.model().len());
        // The smallest count whose product with the record wraps, and a journal that long:
        // the unchecked size check passed it and cut the journal to that length.
        let wrapping = u64::MAX / record + 1;
        let wrapped = wrapping.wrapping_mul(record) as usize;
        std::fs::write(&journal, vec![0u8; wrapped + 4096]).unwrap();
        let mut saved = std::fs::read(at.join(FILE)).unwrap();
        let count = MAGIC.len() + 16;
        saved[count..count + 8].copy_from_slice(&wrapping.to_le_bytes());
        reseal(&mut saved);
        std::fs::write(at.join(FILE), &saved).unwrap();
        let refused = Checkpoints::resume(&at, None, solver.as_mut());
        let Err(CheckpointError::Damaged(path, why)) = refused else {
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
        std::fs::remove_file(at.join(JOURNAL)).unwrap();
        let e = Checkpoints::resume(&at, None, solver.as_mut())
            .map(|c| c.map(|c| c.resumed_frames()))
            .unwrap_err();
        assert!(e.is_bad_input(), "{e}");
        assert_eq!(
            e.to_string(),
            format!(
                "{}: the checkpoint is damaged (the journal of its frames is missing); run \
                 without --resume to start again, or remove it",
                at.join(JOURNAL).display()
            )
        );
    }
}
