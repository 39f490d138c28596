//! Advisory locks on outputs: a run that checkpoints, or a sweep, holds one on what it writes,
//! so that a second process aimed at the same output is refused at once instead of deleting the
//! first one's checkpoint or appending to a manifest the first one is replacing.
//!
//! A lock is a file (`<output>.lock` beside a file, `OUT/.lock` in a directory) held with the
//! operating system's advisory lock (`flock`): the kernel releases it when its holder exits,
//! also by `kill -9`, so a lock is never stale. The file names the holder's process id, for the
//! message of the process refused. On a file system without locks (some network mounts answer
//! `flock` with ENOLCK or EOPNOTSUPP) outputs are written unlocked.

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
    mode: Mode,
    remove: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Exclusive,
    Shared,
}

impl OutputLock {
    /// Locks the output file `output` with `<output>.lock` beside it; the lock file is removed
    /// when the lock is dropped.
    pub fn file(output: &Path) -> Result<OutputLock, LockError> {
        let mut name = output.as_os_str().to_owned();
        name.push(".lock");
        Self::acquire(output, PathBuf::from(name), Mode::Exclusive, true)
    }

    /// Locks the directory `dir` (which must exist) with `dir/.lock`, left there when the lock
    /// is dropped: it is one of the directory's own files.
    pub fn directory(dir: &Path) -> Result<OutputLock, LockError> {
        Self::acquire(dir, dir.join(".lock"), Mode::Exclusive, false)
    }

    /// Locks the directory `dir` shared with other shared holders (Slurm tasks writing files of
    /// their own in it), against an exclusive holder ([`OutputLock::directory`]).
    pub fn directory_shared(dir: &Path) -> Result<OutputLock, LockError> {
        Self::acquire(dir, dir.join(".lock"), Mode::Shared, false)
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn acquire(
        output: &Path,
        path: PathBuf,
        mode: Mode,
        remove: bool,
    ) -> Result<OutputLock, LockError> {
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
            let locked = match mode {
                Mode::Exclusive => file.try_lock(),
                Mode::Shared => file.try_lock_shared(),
            };
            match locked {
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
                // A file system without locks (some network mounts): the output is written
                // unlocked, as before locks, rather than not at all.
                Err(std::fs::TryLockError::Error(e)) if unsupported(&e) => {}
                Err(std::fs::TryLockError::Error(e)) => return Err(io(e)),
            }
            if !same_file(&file, &path) {
                continue;
            }
            // Shared holders are many: the file names only an exclusive one.
            if mode == Mode::Exclusive {
                file.set_len(0).map_err(io)?;
                file.rewind().map_err(io)?;
                writeln!(file, "{}", std::process::id()).map_err(io)?;
            }
            return Ok(OutputLock {
                file,
                path,
                mode,
                remove,
            });
        }
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held, so that no process locks the file being removed unseen
        // (`acquire` checks that the file it locked is still the one at the path).
        if self.remove {
            let _ = std::fs::remove_file(&self.path);
        } else if self.mode == Mode::Exclusive {
            // A file left behind names no holder, once there is none.
            let _ = self.file.set_len(0);
        }
        let _ = self.file.unlock();
    }
}

fn unsupported(e: &io::Error) -> bool {
    // ENOLCK (37), EOPNOTSUPP (95) and ENOSYS (38) are what Linux's network file systems answer.
    e.kind() == io::ErrorKind::Unsupported
        || (cfg!(target_os = "linux") && matches!(e.raw_os_error(), Some(37 | 38 | 95)))
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
        let shared = OutputLock::directory_shared(dir.path()).unwrap();
        let second = OutputLock::directory_shared(dir.path()).unwrap();
        match OutputLock::directory(dir.path()) {
            Err(LockError::Busy { holder, .. }) => assert_eq!(holder, None),
            other => panic!("expected Busy, got {other:?}"),
        }
        drop(shared);
        drop(second);
        OutputLock::directory(dir.path()).unwrap();
    }
}
