//! Fingerprints of what is run: an FNV-1a hash of values as `Debug` prints them, which is every
//! number to the bit (Rust prints the shortest text that reads back to the same float). A
//! checkpoint carries one of its model and state, a sweep's manifest one of its base scene.

use std::fmt;
use std::hash::Hasher;

use fnv::FnvHasher;

/// A running fingerprint: `write!` into it, then [`finish`](Fingerprint::finish).
#[derive(Default)]
pub(crate) struct Fingerprint(FnvHasher);

impl Fingerprint {
    /// The hash of everything written.
    pub(crate) fn finish(&self) -> u64 {
        self.0.finish()
    }
}

impl fmt::Write for Fingerprint {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.0.write(s.as_bytes());
        Ok(())
    }
}
