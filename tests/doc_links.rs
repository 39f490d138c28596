//! Every relative link in the repository's Markdown files resolves: for each `*.md` (outside
//! `target/`, `.git/` and other hidden or build directories), each link `[text](target)`,
//! `![alt](target)`, reference definition `[label]: target` and HTML `src="…"` / `href="…"`
//! whose target is not a URL (`http:`, `https:`, `mailto:`, …) must name a file or directory
//! that exists, relative to the Markdown file (or to the repository's root for `/…`). An
//! `#anchor` into a Markdown file must name one of its headings, slugged as GitHub does
//! (lowercase, punctuation dropped, spaces to hyphens, `-1`, `-2`, … for repeats). Links inside
//! code blocks and code spans are not links and are skipped. No Markdown file holds a merge's
//! conflict markers.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Component, Path, PathBuf};

#[test]
fn every_relative_link_in_the_docs_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    markdown_files(root, root, &mut files);
    files.sort();
    assert!(
        files.iter().any(|f| f == &root.join("README.md")),
        "README.md not found under {}",
        root.display()
    );

    let mut headings: BTreeMap<PathBuf, BTreeSet<String>> = BTreeMap::new();
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in &files {
        let text = fs::read_to_string(file)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", file.display()));
        for link in links(&text) {
            checked += 1;
            if let Err(why) = resolve(root, file, &link.target, &mut headings) {
                let shown = file.strip_prefix(root).unwrap_or(file);
                broken.push(format!(
                    "{}:{}: {} ({why})",
                    shown.display(),
                    link.line,
                    link.target
                ));
            }
        }
    }
    assert!(
        broken.is_empty(),
        "{} of {checked} relative links in {} Markdown files do not resolve:\n  {}",
        broken.len(),
        files.len(),
        broken.join("\n  ")
    );
}

/// Collects the Markdown files under `dir`, skipping build output, VCS data and hidden
/// directories.
/// A merge that left `<<<<<<<` … `>>>>>>>` in a page reads as prose (a heading's anchor can even
/// survive it), so the links' check alone misses it.
#[test]
fn no_markdown_file_holds_conflict_markers() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    markdown_files(root, root, &mut files);
    let mut found = Vec::new();
    for file in &files {
        let text = fs::read_to_string(file)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", file.display()));
        for (k, line) in text.lines().enumerate() {
            if line.starts_with("<<<<<<< ") || line.starts_with(">>>>>>> ") {
                let shown = file.strip_prefix(root).unwrap_or(file);
                found.push(format!("{}:{}", shown.display(), k + 1));
            }
        }
    }
    assert!(found.is_empty(), "conflict markers at {}", found.join(", "));
}

fn markdown_files(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
    let entries =
        fs::read_dir(dir).unwrap_or_else(|e| panic!("cannot list {}: {e}", dir.display()));
    for entry in entries {
        let entry = entry.expect("directory entry");
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        let kind = entry.file_type().expect("file type");
        if kind.is_dir() {
            let skipped = name.starts_with('.')
                || name == "target"
                || name == "node_modules"
                || (dir == root && name == "out");
            if !skipped {
                markdown_files(root, &path, out);
            }
        } else if name.ends_with(".md") {
            out.push(path);
        }
    }
}

/// A link found in a Markdown file.
struct Link {
    target: String,
    line: usize,
}

/// The relative link targets of a Markdown text, with their line numbers.
fn links(text: &str) -> Vec<Link> {
    let masked = mask_code(text);
    let bytes = masked.as_bytes();
    let line_of = |offset: usize| masked[..offset].matches('\n').count() + 1;
    let mut found = Vec::new();
    let mut push = |raw: &str, offset: usize| {
        let target = clean_target(raw);
        if !target.is_empty() && !is_external(&target) {
            found.push(Link {
                target,
                line: line_of(offset),
            });
        }
    };

    // Inline links and images: `](target)` or `](target "title")`.
    let mut at = 0;
    while let Some(i) = masked[at..].find("](") {
        let start = at + i + 2;
        let mut depth = 0usize;
        let mut end = start;
        while end < bytes.len() {
            match bytes[end] {
                b'(' => depth += 1,
                b')' if depth == 0 => break,
                b')' => depth -= 1,
                b'\n' => break,
                _ => {}
            }
            end += 1;
        }
        if end < bytes.len() && bytes[end] == b')' {
            push(&masked[start..end], start);
        }
        at = start;
    }

    // Reference definitions: `[label]: target` at the start of a line.
    let mut offset = 0;
    for line in masked.split_inclusive('\n') {
        let trimmed = line.trim_start();
        if trimmed.starts_with('[')
            && let Some(close) = trimmed.find("]:")
            && !trimmed[1..close].contains(']')
        {
            let target = trimmed[close + 2..].trim();
            push(target, offset);
        }
        offset += line.len();
    }

    // HTML attributes: `src="…"` and `href="…"`.
    for attribute in ["src=\"", "href=\""] {
        let mut at = 0;
        while let Some(i) = masked[at..].find(attribute) {
            let start = at + i + attribute.len();
            if let Some(len) = masked[start..].find('"') {
                push(&masked[start..start + len], start);
            }
            at = start;
        }
    }
    found
}

