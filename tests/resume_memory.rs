//! `--resume` streams the journal to the output a record at a time: the memory of a resumed run
//! does not grow with the frames it takes from its checkpoint, and its output is the
//! uninterrupted run's, byte for byte.
//!
//! Its own test binary, so that its allocator can count every live byte of the run.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use softbody::output::Format;
use softbody::service::{
    self, CheckpointPlan, Destination, Hooks, Notice, RunRequest, SceneSource,
};

/// The system's allocator, counting the bytes live and their peak.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(bytes: usize) {
    let now = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

fn shrank(bytes: usize) {
    LIVE.fetch_sub(bytes, Ordering::Relaxed);
}

// SAFETY: every call is the system allocator's, with the caller's layout; the counters only
// observe.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        unsafe { System.dealloc(p, layout) };
        shrank(layout.size());
    }

    unsafe fn realloc(&self, p: *mut u8, layout: Layout, size: usize) -> *mut u8 {
        let q = unsafe { System.realloc(p, layout, size) };
        if !q.is_null() {
            if size > layout.size() {
                grew(size - layout.size());
            } else {
                shrank(layout.size() - size);
            }
        }
        q
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// What `f` returns, and the most bytes live during it beyond those live before it.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let before = LIVE.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let value = f();
    (value, PEAK.load(Ordering::Relaxed) - before)
}

/// A 10×10×10 cube (1000 particles) falling onto the ground: 121 frames of 8 or 9 steps.
const CUBE: &str = r#"
[simulation]
integrator = "symplectic-euler"
dt = 0.001
duration = 1.0
frame_rate = 120.0

[[body]]
kind = "cuboid"
size = [0.3, 0.3, 0.3]
resolution = [10, 10, 10]
center = [0.0, 0.3, 0.0]
mass = 100.0
structural = { stiffness = 500.0, damping = 1.0 }
shear = { stiffness = 500.0, damping = 1.0 }

[[terrain]]
kind = "plane"
normal = [0.0, 1.0, 0.0]
"#;
const PARTICLES: usize = 1000;
const FRAMES: u64 = 121;
/// Frames between checkpoints.
const EVERY: u64 = 10;

fn request(out: &Path, checkpoint: Option<CheckpointPlan>) -> RunRequest {
    RunRequest {
        scene: SceneSource::Text {
            text: CUBE.into(),
            origin: out.with_file_name("cube.toml"),
        },
        threads: Some(1),
        destination: Destination::File {
            format: Format::Jsonl,
            path: out.to_owned(),
        },
        checkpoint,
        ..RunRequest::file("cube.toml")
    }
}

/// A run checkpointed every 10 frames and stopped after frame 100 is resumed from its
/// checkpoint's 100 frames: the resume's peak of live bytes exceeds the stopped run's by no more
/// than the two journal records a stream holds beyond what the run holds (the record read, and
/// the frame decoded from it), where holding the journal's frames would take a hundred; and the
/// output is the uninterrupted run's.
#[test]
fn a_resume_streams_the_journal_in_the_memory_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.jsonl");
    let (outcome, _) = peak_of(|| service::execute(&request(&whole, None), Hooks::default()));
    assert_eq!(outcome.result.unwrap().frames, FRAMES);

    let out = dir.path().join("resumed.jsonl");
    let plan = CheckpointPlan {
        every: Some(EVERY),
        resume: false,
    };
    let scene = softbody::Scene::from_toml(CUBE, Path::new("cube.toml")).unwrap();
    let stop_at = scene.simulation.frame_step(100);
    let stop = AtomicBool::new(false);
    let (stopped, run_peak) = peak_of(|| {
        service::execute(
            &request(&out, Some(plan)),
            Hooks {
                progress: Some(&mut |done, _| stop.store(done >= stop_at, Ordering::Relaxed)),
                stop: Some(&stop),
                ..Hooks::default()
            },
        )
    });
    assert_eq!(stopped.frames, 101, "{:?}", stopped.result);
    assert!(stopped.checkpoint.is_some());

    let mut resumed_after = None;
    let (resumed, resume_peak) = peak_of(|| {
        service::execute(
            &request(
                &out,
                Some(CheckpointPlan {
                    every: None,
                    resume: true,
                }),
            ),
            Hooks {
                notice: Some(&mut |n| {
                    if let Notice::Resuming { after_frame, .. } = n {
                        resumed_after = Some(after_frame);
                    }
                }),
                ..Hooks::default()
            },
        )
    });
    assert_eq!(resumed.result.unwrap().frames, FRAMES);
    assert_eq!(
        resumed_after,
        Some(99),
        "the checkpoint counts frames 0 to 99"
    );
    assert!(
        std::fs::read(&out).unwrap() == std::fs::read(&whole).unwrap(),
        "the resumed output differs from the uninterrupted run's"
    );

    // A journal record: a frame's positions and velocities (48 bytes a particle), and a few
    // words of frame number, step, time, energies and checksum.
    let record = 48 * PARTICLES + 64;
    let bound = run_peak + 2 * record;
    assert!(
        resume_peak <= bound,
        "the resume peaked at {resume_peak} bytes live, the stopped run at {run_peak}: more than \
         the two records ({record} bytes each) a stream holds beyond the run"
    );
}
