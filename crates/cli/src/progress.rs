//! Progress on the terminal: one bar style for every long command (run, bench, compare,
//! render), shown only when standard error is a terminal and `--quiet` is not given.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// A bar over `total` steps with elapsed time, steps/s and ETA; hidden when `quiet` or when
/// standard error is not a terminal (a pipe, a file, CI logs).
pub fn bar(total: u64, quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} steps, {per_sec}, ETA {eta} {msg}",
        )
        .expect("static template"),
    );
    bar
}