/// The text with fenced code blocks and code spans replaced by spaces (newlines kept, so that
/// offsets keep their line numbers).
fn mask_code(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut fence: Option<(char, usize)> = None;
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim_start();
        let marker = trimmed.chars().next().filter(|c| *c == '`' || *c == '~');
        let run = marker.map_or(0, |c| trimmed.chars().take_while(|&x| x == c).count());
        match fence {
            Some((c, n)) => {
                if marker == Some(c) && run >= n && trimmed[run..].trim().is_empty() {
                    fence = None;
                }
                out.push_str(&blank(line));
            }
            None if run >= 3 => {
                fence = Some((marker.expect("a fence marker"), run));
                out.push_str(&blank(line));
            }
            None => out.push_str(&mask_spans(line)),
        }
    }
    out
}

/// A line with its code spans (backtick runs and what they enclose) replaced by spaces.
fn mask_spans(line: &str) -> String {
    let chars: Vec<char> = line.chars().collect();
    let mut out = String::with_capacity(line.len());
    let mut i = 0;
    while i < chars.len() {
        if chars[i] != '`' {
            out.push(chars[i]);
            i += 1;
            continue;
        }
        let run = chars[i..].iter().take_while(|&&c| c == '`').count();
        // The closing run: exactly `run` backticks.
        let mut j = i + run;
        let mut close = None;
        while j < chars.len() {
            if chars[j] == '`' {
                let n = chars[j..].iter().take_while(|&&c| c == '`').count();
                if n == run {
                    close = Some(j);
                    break;
                }
                j += n;
            } else {
                j += 1;
            }
        }
        match close {
            Some(j) => {
                for c in &chars[i..j + run] {
                    out.extend(std::iter::repeat_n(' ', c.len_utf8()));
                }
                i = j + run;
            }
            None => {
                for c in &chars[i..i + run] {
                    out.push(*c);
                }
                i += run;
            }
        }
    }
    out
}

/// Spaces for every byte of `line` but its newline.
fn blank(line: &str) -> String {
    line.bytes()
        .map(|b| if b == b'\n' { '\n' } else { ' ' })
        .collect()
}

/// The link's destination without its title or angle brackets, `%20` decoded.
fn clean_target(raw: &str) -> String {
    let raw = raw.trim();
    let target = if let Some(rest) = raw.strip_prefix('<') {
        rest.split('>').next().unwrap_or("")
    } else {
        raw.split_whitespace().next().unwrap_or("")
    };
    target.replace("%20", " ")
}

/// Whether a target is a URL (a scheme such as `https:` or `mailto:`) rather than a path.
fn is_external(target: &str) -> bool {
    if target.starts_with("//") {
        return true;
    }
    match target.find(':') {
        Some(colon) => {
            let scheme = &target[..colon];
            !scheme.is_empty()
                && scheme
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
                && !target[..colon].contains('/')
        }
        None => false,
    }
}

/// Checks that `target`, linked from `file`, names an existing path, and that its anchor names a
/// heading when it points into a Markdown file.
fn resolve(
    root: &Path,
    file: &Path,
    target: &str,
    headings: &mut BTreeMap<PathBuf, BTreeSet<String>>,
) -> Result<(), String> {
    let (path, anchor) = match target.split_once('#') {
        Some((path, anchor)) => (path, Some(anchor)),
        None => (target, None),
    };
    let destination = if path.is_empty() {
        file.to_path_buf()
    } else if let Some(from_root) = path.strip_prefix('/') {
        normalise(&root.join(from_root))
    } else {
        normalise(&file.parent().expect("a file has a directory").join(path))
    };
    if !destination.exists() {
        return Err(format!(
            "no such file or directory: {}",
            destination.display()
        ));
    }
    let Some(anchor) = anchor.filter(|a| !a.is_empty()) else {
        return Ok(());
    };
    if destination.extension().is_none_or(|e| e != "md") {
        return Ok(());
    }
    let slugs = headings.entry(destination.clone()).or_insert_with(|| {
        let text = fs::read_to_string(&destination).unwrap_or_default();
        heading_slugs(&text)
    });
    if slugs.contains(&anchor.to_lowercase()) {
        Ok(())
    } else {
        Err(format!(
            "no heading #{anchor} in {}",
            destination
                .strip_prefix(root)
                .unwrap_or(&destination)
                .display()
        ))
    }
}

