//! The manifest journal (`OUT/manifest.jsonl`, or a Slurm task's `manifest-task-I.jsonl`): a
//! header line, then one [`Record`] a line, appended as each run ends.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};
use serde_json::Value as Json;

use super::job::parameter_map;
use super::{Record, Sweep, SweepError};
use crate::fingerprint::Fingerprint;
use crate::lock::OutputLock;

/// The manifest's file name in the out directory.
pub const MANIFEST: &str = "manifest.jsonl";

/// Version of the manifest's header line (`softbody_sweep`): 2 carries the job's `Identity`.
pub const MANIFEST_VERSION: u32 = 2;

/// The manifest's first line.
#[derive(Serialize, Deserialize)]
struct ManifestHeader {
    softbody_sweep: u32,
    sweep: String,
    runs: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    job: Option<Identity>,
}

/// What makes a sweep's records its own besides each run's parameters: the base scene (its
/// text with the settings of every run, and a fingerprint of the model it builds, which holds
/// the meshes it reads), the output format, the metrics, the backend and the threads per run
/// (the same scene, backend and threads give the same bits). A manifest of another identity
/// is never taken for this sweep's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct Identity {
    /// 16 hex digits: the FNV-1a hash of the base scene's text and model.
    pub(super) scene: String,
    pub(super) format: Option<String>,
    pub(super) metrics: Vec<String>,
    pub(super) backend: String,
    pub(super) threads: usize,
}

impl Identity {
    /// The fingerprint of a base scene loaded from `text`.
    pub(super) fn scene_fingerprint(scene: &softbody_scene::Scene, text: &str) -> String {
        use std::fmt::Write as _;
        let mut hash = Fingerprint::default();
        let (model, _) = softbody_scene::Model::build(scene);
        let _ = write!(hash, "{text}\n{model:?}");
        format!("{:016x}", hash.finish())
    }

    /// What differs from `theirs`, in words (`format: npz there, csv here`).
    fn differences(&self, theirs: &Identity) -> Vec<String> {
        let mut out = Vec::new();
        if self.scene != theirs.scene {
            out.push(
                "the base scene (its text, a mesh it reads, or the settings of every run)".into(),
            );
        }
        let mut differ = |what: &str, there: String, here: String| {
            if there != here {
                out.push(format!("{what}: {there} there, {here} here"));
            }
        };
        let format = |f: &Option<String>| f.clone().unwrap_or_else(|| "none".into());
        differ("format", format(&theirs.format), format(&self.format));
        differ(
            "metrics",
            theirs.metrics.join(", "),
            self.metrics.join(", "),
        );
        differ("backend", theirs.backend.clone(), self.backend.clone());
        differ(
            "threads",
            theirs.threads.to_string(),
            self.threads.to_string(),
        );
        out
    }
}

/// A sweep's manifest in its out directory: the records found there, and the file that new
/// records are appended to as runs end.
pub struct Manifest {
    path: PathBuf,
    file: Mutex<File>,
    records: Mutex<BTreeMap<usize, Record>>,
    // Held while the manifest is open: released when it is dropped.
    _locks: Vec<OutputLock>,
}

