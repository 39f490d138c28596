//! Where a run's output goes, and how it gets there whole.
//!
//! Nothing is written under the final name until the run ends: a single-file format streams
//! into a temporary file beside the destination, a series (VTK, PLY, OBJ) into a temporary
//! directory beside it, and [`Output::commit`] renames them into place. A run that fails
//! before then (an unwritable disk, a solver that cannot start) drops the [`Output`], which
//! removes what was staged. A run stopped by an instability is committed like a completed
//! one: every frame written before it is complete.
//!
//! An existing destination is replaced: a file by a rename over it; a directory of frames by
//! moving it aside, renaming the new one in and then deleting the old one. A directory is only
//! replaced when it holds nothing but frames of the same series (`<stem>_<digits>.<ext>` of
//! the format being written): `--out ~` must not delete a home directory, and a PLY run must
//! not delete the `.vtu` files a `.pvd` names (the series formats share a default directory).

use std::fs;
use std::io::{self, BufWriter};
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
        matches!(self, OutputError::Stdout(_) | OutputError::BadName(..))
    }
}

/// `result` with a failure described by `what`.
fn io_context<T>(result: io::Result<T>, what: impl FnOnce() -> String) -> Result<T, OutputError> {
    result.map_err(|source| OutputError::Io {
        what: what(),
        source,
    })
}

/// What [`Output::commit`] renames into place.
enum Staged {
    Stdout,
    File {
        temp: NamedTempFile,
        path: PathBuf,
    },
    Series {
        /// The frames, to become `dir`.
        frames: TempDir,
        dir: PathBuf,
        stem: String,
        format: Format,
        /// The collection file (VTK's `.pvd`), to become its path.
        index: Option<(NamedTempFile, PathBuf)>,
    },
}

/// An output being written: the sink a run writes frames into, and the temporary file or
/// directory it writes them to.
pub struct Output {
    sink: Box<dyn FrameSink>,
    staged: Staged,
}

impl Output {
    /// An output of `format` to `path`, or to standard output when `path` is `None`.
    ///
    /// `path` names the file for JSON Lines, CSV and NPZ, the `.pvd` file for VTK (the frames
    /// go to the directory of the same name without the extension beside it), and the
    /// directory for PLY and OBJ. Checks up front what it can (a series to standard output, a
    /// directory that is not ours), so that a run is not computed for nothing.
    pub fn create(format: Format, path: Option<&Path>) -> Result<Output, OutputError> {
        let Some(path) = path else {
            if format.is_series() {
                return Err(OutputError::Stdout(format));
            }
            return Ok(Output {
                sink: super::sink(format, Box::new(io::stdout().lock()))?,
                staged: Staged::Stdout,
            });
        };
        let parent = parent_of(path);
        io_context(fs::create_dir_all(parent), || {
            format!("cannot create {}", parent.display())
        })?;
        let (dir, stem) = match format {
            Format::Jsonl | Format::Csv | Format::Npz => {
                let temp = temp_file(parent)?;
                let handle = io_context(temp.reopen(), || {
                    format!("cannot write in {}", parent.display())
                })?;
                return Ok(Output {
                    sink: super::sink(format, Box::new(BufWriter::new(handle)))?,
                    staged: Staged::File {
                        temp,
                        path: path.to_owned(),
                    },
                });
            }
            Format::Vtk | Format::Ply | Format::Obj => series_names(format, path)?,
        };
        check_replaceable(&dir, &stem, format)?;
        if format == Format::Vtk && path.is_dir() {
            return Err(OutputError::Io {
                what: format!("cannot write {}", path.display()),
                source: io::Error::new(io::ErrorKind::IsADirectory, "it is a directory"),
            });
        }
        let frames = temp_dir(parent)?;
        let (sink, index): (Box<dyn FrameSink>, _) = match format {
            Format::Vtk => {
                let temp = temp_file(parent)?;
                let handle = io_context(temp.reopen(), || {
                    format!("cannot write in {}", parent.display())
                })?;
                // The .pvd names the frames relative to itself: `<dir name>/<file>`.
                let sink = super::VtkSink::new(
                    frames.path().to_owned(),
                    stem.clone(),
                    format!("{stem}/"),
                    Box::new(BufWriter::new(handle)),
                );
                (Box::new(sink), Some((temp, path.to_owned())))
            }
            Format::Ply => (
                Box::new(super::PlySink::new(frames.path().to_owned(), stem.clone())),
                None,
            ),
            // OBJ: the single-file formats returned above.
            _ => (
                Box::new(super::ObjSink::new(frames.path().to_owned(), stem.clone())),
                None,
            ),
        };
        Ok(Output {
            sink,
            staged: Staged::Series {
                frames,
                dir,
                stem,
                format,
                index,
            },
        })
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
        match self.staged {
            Staged::Stdout => Ok(()),
            Staged::File { temp, path } => {
                temp.persist(&path).map(drop).map_err(|e| OutputError::Io {
                    what: format!("cannot write {}", path.display()),
                    source: e.error,
                })
            }
            Staged::Series {
                frames,
                dir,
                stem,
                format,
                index,
            } => {
                place_dir(frames, &dir, &stem, format)?;
                if let Some((temp, path)) = index {
                    temp.persist(&path).map_err(|e| OutputError::Io {
                        what: format!("cannot write {}", path.display()),
                        source: e.error,
                    })?;
                }
                Ok(())
            }
        }
    }
}

