//! Progress on the terminal: one bar style for every long command (run, bench, compare,
//! render), shown only when standard error is a terminal and `--quiet` is not given.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// A bar over `total` of `unit` (steps, frames) with elapsed time, rate and ETA; hidden when
/// `quiet` or when standard error is not a terminal (a pipe, a file, CI logs).
pub fn bar(total: u64, unit: &str, quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} [{{elapsed_precise}}] {{wide_bar}} {{pos}}/{{len}} {unit}, {{per_sec}}, ETA {{eta}} {{msg}}"
        ))
        .expect("a valid template"),
    );
    bar
}
