//! Scene errors that say where: file, line, column, key, and what is wrong.
//!
//! Validation works on plain structs and names the offending value by its key path
//! (`body[1].mass`); [`locate`] maps that path back to a span with a second, spanned parse of the
//! same text (`toml::de::DeTable`). Serde's own errors come the other way round, with a span and
//! no path, and [`key_at`] recovers the path. Both end up as one [`Diagnostic`].

use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};

use toml::de::{DeTable, DeValue};

/// One step of a key path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Seg {
    /// A table key.
    Key(String),
    /// An index into an array (or array of tables).
    Index(usize),
}

/// A key path such as `body[1].structural.stiffness`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct KeyPath(pub Vec<Seg>);

impl KeyPath {
    /// The empty path: the document itself.
    pub fn root() -> Self {
        Self(Vec::new())
    }
    /// This path extended by a key.
    pub fn key(&self, key: &str) -> Self {
        let mut p = self.clone();
        p.0.push(Seg::Key(key.to_owned()));
        p
    }
    /// This path extended by an index.
    pub fn index(&self, i: usize) -> Self {
        let mut p = self.clone();
        p.0.push(Seg::Index(i));
        p
    }
}

impl fmt::Display for KeyPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.is_empty() {
            return f.write_str("(document)");
        }
        for (i, seg) in self.0.iter().enumerate() {
            match seg {
                Seg::Key(k) if i == 0 => write!(f, "{k}")?,
                Seg::Key(k) => write!(f, ".{k}")?,
                Seg::Index(n) => write!(f, "[{n}]")?,
            }
        }
        Ok(())
    }
}

/// A number as messages write it: the shortest text that reads back to it, in exponent form
/// when it is very large or very small (`1e300`, not 301 digits; `2.5e-7`), else plainly
/// (`0.25`, `2000`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        if x == 0.0 || !x.is_finite() || (1e-5..1e16).contains(&x.abs()) {
            write!(f, "{x}")
        } else {
            write!(f, "{x:e}")
        }
    }
}

/// A located problem in a scene file.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostic {
    /// The scene file (or `<inline>` for text not read from a file).
    pub file: PathBuf,
    /// 1-based line, 0 when unknown.
    pub line: usize,
    /// 1-based column, 0 when unknown.
    pub column: usize,
    /// The key the problem is about.
    pub key: KeyPath,
    /// What is wrong, in words.
    pub message: String,
    /// The source line, for display.
    pub source_line: String,
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        write!(f, ": {}: {}", self.key, self.message)?;
        if !self.source_line.is_empty() {
            let n = self.line.to_string();
            let pad = " ".repeat(n.len());
            write!(
                f,
                "\n{pad} |\n{n} | {}\n{pad} | {}^",
                self.source_line,
                " ".repeat(self.column.saturating_sub(1))
            )?;
        }
        Ok(())
    }
}

/// Everything that can go wrong loading a scene.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file (or a file it names) could not be read.
    #[error("{}: cannot read: {cause}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why (in the message already, so not a `source`: error chains would repeat it).
        cause: std::io::Error,
    },
    /// The file was read but is not a valid scene.
    #[error("{0}")]
    Invalid(Box<Diagnostic>),
}

impl SceneError {
    /// The diagnostic, where the error has one.
    pub fn diagnostic(&self) -> Option<&Diagnostic> {
        match self {
            SceneError::Invalid(d) => Some(d),
            SceneError::Io { .. } => None,
        }
    }
}

/// An unlocated validation failure: a key path and a message (`key: message` when displayed).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct Invalid {
    /// Which value.
    pub key: KeyPath,
    /// What is wrong with it.
    pub message: String,
}

impl Invalid {
    /// A failure at `key`.
    pub fn new(key: KeyPath, message: impl Into<String>) -> Self {
        Self {
            key,
            message: message.into(),
        }
    }

    /// Locates this failure in `text` (the file's contents) and turns it into a [`SceneError`].
    pub fn locate(self, file: &Path, text: &str) -> SceneError {
        let span = locate(text, &self.key);
        diagnostic(file, text, span, self.key, self.message)
    }
}

/// Turns a serde/TOML error into a located [`SceneError`]; a file that is plainly something
/// else than TOML (a mesh, a run's frames) is named for what it is instead.
pub fn from_toml(file: &Path, text: &str, err: &toml::de::Error) -> SceneError {
    if let Some(what) = not_toml(file, text) {
        let see = "a scene is a TOML file (see docs/guide/scene-format.md)";
        return diagnostic(
            file,
            text,
            None,
            KeyPath::root(),
            format!(
                "{what}; {see}{}",
                match what {
                    OBJ => ", which takes a mesh as a `kind = \"mesh\"` body's or terrain's `file`",
                    _ => "",
                }
            ),
        );
    }
    let key = err
        .span()
        .map(|s| key_at(text, s.start))
        .unwrap_or_default();
    diagnostic(file, text, err.span(), key, plain(err.message().trim()))
}

/// A serde message in the scene file's terms: `expected f64` is Rust's name for a number.
fn plain(message: &str) -> String {
    const TERMS: [(&str, &str); 12] = [
        ("expected f64", "expected a number"),
        ("expected f32", "expected a number"),
        ("expected u8", "expected a whole number"),
        ("expected u16", "expected a whole number"),
        ("expected u32", "expected a whole number"),
        ("expected u64", "expected a whole number"),
        ("expected usize", "expected a whole number"),
        ("expected i32", "expected a whole number"),
        ("expected i64", "expected a whole number"),
        ("expected a sequence", "expected a list"),
        ("expected a map", "expected a table"),
        ("expected a boolean", "expected true or false"),
    ];
    let mut out = message.to_owned();
    for (rust, words) in TERMS {
        out = out.replace(rust, words);
    }
    out
}