impl Manifest {
    /// Opens the manifest of `sweep` in `out` (made if missing): locks `out` (shared with the
    /// other Slurm tasks for a task, else alone), reads the records of `manifest.jsonl` and of
    /// every `manifest-task-*.jsonl` there, checks that they belong to this sweep (the same
    /// `Identity` in each header, the same parameters for the same run number), keeps one per
    /// run (a finished one over a failed one, else the last), and opens for appending
    /// `manifest.jsonl`, rewritten with the finished records kept, or with `task` Some(i) the
    /// task's own `manifest-task-i.jsonl`, which no other task writes, cut after its last whole
    /// line.
    pub fn open(sweep: &Sweep, out: &Path, task: Option<usize>) -> Result<Manifest, SweepError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |source| SweepError::Io { path, source }
        };
        std::fs::create_dir_all(out).map_err(io(out))?;
        let path = match task {
            Some(i) => out.join(format!("manifest-task-{i}.jsonl")),
            None => out.join(MANIFEST),
        };
        let locks = match task {
            Some(_) => vec![OutputLock::directory_shared(out)?, OutputLock::file(&path)?],
            None => vec![OutputLock::directory(out)?],
        };
        let mut records = collect(sweep, out)?;
        let file = if task.is_some() {
            let mut f = OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .map_err(io(&path))?;
            let whole = read_journal(&path)?.whole;
            if f.metadata().map_err(io(&path))?.len() > whole {
                // What a kill or a full disk left of a line: appended to, it would spoil the
                // next record's line too.
                f.set_len(whole).map_err(io(&path))?;
            }
            if whole == 0 {
                writeln!(f, "{}", header_line(sweep)).map_err(io(&path))?;
            }
            f
        } else {
            // Rewritten whole beside and renamed over, so a crash leaves the old or the new;
            // without the failed records, whose runs this sweep runs again and records anew.
            records.retain(|_, r| r.status.finished());
            let staged = out.join(".manifest.jsonl.part");
            let mut text = header_line(sweep);
            text.push('\n');
            for r in records.values() {
                text.push_str(&serde_json::to_string(r).expect("records serialise"));
                text.push('\n');
            }
            std::fs::write(&staged, text).map_err(io(&staged))?;
            std::fs::rename(&staged, &path).map_err(io(&path))?;
            OpenOptions::new()
                .append(true)
                .open(&path)
                .map_err(io(&path))?
        };
        Ok(Manifest {
            path,
            file: Mutex::new(file),
            records: Mutex::new(records),
            _locks: locks,
        })
    }

    /// The file records are appended to.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether run `i` has a finished record.
    pub fn finished(&self, i: usize) -> bool {
        let records = self.records.lock().expect("not poisoned");
        records.get(&i).is_some_and(|r| r.status.finished())
    }

    /// Appends a record (one write of one line, flushed) and keeps it.
    pub fn append(&self, record: Record) -> io::Result<()> {
        let mut line = serde_json::to_string(&record).map_err(io::Error::other)?;
        line.push('\n');
        {
            let mut file = self.file.lock().expect("not poisoned");
            file.write_all(line.as_bytes())?;
            file.flush()?;
        }
        self.records
            .lock()
            .expect("not poisoned")
            .insert(record.run, record);
        Ok(())
    }

    /// Every record, in run order.
    pub fn records(&self) -> Vec<Record> {
        let records = self.records.lock().expect("not poisoned");
        records.values().cloned().collect()
    }
}

/// The records of `out`'s manifests (`manifest.jsonl`, then every `manifest-task-*.jsonl`),
/// checked against `sweep`, one per run: a finished one over a failed one, else the last.
fn collect(sweep: &Sweep, out: &Path) -> Result<BTreeMap<usize, Record>, SweepError> {
    let mut files = vec![out.join(MANIFEST)];
    let mut tasks: Vec<PathBuf> = match std::fs::read_dir(out) {
        Ok(entries) => entries.filter_map(|e| e.ok().map(|e| e.path())).collect(),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Vec::new(),
        Err(source) => {
            return Err(SweepError::Io {
                path: out.to_owned(),
                source,
            });
        }
    };
    tasks.retain(|p| {
        p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with("manifest-task-") && n.ends_with(".jsonl"))
    });
    tasks.sort();
    files.extend(tasks);
    let mut records: BTreeMap<usize, Record> = BTreeMap::new();
    for file in &files {
        let journal = read_journal(file)?;
        check_identity(sweep, file, &journal)?;
        for record in journal.records {
            let expected = sweep
                .runs
                .get(record.run)
                .map(|p| parameter_map(p))
                .filter(|p| *p == record.parameters);
            if expected.is_none() {
                return Err(SweepError::Manifest {
                    path: file.clone(),
                    message: format!(
                        "run {} there has other parameters than in {} ({}): the manifest is \
                         another sweep's; give this one another out directory",
                        record.run,
                        sweep.file.display(),
                        Json::Object(record.parameters.clone())
                    ),
                });
            }
            let keep = match records.get(&record.run) {
                Some(old) => !old.status.finished() || record.status.finished(),
                None => true,
            };
            if keep {
                records.insert(record.run, record);
            }
        }
    }
    Ok(records)
}

