//! Where a run's output goes, and how it gets there whole.
//!
//! Nothing is written under the final name until the run ends: a single-file format streams
//! into a temporary file beside the destination, a series (VTK, PLY, OBJ) into a temporary
//! directory beside it, and [`Output::commit`] renames them into place. A run that fails
//! before then (an unwritable disk, a solver that cannot start) drops the [`Output`], which
//! removes what was staged. A run stopped by an instability is committed like a completed
//! one: every frame written before it is complete.
//!
//! An existing destination is replaced: a regular file by a rename over it (keeping its
//! permissions; a symbolic link is followed, and a device or a FIFO is written in place, see
//! [`Staged::file`]); a directory of frames by
//! moving it aside, renaming the new one in and then deleting the old one. A directory is only
//! replaced when it holds nothing but frames of the same series (`<stem>_<digits>.<ext>` of
//! the format being written): `--out ~` must not delete a home directory, and a PLY run must
//! not delete the `.vtu` files a `.pvd` names (the series formats share a default directory).
//!
//! [`Staged`] is the mechanism underneath, for other outputs too (`softbody render`'s pictures):
//! a file, or a directory of numbered files that is merged into an existing directory rather
//! than replacing it.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use tempfile::{NamedTempFile, TempDir};

use super::{Format, FrameSink};

/// Why an output cannot be created or completed.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// A multi-file format was asked to write to standard output.
    #[error(
        "--format {0} writes a series of files, one per frame, and cannot go to standard \
         output; name {what} with --out",
        what = if *.0 == Format::Vtk { "the .pvd file" } else { "a directory" }
    )]
    Stdout(Format),
    /// The destination cannot be used as a name for a series (no final component, not UTF-8).
    #[error("{}: {}", .0.display(), .1)]
    BadName(PathBuf, &'static str),
    /// The destination is not a directory of frames of the series being written: it holds
    /// the second path (or is itself not a directory).
    #[error(
        "refusing to replace {}: it holds {}, which is not a {} frame of this series; \
         choose another --out or remove it",
        .0.display(), .1.display(), .2
    )]
    Foreign(PathBuf, PathBuf, Format),
    /// `--out`'s extension names no format, or another format than `--format`.
    #[error("{}: {problem}", path.display())]
    Extension {
        /// The output path.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// Reading or writing failed.
    #[error("{what}")]
    Io {
        /// What was being done, naming the path.
        what: String,
        /// The failure.
        source: io::Error,
    },
}

impl OutputError {
    /// Whether the request itself is wrong (the command line), rather than the file system.
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            OutputError::Stdout(_) | OutputError::BadName(..) | OutputError::Extension { .. }
        )
    }
}

/// `result` with a failure described by `what`.
fn io_context<T>(result: io::Result<T>, what: impl FnOnce() -> String) -> Result<T, OutputError> {
    result.map_err(|source| OutputError::Io {
        what: what(),
        source,
    })
}

/// An output being written: the sink a run writes frames into, and the temporary files or
/// directory it writes them to.
pub struct Output {
    sink: Box<dyn FrameSink>,
    /// Committed in order: a series' frames before the collection file that lists them. Empty
    /// for standard output.
    staged: Vec<Staged>,
}

