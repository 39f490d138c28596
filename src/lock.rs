//! Advisory locks on outputs: a run that checkpoints, or a sweep, holds one on what it writes,
//! so that a second process aimed at the same output is refused at once instead of deleting the
//! first one's checkpoint or appending to a manifest the first one is replacing.
//!
//! A lock is a file (`<output>.lock` beside a file, `OUT/.lock` in a directory) held with the
//! operating system's advisory lock (`flock`): the kernel releases it when its holder exits,
//! also by `kill -9`, so a lock is never stale. The file names the holder's process id, for the
//! message of the process refused.

use std::fs::{File, OpenOptions};
use std::io::{self, Read, Seek, Write};
use std::path::{Path, PathBuf};

/// Why a lock was not taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another process holds it.
    #[error(
        "{} is being written by another softbody process{} (it holds {}); wait for it to end, \
         or write elsewhere",
        output.display(),
        holder.map(|p| format!(" (process {p})")).unwrap_or_default(),
        lock.display()
    )]
    Busy {
        /// The output.
        output: PathBuf,
        /// The lock file.
        lock: PathBuf,
        /// The holder's process id, when the file names one.
        holder: Option<u32>,
    },
    /// The lock file cannot be made or locked.
    #[error("cannot lock {}: {cause}", lock.display())]
    Io {
        /// The lock file.
        lock: PathBuf,
        /// Why (in the message already, so not a `source`: error chains would repeat it).
        cause: io::Error,
    },
}

/// A held lock; released (and its file removed, when it was made beside a file) when dropped.
#[derive(Debug)]
pub struct OutputLock {
    file: File,
    path: PathBuf,
    remove: bool,
}

impl OutputLock {
    /// Locks the output file `output` with `<output>.lock` beside it; the lock file is removed
    /// when the lock is dropped.
    pub fn file(output: &Path) -> Result<OutputLock, LockError> {
        let mut name = output.as_os_str().to_owned();
        name.push(".lock");
        Self::acquire(output, PathBuf::from(name), true)
    }

    /// Locks the directory `dir` (which must exist) with `dir/.lock`, left there when the lock
    /// is dropped: it is one of the directory's own files.
    pub fn directory(dir: &Path) -> Result<OutputLock, LockError> {
        Self::acquire(dir, dir.join(".lock"), false)
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn acquire(output: &Path, path: PathBuf, remove: bool) -> Result<OutputLock, LockError> {
        let io = |cause| LockError::Io {
            lock: path.clone(),
            cause,
        };
        // A holder that removes its file on release may do so between our open and our lock:
        // the lock is then on a file no longer at `path`, and the open is tried again.
        loop {
            let mut file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(io)?;
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    let mut text = String::new();
                    let holder = file
                        .read_to_string(&mut text)
                        .ok()
                        .and_then(|_| text.trim().parse().ok());
                    return Err(LockError::Busy {
                        output: output.to_owned(),
                        lock: path,
                        holder,
                    });
                }
                Err(std::fs::TryLockError::Error(e)) => return Err(io(e)),
            }
            if !same_file(&file, &path) {
                continue;
            }
            file.set_len(0).map_err(io)?;
            file.rewind().map_err(io)?;
            writeln!(file, "{}", std::process::id()).map_err(io)?;
            return Ok(OutputLock { file, path, remove });
        }
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held, so that no process locks the file being removed unseen
        // (`acquire` checks that the file it locked is still the one at the path).
        if self.remove {
            let _ = std::fs::remove_file(&self.path);
        }
        let _ = self.file.unlock();
    }
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

// Elsewhere a file that is open cannot be removed, so the one at the path is the one locked.
#[cfg(not(unix))]
fn same_file(_: &File, path: &Path) -> bool {
    path.exists()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_on_one_output_is_refused_and_names_the_holder() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("frames.jsonl");
        let first = OutputLock::file(&out).unwrap();
        match OutputLock::file(&out) {
            Err(LockError::Busy { holder, lock, .. }) => {
                assert_eq!(holder, Some(std::process::id()));
                assert_eq!(lock, dir.path().join("frames.jsonl.lock"));
            }
            other => panic!("expected Busy, got {other:?}"),
        }
        drop(first);
        assert!(!dir.path().join("frames.jsonl.lock").exists());
        let again = OutputLock::file(&out).unwrap();
        assert!(again.path().exists());
    }

    #[test]
    fn a_directory_lock_stays_as_a_file_of_the_directory() {
        let dir = tempfile::tempdir().unwrap();
        let lock = OutputLock::directory(dir.path()).unwrap();
        assert!(matches!(
            OutputLock::directory(dir.path()),
            Err(LockError::Busy { .. })
        ));
        drop(lock);
        assert!(dir.path().join(".lock").exists());
        OutputLock::directory(dir.path()).unwrap();
    }
}