/// Every record of `sweep` in `out` (its manifest and its Slurm tasks' manifests), one per
/// run that has one, in run order.
pub fn read_manifest(sweep: &Sweep, out: &Path) -> Result<Vec<Record>, SweepError> {
    Ok(collect(sweep, out)?.into_values().collect())
}

pub(super) fn header_line(sweep: &Sweep) -> String {
    let sweep_file = std::path::absolute(&sweep.file).unwrap_or_else(|_| sweep.file.clone());
    serde_json::to_string(&ManifestHeader {
        softbody_sweep: MANIFEST_VERSION,
        sweep: sweep_file.display().to_string(),
        runs: sweep.len(),
        job: Some(sweep.identity.clone()),
    })
    .expect("the header serialises")
}

/// Refuses a manifest file whose header is another job's (or has none, with records).
fn check_identity(sweep: &Sweep, file: &Path, journal: &Journal) -> Result<(), SweepError> {
    let refuse = |why: String| SweepError::Manifest {
        path: file.to_owned(),
        message: format!(
            "{why}: its records are not this sweep's answer; give this sweep another --out \
             directory, or remove {} to start afresh",
            file.parent().unwrap_or(Path::new(".")).display()
        ),
    };
    match &journal.header {
        None if journal.records.is_empty() => Ok(()),
        None => Err(refuse("it has no header line".into())),
        Some(h) if h.softbody_sweep != MANIFEST_VERSION => Err(refuse(format!(
            "it is of manifest version {}, this softbody writes {MANIFEST_VERSION}",
            h.softbody_sweep
        ))),
        Some(ManifestHeader { job: None, .. }) => {
            Err(refuse("its header does not say which job wrote it".into()))
        }
        Some(ManifestHeader {
            job: Some(theirs),
            sweep: other,
            ..
        }) => {
            let differences = sweep.identity.differences(theirs);
            if differences.is_empty() {
                Ok(())
            } else {
                Err(refuse(format!(
                    "it holds the runs of another sweep job ({other}), which differs in {}",
                    differences.join("; ")
                )))
            }
        }
    }
}

/// A manifest file as read: its header, its records, and the length of its whole lines.
struct Journal {
    header: Option<ManifestHeader>,
    records: Vec<Record>,
    whole: u64,
}

/// The records of a manifest file (none when it does not exist).
#[cfg(test)]
pub(super) fn read_records(path: &Path) -> Result<Vec<Record>, SweepError> {
    Ok(read_journal(path)?.records)
}

/// A manifest file (empty when it does not exist). A last line without its newline is what a
/// killed sweep leaves mid-write: it is dropped, and its run runs again.
fn read_journal(path: &Path) -> Result<Journal, SweepError> {
    let mut journal = Journal {
        header: None,
        records: Vec::new(),
        whole: 0,
    };
    let file = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(journal),
        Err(source) => {
            return Err(SweepError::Io {
                path: path.to_owned(),
                source,
            });
        }
    };
    let mut reader = BufReader::new(file);
    let mut line = String::new();
    let mut number = 0;
    let bad = |number: usize, what: &str, e: serde_json::Error| SweepError::Manifest {
        path: path.to_owned(),
        message: format!("line {number} is not {what}: {e}"),
    };
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .map_err(|source| SweepError::Io {
                path: path.to_owned(),
                source,
            })?;
        if n == 0 || !line.ends_with('\n') {
            break;
        }
        number += 1;
        journal.whole += n as u64;
        if line.trim().is_empty() {
            continue;
        }
        if line.starts_with("{\"softbody_sweep\"") {
            let header = serde_json::from_str(&line).map_err(|e| bad(number, "a header", e))?;
            journal.header = Some(header);
            continue;
        }
        let record = serde_json::from_str(&line).map_err(|e| bad(number, "a sweep record", e))?;
        journal.records.push(record);
    }
    Ok(journal)
}