impl Output {
    /// An output of `format` to `path`, or to standard output when `path` is `None`.
    ///
    /// `path` names the file for JSON Lines, CSV and NPZ, the `.pvd` file for VTK (the frames
    /// go to the directory of the same name without the extension beside it), and the
    /// directory for PLY and OBJ (a name ending in `.ply` or `.obj` names the directory without
    /// it, as for VTK). Checks up front what it can (a series to standard output, a
    /// directory that is not ours, a directory where the file should go), so that a run is not
    /// computed for nothing.
    pub fn create(format: Format, path: Option<&Path>) -> Result<Output, OutputError> {
        let Some(path) = path else {
            if format.is_series() {
                return Err(OutputError::Stdout(format));
            }
            return Ok(Output {
                sink: super::sink(format, Box::new(io::stdout().lock()))?,
                staged: Vec::new(),
            });
        };
        if !format.is_series() {
            let (staged, file) = Staged::file(path)?;
            let out = Box::new(super::Named::new(file, path));
            let sink = match format {
                // Beside the destination, on the file system the archive needs room on; a
                // device or a FIFO written in place has no such room (`/dev`): as a stream.
                Format::Npz if !matches!(staged.temp, Temp::Direct) => {
                    Box::new(super::NpzSink::staged_in(parent_of(staged.path()), out)?)
                }
                _ => super::sink(format, out)?,
            };
            return Ok(Output {
                sink,
                staged: vec![staged],
            });
        }
        let (dir, stem) = series_names(format, path)?;
        let frames = Staged::dir(&dir, &stem, Existing::Series(format))?;
        let frames_path = frames.path().to_owned();
        let (sink, staged): (Box<dyn FrameSink>, _) = match format {
            Format::Vtk => {
                let (index, file) = Staged::file(path)?;
                // The .pvd names the frames relative to itself: `<dir name>/<file>`.
                let sink = super::VtkSink::new(
                    frames_path,
                    stem.clone(),
                    format!("{stem}/"),
                    Box::new(super::Named::new(file, path)),
                );
                (Box::new(sink), vec![frames, index])
            }
            Format::Ply => (
                Box::new(super::PlySink::new(frames_path, stem)),
                vec![frames],
            ),
            // OBJ: the single-file formats returned above.
            _ => (
                Box::new(super::ObjSink::new(frames_path, stem)),
                vec![frames],
            ),
        };
        Ok(Output { sink, staged })
    }

    /// The sink the run writes into.
    pub fn sink(&mut self) -> &mut dyn FrameSink {
        self.sink.as_mut()
    }

    /// Completes the output (the sink's [`finish`](FrameSink::finish)) and renames it into
    /// place. Call it after the run, also after an instability; drop the output instead to
    /// discard it.
    pub fn commit(mut self) -> Result<(), OutputError> {
        io_context(self.sink.finish(), || "cannot write frames".to_owned())?;
        // Close every file the sink holds before renaming (Windows will not rename open files).
        drop(self.sink);
        self.staged.into_iter().try_for_each(Staged::commit)
    }
}

/// A file or a directory being written beside its destination: [`Staged::commit`] puts it in
/// place, and dropping it first removes it. Hidden (`.softbody-*.part`) until then, and made
/// with the permissions of an ordinary file or directory, since it is renamed as it is.
pub struct Staged {
    temp: Temp,
    destination: PathBuf,
}

enum Temp {
    File(NamedTempFile),
    /// Written in place: a character device or a FIFO, which a rename would replace.
    Direct,
    Dir {
        files: TempDir,
        stem: String,
        existing: Existing,
    },
}

/// What committing a directory does with one already at its destination.
enum Existing {
    /// A series' directory is its own: replaced whole, but only when it holds nothing but frame
    /// files of the same series.
    Series(Format),
    /// A directory of numbered files with this extension is the user's: the staged files are
    /// moved into it, its other files stay, and the numbered files of an earlier, longer set
    /// go.
    Merge(String),
}

