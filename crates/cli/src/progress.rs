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

/// `x` rounded to a whole number with thousands separated: `7,446`.
pub fn whole(x: f64) -> String {
    let digits = format!("{:.0}", x.abs());
    if !x.is_finite() || digits.contains(|c: char| !c.is_ascii_digit()) {
        return format!("{x:.0}");
    }
    let mut out = String::new();
    for (k, c) in digits.chars().enumerate() {
        if k > 0 && (digits.len() - k) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    if x.is_sign_negative() && digits != "0" {
        out.insert(0, '-');
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn whole_numbers_have_their_thousands_separated() {
        for (x, text) in [
            (0.0, "0"),
            (7.4, "7"),
            (999.5, "1,000"),
            (7446.2, "7,446"),
            (1234567.0, "1,234,567"),
            (-65536.0, "-65,536"),
        ] {
            assert_eq!(super::whole(x), text, "{x}");
        }
    }
}
