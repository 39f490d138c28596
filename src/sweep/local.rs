//! Running a sweep on this machine: worker threads taking the unfinished runs one by one.

use std::io;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use super::{Manifest, Status, Sweep, SweepError};

/// Which runs a local sweep takes, with how many workers, and until when.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options<'a> {
    /// Runs at once (default: all cores, divided by the threads per run).
    pub workers: Option<usize>,
    /// A Slurm array task: `(index, count)` runs the runs `i` with `i % count == index`
    /// (count 1: the run `index` alone), recording them in the task's own manifest.
    pub task: Option<(usize, usize)>,
    /// Set (by a signal handler, another thread) to stop: the runs under way end after their
    /// complete frames and are not recorded (a sweep run again runs them), no run starts.
    pub stop: Option<&'a AtomicBool>,
}

impl Options<'_> {
    /// Refuses zero workers, zero tasks, and a task index that takes none of `runs` runs.
    pub fn check(&self, runs: usize) -> Result<(), SweepError> {
        let refuse = |m: String| Err(SweepError::Options(m));
        match (self.workers, self.task) {
            (Some(0), _) => refuse("a sweep takes at least 1 worker".into()),
            (_, Some((_, 0))) => refuse("a sweep is shared by at least 1 task".into()),
            (_, Some((index, 1))) if index >= runs => refuse(format!(
                "task index {index} names no run: the sweep has {runs} (0 to {})",
                runs - 1
            )),
            (_, Some((index, count))) if count > 1 && index >= count => refuse(format!(
                "task index {index} is not below the task count {count}: it takes no run"
            )),
            _ => Ok(()),
        }
    }
}

/// What a sweep did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Outcome {
    /// Runs this invocation was to take (the plan, or the task's share).
    pub planned: usize,
    /// Of those, already finished in the manifest and skipped.
    pub skipped: usize,
    /// Run now and ended `ok`.
    pub ok: usize,
    /// Run now and ended `unstable`.
    pub unstable: usize,
    /// Run now and ended `invalid`.
    pub invalid: usize,
    /// Run now and ended `failed`.
    pub failed: usize,
    /// Stopped under way by [`Options::stop`], not recorded.
    pub stopped: usize,
}

/// The runs this invocation takes under `task` (see [`Options::task`]).
pub fn task_runs(len: usize, task: Option<(usize, usize)>) -> Vec<usize> {
    match task {
        None => (0..len).collect(),
        Some((index, 1)) => (index < len).then_some(index).into_iter().collect(),
        Some((index, count)) => (0..len).filter(|i| i % count == index).collect(),
    }
}

/// Runs the sweep on this machine's cores into `out`: the runs not yet finished there, as many
/// at once as `options.workers`, each record appended to the manifest as its run ends;
/// `progress` hears (runs done, runs to do).
pub fn run_local(
    sweep: &Sweep,
    out: &Path,
    options: &Options,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Outcome, SweepError> {
    options.check(sweep.len())?;
    let manifest = Manifest::open(sweep, out, options.task.map(|(i, _)| i))?;
    let planned = task_runs(sweep.len(), options.task);
    let todo: Vec<usize> = planned
        .iter()
        .copied()
        .filter(|&i| !manifest.finished(i))
        .collect();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let workers = options
        .workers
        .unwrap_or((cores / sweep.threads).max(1))
        .max(1);
    let done = AtomicUsize::new(0);
    let next = AtomicUsize::new(0);
    let counts = Mutex::new(Outcome {
        planned: planned.len(),
        skipped: planned.len() - todo.len(),
        ..Outcome::default()
    });
    let write_error: Mutex<Option<io::Error>> = Mutex::new(None);
    progress(0, todo.len());
    // Plain threads taking the next run from a counter, not a rayon pool: each run steps in
    // its solver's own pool, and a rayon worker blocked in another pool's `install` steals
    // work from its own meanwhile — another run, whose solver blocks in turn — so the runs
    // nested on one stack until it overflowed (a 1,000-run sweep did).
    let worker = || {
        loop {
            if options.stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
                break;
            }
            let k = next.fetch_add(1, Ordering::Relaxed);
            let Some(&i) = todo.get(k) else { break };
            let Some(record) = sweep.job(i, out).run_until(options.stop) else {
                counts.lock().expect("not poisoned").stopped += 1;
                break;
            };
            {
                let mut c = counts.lock().expect("not poisoned");
                match record.status {
                    Status::Ok => c.ok += 1,
                    Status::Unstable => c.unstable += 1,
                    Status::Invalid => c.invalid += 1,
                    Status::Failed => c.failed += 1,
                }
            }
            if let Err(e) = manifest.append(record) {
                write_error.lock().expect("not poisoned").get_or_insert(e);
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, todo.len());
        }
    };
    std::thread::scope(|scope| -> Result<(), SweepError> {
        for w in 0..workers.min(todo.len()) {
            std::thread::Builder::new()
                .name(format!("sweep-{w}"))
                .spawn_scoped(scope, worker)
                .map_err(|source| SweepError::Threads { workers, source })?;
        }
        Ok(())
    })?;
    if let Some(source) = write_error.into_inner().expect("not poisoned") {
        return Err(SweepError::Io {
            path: manifest.path().to_owned(),
            source,
        });
    }
    Ok(counts.into_inner().expect("not poisoned"))
}