impl Staged {
    /// A file to be renamed over `path`, and the handle to write it through. Makes the missing
    /// directories above `path`.
    ///
    /// What is already at `path` decides how: a symbolic link is followed (the file it names
    /// is written, the link stays); a regular file is replaced at commit and the new one takes
    /// its permissions (without set-id bits) and, where the process may, its owner; a character
    /// device or a FIFO (`/dev/null`, `/dev/stdout`, a named pipe) is written directly, as a
    /// shell redirection would (opening a FIFO waits for its reader); a directory or anything
    /// else (a block device, a socket) is refused, since the rename at the end would replace it.
    pub fn file(path: &Path) -> Result<(Staged, fs::File), OutputError> {
        let path = &follow_links(path)?;
        let parent = create_parent(path)?;
        let existing = match fs::metadata(path) {
            Err(e) if e.kind() == io::ErrorKind::NotFound => None,
            other => Some(io_context(other, || {
                format!("cannot read {}", path.display())
            })?),
        };
        if let Some(meta) = existing.filter(|m| !m.is_file()) {
            if is_stream(&meta) {
                let file = io_context(fs::OpenOptions::new().write(true).open(path), || {
                    format!("cannot write {}", path.display())
                })?;
                let staged = Staged {
                    temp: Temp::Direct,
                    destination: path.to_owned(),
                };
                return Ok((staged, file));
            }
            return Err(not_a_file(path, &meta));
        }
        let temp = temp_file(path)?;
        let file = io_context(temp.reopen(), || {
            format!("cannot write in {}", parent.display())
        })?;
        let staged = Staged {
            temp: Temp::File(temp),
            destination: path.to_owned(),
        };
        Ok((staged, file))
    }

    /// A directory of numbered files `<stem>_<digits>.<extension>` to be put at `dir`, written
    /// into [`Staged::path`]. When `dir` exists, the new files are moved into it: its other
    /// files stay, and its numbered files of that stem and extension that were not written
    /// this time (those of an earlier, longer set) are removed. Refuses a `dir` that is not a
    /// directory.
    pub fn numbered_files(dir: &Path, stem: &str, extension: &str) -> Result<Staged, OutputError> {
        Staged::dir(dir, stem, Existing::Merge(extension.to_owned()))
    }

    fn dir(dir: &Path, stem: &str, existing: Existing) -> Result<Staged, OutputError> {
        create_parent(dir)?;
        match &existing {
            Existing::Series(format) => check_replaceable(dir, stem, *format)?,
            Existing::Merge(_) if dir.exists() && !dir.is_dir() => {
                return Err(OutputError::Io {
                    what: format!("cannot write into {}", dir.display()),
                    source: io::Error::new(io::ErrorKind::NotADirectory, "it is not a directory"),
                });
            }
            Existing::Merge(_) => {}
        }
        let files = temp_dir(dir)?;
        Ok(Staged {
            temp: Temp::Dir {
                files,
                stem: stem.to_owned(),
                existing,
            },
            destination: dir.to_owned(),
        })
    }

    /// Where to write now: the temporary file, or the temporary directory.
    pub fn path(&self) -> &Path {
        match &self.temp {
            Temp::File(file) => file.path(),
            Temp::Direct => &self.destination,
            Temp::Dir { files, .. } => files.path(),
        }
    }

    /// Puts the file or directory in place. Close the handles to it first (Windows will not
    /// rename open files).
    pub fn commit(self) -> Result<(), OutputError> {
        let path = self.destination;
        match self.temp {
            Temp::File(temp) => {
                // Checked again: the destination may have changed during the run.
                match fs::symlink_metadata(&path) {
                    Ok(meta) if meta.is_file() => keep_mode_and_owner(temp.as_file(), &meta),
                    Ok(meta) => return Err(not_a_file(&path, &meta)),
                    Err(_) => {}
                }
                temp.persist(&path).map(drop).map_err(|e| OutputError::Io {
                    what: format!("cannot write {}", path.display()),
                    source: e.error,
                })
            }
            Temp::Direct => Ok(()),
            Temp::Dir {
                files,
                stem,
                existing,
            } => place_dir(files, &path, &stem, &existing),
        }
    }
}

/// The path a chain of symbolic links at `path` ends in (`path` itself when it is not a link),
/// which may not exist yet. Only the last component is resolved: the directories above are the
/// operating system's to follow.
fn follow_links(path: &Path) -> Result<PathBuf, OutputError> {
    // As Linux's ELOOP limit.
    const MAX_LINKS: usize = 40;
    let mut at = path.to_owned();
    for _ in 0..MAX_LINKS {
        match fs::symlink_metadata(&at) {
            Ok(meta) if meta.file_type().is_symlink() => {
                let target = io_context(fs::read_link(&at), || {
                    format!("cannot read the link {}", at.display())
                })?;
                // A relative target is relative to the link's directory.
                at = parent_of(&at).join(target);
            }
            _ => return Ok(at),
        }
    }
    Err(OutputError::Io {
        what: format!("cannot write {}", path.display()),
        source: io::Error::other(format!("more than {MAX_LINKS} symbolic links")),
    })
}