/// `a/b/../c` → `a/c`, without touching the file system.
fn normalise(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// The anchors GitHub gives a Markdown text's headings.
fn heading_slugs(text: &str) -> BTreeSet<String> {
    let masked_fences = {
        // Fences only: a heading's code spans are part of its text.
        let mut out = Vec::new();
        let mut fence: Option<(char, usize)> = None;
        for line in text.lines() {
            let trimmed = line.trim_start();
            let marker = trimmed.chars().next().filter(|c| *c == '`' || *c == '~');
            let run = marker.map_or(0, |c| trimmed.chars().take_while(|&x| x == c).count());
            match fence {
                Some((c, n)) => {
                    if marker == Some(c) && run >= n && trimmed[run..].trim().is_empty() {
                        fence = None;
                    }
                }
                None if run >= 3 => fence = Some((marker.expect("a fence marker"), run)),
                None => out.push(line),
            }
        }
        out
    };
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut slugs = BTreeSet::new();
    for line in masked_fences {
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if !(1..=6).contains(&hashes) || !line[hashes..].starts_with(' ') {
            continue;
        }
        let title = line[hashes..].trim().trim_end_matches('#').trim();
        let base = slug(&link_texts(title));
        let count = seen.entry(base.clone()).or_insert(0);
        let slug = if *count == 0 {
            base.clone()
        } else {
            format!("{base}-{count}")
        };
        *count += 1;
        slugs.insert(slug);
    }
    slugs
}

/// `[text](url)` → `text`, as a heading renders.
fn link_texts(title: &str) -> String {
    let mut out = String::new();
    let mut rest = title;
    while let Some(open) = rest.find('[') {
        let Some(mid) = rest[open..].find("](") else {
            break;
        };
        let Some(close) = rest[open + mid..].find(')') else {
            break;
        };
        out.push_str(&rest[..open]);
        out.push_str(&rest[open + 1..open + mid]);
        rest = &rest[open + mid + close + 1..];
    }
    out.push_str(rest);
    out
}

/// GitHub's heading anchor: lowercase; letters, numbers, `_`, `-` and spaces kept, the rest
/// dropped; spaces become hyphens.
fn slug(title: &str) -> String {
    title
        .to_lowercase()
        .chars()
        .filter(|&c| c.is_alphanumeric() || c == '_' || c == '-' || c == ' ')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

#[test]
fn slugs_are_githubs() {
    let text = "# A title\n## `softbody run`\n### Changing any value: `--set`\n## NPZ (`npz`)\n\
                ```sh\n# not a heading\n```\n## A title\n## 100³ and 46³ — figures\n";
    let slugs = heading_slugs(text);
    let expected = [
        "a-title",
        "softbody-run",
        "changing-any-value---set",
        "npz-npz",
        "a-title-1",
        "100³-and-46³--figures",
    ];
    assert_eq!(
        slugs,
        expected
            .iter()
            .map(|s| s.to_string())
            .collect::<BTreeSet<_>>()
    );
}

#[test]
fn links_skip_code_and_urls() {
    let text = "See [a](a.md#x) and ![b](img/b.png \"title\").\n\
                `[not](a link)` and [web](https://example.org) [mail](mailto:x@y)\n\
                ```text\n[inside](fence.md)\n```\n[ref]: <refs/c.md>\n<img src=\"d.gif\" alt=\"\">\n";
    let found: Vec<(String, usize)> = links(text)
        .into_iter()
        .map(|l| (l.target, l.line))
        .collect();
    let expected = [
        ("a.md#x", 1),
        ("img/b.png", 1),
        ("refs/c.md", 6),
        ("d.gif", 7),
    ];
    assert_eq!(
        found,
        expected
            .iter()
            .map(|(t, l)| (t.to_string(), *l))
            .collect::<Vec<_>>()
    );
}