const OBJ: &str = "this looks like an OBJ file (a mesh)";

/// What the text that did not parse as TOML looks like, when it is plainly another format: an
/// OBJ file (`.obj`, or its first statement an OBJ one) or JSON (a run's frames).
fn not_toml(file: &Path, text: &str) -> Option<&'static str> {
    let first = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))?;
    let word = first.split_whitespace().next().unwrap_or_default();
    // `v = 1` is a TOML key, broken further on.
    let obj_statement = ["v", "vt", "vn", "f", "o", "g", "s", "mtllib", "usemtl"].contains(&word)
        && !first.contains('=');
    if file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"))
        || obj_statement
    {
        Some(OBJ)
    } else if first.starts_with('{') {
        Some("this looks like JSON (a run's frames, JSON Lines)")
    } else {
        None
    }
}

fn diagnostic(
    file: &Path,
    text: &str,
    span: Option<Range<usize>>,
    key: KeyPath,
    message: String,
) -> SceneError {
    let (line, column, source_line) = match span {
        Some(s) => line_col(text, s.start),
        None => (0, 0, String::new()),
    };
    SceneError::Invalid(Box::new(Diagnostic {
        file: file.to_owned(),
        line,
        column,
        key,
        message,
        source_line,
    }))
}

/// 1-based line and column (in characters) of a byte offset, and that line's text.
fn line_col(text: &str, offset: usize) -> (usize, usize, String) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = text[start..offset].chars().count() + 1;
    let end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    (
        line,
        column,
        text[start..end].trim_end_matches('\r').to_owned(),
    )
}

/// The span of the value at `key`, or of the deepest existing table on its way (a missing key is
/// reported where it should have been).
pub fn locate(text: &str, key: &KeyPath) -> Option<Range<usize>> {
    let doc = DeTable::parse(text).ok()?;
    let mut span = doc.span();
    let mut node: Option<&DeValue<'_>> = None;
    let table = doc.get_ref();
    for (depth, seg) in key.0.iter().enumerate() {
        let next = match (depth, seg, node) {
            (0, Seg::Key(k), _) => table.get(k.as_str()),
            (_, Seg::Key(k), Some(DeValue::Table(t))) => t.get(k.as_str()),
            (_, Seg::Index(i), Some(DeValue::Array(a))) => a.get(*i),
            _ => None,
        };
        match next {
            Some(v) => {
                span = v.span();
                node = Some(v.get_ref());
            }
            None => break,
        }
    }
    Some(span)
}

/// The key path of the deepest value or key whose span holds `offset`. Parses what it can of
/// a broken file, so syntax errors get a key too.
pub fn key_at(text: &str, offset: usize) -> KeyPath {
    let (doc, _) = DeTable::parse_recoverable(text);
    let mut path = Vec::new();
    for (k, v) in doc.get_ref().iter() {
        path.push(Seg::Key(k.get_ref().to_string()));
        if k.span().contains(&offset) || path_to(v, offset, &mut path) {
            return KeyPath(path);
        }
        path.pop();
    }
    KeyPath(path)
}

/// Extends `path` to the deepest node under `node` that holds `offset`. A table written with
/// a `[header]` spans only its header line, so children are searched whatever the parent's
/// span.
fn path_to(node: &toml::Spanned<DeValue<'_>>, offset: usize, path: &mut Vec<Seg>) -> bool {
    match node.get_ref() {
        DeValue::Table(t) => {
            for (k, v) in t.iter() {
                path.push(Seg::Key(k.get_ref().to_string()));
                if k.span().contains(&offset) || path_to(v, offset, path) {
                    return true;
                }
                path.pop();
            }
        }
        DeValue::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                path.push(Seg::Index(i));
                if path_to(v, offset, path) {
                    return true;
                }
                path.pop();
            }
        }
        _ => {}
    }
    node.span().contains(&offset)
}

#[cfg(test)]
mod tests {
    use crate::Scene;

    fn message(text: &str, name: &str) -> String {
        let e = Scene::from_toml(text, name.as_ref()).unwrap_err();
        e.diagnostic().unwrap().message.clone()
    }

    /// A mesh or a run's frames given where a scene goes are named for what they are.
    #[test]
    fn an_obj_or_a_frames_file_given_as_a_scene_is_named() {
        let obj = "# Blender 4.1\nmtllib torus.mtl\no Torus\nv 0.28 0.0 0.0\nv 0.27 0.03 0.0\n";
        let said = "this looks like an OBJ file (a mesh); a scene is a TOML file (see \
                    docs/guide/scene-format.md), which takes a mesh as a `kind = \"mesh\"` \
                    body's or terrain's `file`";
        assert_eq!(message(obj, "torus.obj"), said);
        assert_eq!(
            message("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "scene.toml"),
            said
        );
        let jsonl = "{\"format\":\"softbody-frames\",\"version\":1}\n{\"frame\":0}\n";
        assert_eq!(
            message(jsonl, "out/jelly.jsonl"),
            "this looks like JSON (a run's frames, JSON Lines); a scene is a TOML file (see \
             docs/guide/scene-format.md)"
        );
        // A broken TOML file is reported as such.
        let broken = message("[simulation\n", "s.toml");
        assert!(!broken.contains("looks like"), "{broken}");
    }
}