/// Whether `meta` is a file written as a stream rather than replaced: a character device or a
/// FIFO.
fn is_stream(meta: &fs::Metadata) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let kind = meta.file_type();
        kind.is_char_device() || kind.is_fifo()
    }
    #[cfg(not(unix))]
    {
        let _ = meta;
        false
    }
}

/// The refusal to replace `path`, which `meta` says is not a regular file.
fn not_a_file(path: &Path, meta: &fs::Metadata) -> OutputError {
    let (kind, what) = if meta.is_dir() {
        (io::ErrorKind::IsADirectory, "it is a directory")
    } else {
        (
            io::ErrorKind::InvalidInput,
            "it is not a regular file (a block device or a socket), which would be replaced",
        )
    };
    OutputError::Io {
        what: format!("cannot write {}", path.display()),
        source: io::Error::new(kind, what),
    }
}

/// Gives the staged `file` the permissions (less the set-id and sticky bits) and, where the
/// process may, the owner of the regular file `meta` it replaces. Best effort: a file the
/// process may not chown becomes its own, as any rename-into-place leaves it.
fn keep_mode_and_owner(file: &fs::File, meta: &fs::Metadata) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let _ = std::os::unix::fs::fchown(file, Some(meta.uid()), Some(meta.gid()));
        // After the chown, which clears set-id bits, and of the mode alone.
        let _ = file.set_permissions(fs::Permissions::from_mode(meta.mode() & 0o777));
    }
    #[cfg(not(unix))]
    let _ = file.set_permissions(meta.permissions());
}

/// The directory `path` is in (`.` for a bare name).
fn parent_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// The directory `path` is in, made if missing.
fn create_parent(path: &Path) -> Result<&Path, OutputError> {
    let parent = parent_of(path);
    io_context(fs::create_dir_all(parent), || {
        format!("cannot create {}", parent.display())
    })?;
    Ok(parent)
}

/// The frames directory of a series written to `path`, and the stem of its file names.
fn series_names(format: Format, path: &Path) -> Result<(PathBuf, String), OutputError> {
    // `run.pvd` names the directory `run` beside it, and so do `run.ply` and `run.obj`: the
    // frames of all three are `run/run_<digits>.<ext>`.
    let name = if Format::from_path(path) == Some(format) {
        path.file_stem()
    } else {
        path.file_name()
    };
    let Some(name) = name else {
        return Err(OutputError::BadName(
            path.to_owned(),
            "--out must end in a file or directory name",
        ));
    };
    // The stem goes into file names and, for VTK, into the .pvd's XML as text.
    let Some(stem) = name.to_str() else {
        return Err(OutputError::BadName(
            path.to_owned(),
            "the output name must be valid UTF-8",
        ));
    };
    // Without an extension the .pvd and the frames directory would have the same name.
    if format == Format::Vtk && path.extension().is_none() {
        return Err(OutputError::BadName(
            path.to_owned(),
            "--out must name the .pvd file, e.g. out/frames.pvd",
        ));
    }
    let dir = parent_of(path).join(stem);
    Ok((dir, stem.to_owned()))
}

/// The extension of `format`'s frame files.
fn frame_extension(format: Format) -> &'static str {
    match format {
        Format::Vtk => "vtu",
        other => other.extension(),
    }
}

/// Whether `name` is a frame file of the series `stem` in `format`: `<stem>_<digits>.<ext>`.
fn is_frame_file(name: &str, stem: &str, format: Format) -> bool {
    is_numbered(name, stem, frame_extension(format))
}