/// The directory `path` is in (`.` for a bare name).
fn parent_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// The frames directory of a series written to `path`, and the stem of its file names.
fn series_names(format: Format, path: &Path) -> Result<(PathBuf, String), OutputError> {
    let name = if format == Format::Vtk {
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
    let Some(digits) = name
        .strip_prefix(stem)
        .and_then(|n| n.strip_prefix('_'))
        .and_then(|n| n.strip_suffix(frame_extension(format)))
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
    let entries = io_context(fs::read_dir(dir), || {
        format!("cannot read {}", dir.display())
    })?;
    for entry in entries {
        let entry = io_context(entry, || format!("cannot read {}", dir.display()))?;
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

/// A builder for staged names: hidden, recognisable, and created with ordinary permissions
/// (0666 / 0777 less the umask) rather than a temporary file's 0600, since they are renamed
/// into place as they are.
fn builder(mode: u32) -> tempfile::Builder<'static, 'static> {
    let mut builder = tempfile::Builder::new();
    builder.prefix(".softbody-").suffix(".part");
    #[cfg(unix)]
    builder.permissions(<fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(mode));
    #[cfg(not(unix))]
    let _ = mode;
    builder
}

fn temp_file(dir: &Path) -> Result<NamedTempFile, OutputError> {
    io_context(builder(0o666).tempfile_in(dir), || {
        format!("cannot write in {}", dir.display())
    })
}

fn temp_dir(dir: &Path) -> Result<TempDir, OutputError> {
    io_context(builder(0o777).tempdir_in(dir), || {
        format!("cannot write in {}", dir.display())
    })
}

/// Renames the staged directory `frames` to `dir`, replacing a directory of frames there.
fn place_dir(frames: TempDir, dir: &Path, stem: &str, format: Format) -> Result<(), OutputError> {
    let parent = parent_of(dir);
    let cannot = || format!("cannot write {}", dir.display());
    // Checked again: the directory may have changed during the run.
    check_replaceable(dir, stem, format)?;
    // A directory cannot be renamed over a non-empty one: move the old one into a temporary
    // directory (deleted with it) first.
    let old = if dir.exists() {
        let aside = temp_dir(parent)?;
        io_context(fs::rename(dir, aside.path().join("old")), cannot)?;
        Some(aside)
    } else {
        None
    };
    let staged = frames.keep();
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
        let (dir, stem) = series_names(Format::Ply, Path::new("out/run.v2")).unwrap();
        assert_eq!(
            (dir, stem.as_str()),
            (PathBuf::from("out/run.v2"), "run.v2")
        );
        assert!(series_names(Format::Obj, Path::new("..")).is_err());
        assert!(series_names(Format::Obj, Path::new("/")).is_err());
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