/// Whether `name` is `<stem>_<digits>.<extension>`.
fn is_numbered(name: &str, stem: &str, extension: &str) -> bool {
    let Some(digits) = name
        .strip_prefix(stem)
        .and_then(|n| n.strip_prefix('_'))
        .and_then(|n| n.strip_suffix(extension))
        .and_then(|n| n.strip_suffix('.'))
    else {
        return false;
    };
    !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
}

/// Fails unless `dir` is absent, or a directory holding only frame files of the series
/// `stem` in `format`.
fn check_replaceable(dir: &Path, stem: &str, format: Format) -> Result<(), OutputError> {
    let meta = match fs::symlink_metadata(dir) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        other => io_context(other, || format!("cannot read {}", dir.display()))?,
    };
    if !meta.is_dir() {
        return Err(OutputError::Foreign(dir.to_owned(), dir.to_owned(), format));
    }
    for entry in read_dir(dir)? {
        let ours = entry.file_type().is_ok_and(|t| t.is_file())
            && entry
                .file_name()
                .to_str()
                .is_some_and(|n| is_frame_file(n, stem, format));
        if !ours {
            return Err(OutputError::Foreign(dir.to_owned(), entry.path(), format));
        }
    }
    Ok(())
}

/// The entries of `dir`.
fn read_dir(dir: &Path) -> Result<Vec<fs::DirEntry>, OutputError> {
    let cannot = || format!("cannot read {}", dir.display());
    io_context(fs::read_dir(dir), cannot)?
        .map(|entry| io_context(entry, cannot))
        .collect()
}

/// The staged names of files bound for `destination`: `.softbody-<pid>-<random>-<tag>.part`,
/// hidden, with the process that writes them and a tag of the destination's file name
/// ([`destination_tag`]), so that a later run can tell its own destination's leftovers from a
/// killed process ([`remove_stale`]) from another run's work in progress. Made with ordinary
/// permissions (0666 / 0777 less the umask) rather than a temporary file's 0600, since they are
/// renamed into place as they are.
fn staged<T>(
    destination: &Path,
    mode: u32,
    make: impl FnOnce(&tempfile::Builder<'_, '_>, &Path) -> io::Result<T>,
) -> Result<T, OutputError> {
    let dir = parent_of(destination);
    remove_stale(dir, destination);
    let prefix = format!("{STAGED_PREFIX}{}-", std::process::id());
    let suffix = format!("-{}{STAGED_SUFFIX}", destination_tag(destination));
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(&suffix);
    #[cfg(unix)]
    builder.permissions(<fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(mode));
    #[cfg(not(unix))]
    let _ = mode;
    io_context(make(&builder, dir), || {
        format!("cannot write in {}", dir.display())
    })
}

const STAGED_PREFIX: &str = ".softbody-";
const STAGED_SUFFIX: &str = ".part";

/// 16 hex digits of the FNV-1a hash of `destination`'s file name: short whatever the name's
/// length, and the same in every build.
fn destination_tag(destination: &Path) -> String {
    use std::hash::Hasher;
    let name = destination.file_name().unwrap_or(destination.as_os_str());
    let mut hash = fnv::FnvHasher::default();
    hash.write(name.as_encoded_bytes());
    format!("{:016x}", hash.finish())
}

/// Removes from `dir` what a process that no longer runs staged for `destination` (killed
/// before it could clean up: SIGKILL, a power cut). Where it cannot tell whether a process runs
/// (no `/proc`), and whatever it cannot remove, it leaves.
fn remove_stale(dir: &Path, destination: &Path) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    let suffix = format!("-{}{STAGED_SUFFIX}", destination_tag(destination));
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name
            .to_str()
            .filter(|n| n.ends_with(&suffix))
            .and_then(|n| n.strip_prefix(STAGED_PREFIX))
            .and_then(|n| n.split('-').next())
            .and_then(|pid| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == std::process::id() || Path::new("/proc").join(pid.to_string()).exists() {
            continue;
        }
        let path = entry.path();
        let _ = match entry.file_type() {
            Ok(t) if t.is_dir() => fs::remove_dir_all(&path),
            _ => fs::remove_file(&path),
        };
    }
}

fn temp_file(destination: &Path) -> Result<NamedTempFile, OutputError> {
    staged(destination, 0o666, |b, dir| b.tempfile_in(dir))
}

fn temp_dir(destination: &Path) -> Result<TempDir, OutputError> {
    staged(destination, 0o777, |b, dir| b.tempdir_in(dir))
}

/// Renames the staged directory `files` to `dir`, or into it (see [`Existing`]).
fn place_dir(
    files: TempDir,
    dir: &Path,
    stem: &str,
    existing: &Existing,
) -> Result<(), OutputError> {
    let cannot = || format!("cannot write {}", dir.display());
    let old = match existing {
        Existing::Merge(extension) if dir.exists() => {
            return merge_dir(&files, dir, stem, extension);
        }
        Existing::Merge(_) => None,
        Existing::Series(format) => {
            // Checked again: the directory may have changed during the run.
            check_replaceable(dir, stem, *format)?;
            // A directory cannot be renamed over a non-empty one: move the old one into a
            // temporary directory (deleted with it) first.
            if dir.exists() {
                let aside = temp_dir(dir)?;
                io_context(fs::rename(dir, aside.path().join("old")), cannot)?;
                Some(aside)
            } else {
                None
            }
        }
    };
    let staged = files.keep();
    if let Err(e) = fs::rename(&staged, dir) {
        // Put things back as they were: the old frames where they were, no staged directory.
        if let Some(aside) = &old {
            let _ = fs::rename(aside.path().join("old"), dir);
        }
        let _ = fs::remove_dir_all(&staged);
        return Err(OutputError::Io {
            what: cannot(),
            source: e,
        });
    }
    if let Some(aside) = old {
        io_context(aside.close(), || {
            format!("cannot remove the previous frames of {}", dir.display())
        })?;
    }
    Ok(())
}

/// Moves the files of `files` into the existing directory `dir`, then removes the numbered
/// files there that were not among them.
fn merge_dir(files: &TempDir, dir: &Path, stem: &str, extension: &str) -> Result<(), OutputError> {
    let mut written = std::collections::HashSet::new();
    for entry in read_dir(files.path())? {
        let name = entry.file_name();
        io_context(fs::rename(entry.path(), dir.join(&name)), || {
            format!("cannot write in {}", dir.display())
        })?;
        written.insert(name);
    }
    for entry in read_dir(dir)? {
        let name = entry.file_name();
        let stale = !written.contains(&name)
            && name
                .to_str()
                .is_some_and(|n| is_numbered(n, stem, extension));
        if stale {
            io_context(fs::remove_file(entry.path()), || {
                format!("cannot remove {}", entry.path().display())
            })?;
        }
    }
    Ok(())
}

impl From<io::Error> for OutputError {
    fn from(source: io::Error) -> Self {
        OutputError::Io {
            what: "cannot write frames".to_owned(),
            source,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_file_names_are_recognised() {
        for (name, format) in [
            ("a_000000.vtu", Format::Vtk),
            ("a_000123.ply", Format::Ply),
            ("a_1234567.obj", Format::Obj),
        ] {
            assert!(is_frame_file(name, "a", format), "{name}");
        }
        for (name, format) in [
            ("a_000000.vtu", Format::Ply),
            ("b_000000.vtu", Format::Vtk),
            ("ab_000000.vtu", Format::Vtk),
            ("a.vtu", Format::Vtk),
            ("a_.ply", Format::Ply),
            ("a_00x1.obj", Format::Obj),
            ("a_000000.obj.bak", Format::Obj),
            ("notes.txt", Format::Obj),
        ] {
            assert!(!is_frame_file(name, "a", format), "{name} {format}");
        }
    }

    #[test]
    fn series_names_follow_the_out_path() {
        let (dir, stem) = series_names(Format::Vtk, Path::new("out/run.pvd")).unwrap();
        assert_eq!((dir, stem.as_str()), (PathBuf::from("out/run"), "run"));
        for format in [Format::Ply, Format::Obj] {
            let path = format!("out/run.{}", format.extension());
            let (dir, stem) = series_names(format, Path::new(&path)).unwrap();
            assert_eq!((dir, stem.as_str()), (PathBuf::from("out/run"), "run"));
        }
        let (dir, stem) = series_names(Format::Ply, Path::new("out/run.v2")).unwrap();
        assert_eq!(
            (dir, stem.as_str()),
            (PathBuf::from("out/run.v2"), "run.v2")
        );
        assert!(series_names(Format::Obj, Path::new("..")).is_err());
        assert!(series_names(Format::Obj, Path::new("/")).is_err());
    }

    #[test]
    fn numbered_files_merge_into_an_existing_directory() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("pictures");
        let write = |staged: &Staged, names: &[&str]| {
            for name in names {
                fs::write(staged.path().join(name), "new").unwrap();
            }
        };
        let names = || {
            let mut names: Vec<String> = fs::read_dir(&dir)
                .unwrap()
                .map(|e| e.unwrap().file_name().into_string().unwrap())
                .collect();
            names.sort();
            names
        };
        // Absent: the staged directory becomes it.
        let staged = Staged::numbered_files(&dir, "frame", "png").unwrap();
        write(
            &staged,
            &["frame_000000.png", "frame_000001.png", "frame_000002.png"],
        );
        staged.commit().unwrap();
        assert_eq!(
            names(),
            ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
        );

        // Present: a shorter set replaces its files, the user's files stay.
        fs::write(dir.join("notes.txt"), "mine").unwrap();
        fs::write(dir.join("frame_000000.jpg"), "mine").unwrap();
        let staged = Staged::numbered_files(&dir, "frame", "png").unwrap();
        write(&staged, &["frame_000000.png"]);
        staged.commit().unwrap();
        assert_eq!(
            names(),
            ["frame_000000.jpg", "frame_000000.png", "notes.txt"]
        );
        assert_eq!(
            fs::read_to_string(dir.join("frame_000000.png")).unwrap(),
            "new"
        );
        assert_eq!(
            fs::read_dir(root.path()).unwrap().count(),
            1,
            "nothing staged is left beside it"
        );

        // A file where the directory should go, and a directory where a file should go.
        let file = root.path().join("file");
        fs::write(&file, "x").unwrap();
        assert!(Staged::numbered_files(&file, "frame", "png").is_err());
        assert!(Staged::file(&dir).is_err());
        // Dropped before commit: nothing changes.
        let staged = Staged::numbered_files(&dir, "frame", "png").unwrap();
        write(&staged, &["frame_000009.png"]);
        drop(staged);
        assert!(!dir.join("frame_000009.png").exists());
    }

    #[test]
    fn a_directory_with_other_files_is_not_replaced() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("frames");
        let check = |dir: &Path, format| check_replaceable(dir, "frames", format);
        assert!(check(&dir, Format::Ply).is_ok(), "absent");
        fs::create_dir(&dir).unwrap();
        assert!(check(&dir, Format::Ply).is_ok(), "empty");
        fs::write(dir.join("frames_000000.ply"), "ply").unwrap();
        assert!(check(&dir, Format::Ply).is_ok(), "frames only");
        assert!(
            matches!(check(&dir, Format::Obj), Err(OutputError::Foreign(..))),
            "frames of another format"
        );
        fs::write(dir.join("thesis.tex"), "precious").unwrap();
        assert!(matches!(
            check(&dir, Format::Ply),
            Err(OutputError::Foreign(_, p, _)) if p.ends_with("thesis.tex")
        ));
        let file = root.path().join("file");
        fs::write(&file, "x").unwrap();
        assert!(matches!(
            check(&file, Format::Ply),
            Err(OutputError::Foreign(..))
        ));
    }
}
