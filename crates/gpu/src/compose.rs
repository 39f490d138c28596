//! The WGSL preprocessor: WGSL has no includes and no conditional compilation, so a stage file
//! says what it needs in a few directives, each on a line of its own (vello's `vello_shaders`
//! preprocessor, cut down to what these shaders use):
//!
//! - `#import name`: the piece `name` (`shaders/shared/name.wgsl`, or a piece the host
//!   generates: [`crate::shaders`]), in place of the line. Pieces import pieces; each is included once per module,
//!   where it is first imported, so that a piece comes after the pieces it imports.
//! - `#ifdef name`, `#ifndef name`, `#else`, `#endif`: lines kept or dropped by whether the
//!   module is composed with the define `name` (a stage's permutation, [`crate::shaders`]).
//!
//! The composed module keeps, for each of its lines, the file and line it came from, so that
//! naga's errors (which number the composed lines) can name the line of the file to fix.

use std::borrow::Cow;

/// A piece as the lookup of [`compose`] returns it: its path (which the composed module's
/// headers, the origins of its lines and the errors name) and its text.
pub(crate) type Piece = (&'static str, Cow<'static, str>);

/// A composed module: the WGSL naga reads, and where each of its lines came from.
#[derive(Debug, Clone)]
pub(crate) struct Composed {
    /// The WGSL.
    pub source: String,
    /// For line k + 1 of `source`, (file, 1-based line) of the line it is; `None` for the lines
    /// the composer writes (a header naming each piece).
    origins: Vec<Option<(&'static str, usize)>>,
}

impl Composed {
    /// The file and line that 1-based line `line` of the module came from.
    pub fn locate(&self, line: usize) -> Option<(&'static str, usize)> {
        *self.origins.get(line.checked_sub(1)?)?
    }

    /// The files the module holds lines of, in the order they were first included.
    #[cfg(test)]
    pub fn files(&self) -> Vec<&'static str> {
        let mut files = Vec::new();
        for (file, _) in self.origins.iter().flatten() {
            if !files.contains(file) {
                files.push(*file);
            }
        }
        files
    }

    fn push(&mut self, line: &str, origin: Option<(&'static str, usize)>) {
        self.source.push_str(line);
        self.source.push('\n');
        self.origins.push(origin);
    }
}

/// Composes the module of the stage file at path `file` whose text is `text`, with
/// the defines `defines`; `piece(name)` looks up what `#import name` names. Errors name the
/// file and line of the directive at fault: an unknown import or directive, an import cycle,
/// an `#else` or `#endif` without its `#ifdef`, an `#ifdef` without its `#endif`.
pub(crate) fn compose(
    file: &'static str,
    text: &str,
    defines: &[&str],
    piece: &dyn Fn(&str) -> Option<Piece>,
) -> Result<Composed, String> {
    let mut composer = Composer {
        defines,
        piece,
        included: Vec::new(),
        importing: Vec::new(),
        out: Composed {
            source: String::new(),
            origins: Vec::new(),
        },
    };
    composer.add(file, text)?;
    Ok(composer.out)
}

struct Composer<'a> {
    defines: &'a [&'a str],
    piece: &'a dyn Fn(&str) -> Option<Piece>,
    /// The pieces included so far.
    included: Vec<String>,
    /// The pieces being included, innermost last: importing one of them again is a cycle.
    importing: Vec<String>,
    out: Composed,
}

/// An `#ifdef` or `#ifndef` open at some line of a file.
struct Open {
    line: usize,
    /// Whether its first branch is kept.
    holds: bool,
    /// Whether its `#else` was passed.
    otherwise: bool,
}

impl Open {
    fn keeps(&self) -> bool {
        self.holds != self.otherwise
    }
}

impl Composer<'_> {
    fn add(&mut self, file: &'static str, text: &str) -> Result<(), String> {
        let mut open: Vec<Open> = Vec::new();
        for (k, line) in text.lines().enumerate() {
            let at = |message: String| format!("{file}:{}: {message}", k + 1);
            let keeps = open.iter().all(Open::keeps);
            let Some((directive, argument)) = directive(line) else {
                if keeps {
                    self.out.push(line, Some((file, k + 1)));
                }
                continue;
            };
            let name = || match argument {
                "" => Err(at(format!("#{directive} needs a name"))),
                name => Ok(name),
            };
            let bare = || match argument {
                "" => Ok(()),
                _ => Err(at(format!("#{directive} takes no argument"))),
            };
            match directive {
                "import" => {
                    let name = name()?;
                    if keeps && let Some((file, text)) = self.enter(name).map_err(at)? {
                        self.add(file, &text)?;
                        self.leave();
                    }
                }
                "ifdef" | "ifndef" => {
                    let defined = self.defines.contains(&name()?);
                    open.push(Open {
                        line: k + 1,
                        holds: defined == (directive == "ifdef"),
                        otherwise: false,
                    });
                }
                "else" => {
                    bare()?;
                    match open.last_mut() {
                        Some(o) if !o.otherwise => o.otherwise = true,
                        Some(_) => return Err(at("a second #else".to_owned())),
                        None => return Err(at("#else without #ifdef".to_owned())),
                    }
                }
                "endif" => {
                    bare()?;
                    open.pop()
                        .ok_or_else(|| at("#endif without #ifdef".to_owned()))?;
                }
                other => return Err(at(format!("unknown directive #{other}"))),
            }
        }
        match open.last() {
            Some(o) => Err(format!("{file}:{}: #ifdef without #endif", o.line)),
            None => Ok(()),
        }
    }

    /// Starts including piece `name`: the piece, or `None` if it is included already.
    fn enter(&mut self, name: &str) -> Result<Option<Piece>, String> {
        if self.importing.iter().any(|n| n == name) {
            return Err(format!(
                "import cycle: {} → {name}",
                self.importing.join(" → ")
            ));
        }
        if self.included.iter().any(|n| n == name) {
            return Ok(None);
        }
        let (file, text) = (self.piece)(name).ok_or_else(|| format!("unknown import `{name}`"))?;
        self.out.push(&format!("// ---- {file} ----"), None);
        self.importing.push(name.to_owned());
        Ok(Some((file, text)))
    }

    /// Ends including the innermost piece.
    fn leave(&mut self) {
        if let Some(name) = self.importing.pop() {
            self.included.push(name);
        }
    }
}

/// `(directive, argument)` of a directive line (`#import name`), `None` for a line of WGSL.
fn directive(line: &str) -> Option<(&str, &str)> {
    let rest = line.trim_start().strip_prefix('#')?;
    let (directive, argument) = rest.split_once(char::is_whitespace).unwrap_or((rest, ""));
    Some((directive, argument.trim()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pieces `a` (importing nothing), `b` (importing `a`) and `c` (importing `b` and `a`).
    fn pieces(name: &str) -> Option<Piece> {
        let text = match name {
            "a" => "fn a() {}",
            "b" => "#import a\nfn b() { a(); }",
            "c" => "#import b\n#import a\nfn c() { b(); }",
            "loop" => "#import round",
            "round" => "#import loop",
            _ => return None,
        };
        let file = match name {
            "a" => "shared/a.wgsl",
            "b" => "shared/b.wgsl",
            "c" => "shared/c.wgsl",
            "loop" => "shared/loop.wgsl",
            _ => "shared/round.wgsl",
        };
        Some((file, Cow::Borrowed(text)))
    }

    fn composed(text: &str, defines: &[&str]) -> Result<String, String> {
        compose("stage.wgsl", text, defines, &pieces).map(|c| c.source)
    }

    /// The WGSL lines of a module, the headers left out.
    fn code(text: &str, defines: &[&str]) -> Vec<String> {
        composed(text, defines)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with("// ----"))
            .map(str::to_owned)
            .collect()
    }

    #[test]
    fn a_piece_imported_twice_is_included_once_before_its_importers() {
        let text = "// stage\n#import c\n#import a\nfn main() { c(); }";
        assert_eq!(
            code(text, &[]),
            [
                "// stage",
                "fn a() {}",
                "fn b() { a(); }",
                "fn c() { b(); }",
                "fn main() { c(); }"
            ]
        );
        let module = compose("stage.wgsl", text, &[], &pieces).unwrap();
        assert_eq!(
            module.files(),
            [
                "stage.wgsl",
                "shared/a.wgsl",
                "shared/b.wgsl",
                "shared/c.wgsl"
            ]
        );
        assert!(
            module
                .source
                .lines()
                .next()
                .is_some_and(|l| l == "// stage")
        );
    }

    #[test]
    fn each_line_is_located_in_its_file() {
        let module = compose("stage.wgsl", "#import b\nfn main() {}", &[], &pieces).unwrap();
        let lines: Vec<&str> = module.source.lines().collect();
        assert_eq!(
            lines,
            [
                "// ---- shared/b.wgsl ----",
                "// ---- shared/a.wgsl ----",
                "fn a() {}",
                "fn b() { a(); }",
                "fn main() {}"
            ]
        );
        let located: Vec<_> = (1..=lines.len() + 1).map(|l| module.locate(l)).collect();
        assert_eq!(
            located,
            [
                None,
                None,
                Some(("shared/a.wgsl", 1)),
                Some(("shared/b.wgsl", 2)),
                Some(("stage.wgsl", 2)),
                None
            ]
        );
        assert_eq!(module.locate(0), None);
    }

    #[test]
    fn an_unknown_import_is_an_error_naming_the_file_and_line() {
        assert_eq!(
            composed("fn main() {}\n#import nowhere", &[]),
            Err("stage.wgsl:2: unknown import `nowhere`".to_owned())
        );
        // In a piece, the piece's file and line.
        let nested = |name: &str| match name {
            "outer" => Some(("shared/outer.wgsl", Cow::Borrowed("\n\n#import inner"))),
            _ => None,
        };
        assert_eq!(
            compose("stage.wgsl", "#import outer", &[], &nested).map(|c| c.source),
            Err("shared/outer.wgsl:3: unknown import `inner`".to_owned())
        );
    }

    #[test]
    fn an_import_cycle_is_an_error() {
        let e = composed("#import loop", &[]).unwrap_err();
        assert_eq!(e, "shared/round.wgsl:1: import cycle: loop → round → loop");
    }

    #[test]
    fn defines_choose_the_branches_and_their_imports() {
        let text = "#ifdef fast\n#import a\nfn f() { a(); }\n#else\nfn f() {}\n#endif\n\
                    #ifndef fast\nfn slow() {}\n#endif";
        assert_eq!(code(text, &["fast"]), ["fn a() {}", "fn f() { a(); }"]);
        assert_eq!(code(text, &[]), ["fn f() {}", "fn slow() {}"]);
        // Nested: the inner branch counts only where the outer one is kept.
        let nested = "#ifdef x\n#ifdef y\nfn xy() {}\n#else\nfn x() {}\n#endif\n#endif";
        assert_eq!(code(nested, &["x", "y"]), ["fn xy() {}"]);
        assert_eq!(code(nested, &["x"]), ["fn x() {}"]);
        assert!(code(nested, &["y"]).is_empty());
        // An import in a dropped branch is not looked up.
        assert_eq!(
            code("#ifdef x\n#import nowhere\n#endif", &[]),
            Vec::<String>::new()
        );
    }

    #[test]
    fn unbalanced_or_unknown_directives_are_errors_naming_the_line() {
        let e = |text: &str| composed(text, &[]).unwrap_err();
        assert_eq!(
            e("fn f() {}\n#endif"),
            "stage.wgsl:2: #endif without #ifdef"
        );
        assert_eq!(e("#else"), "stage.wgsl:1: #else without #ifdef");
        assert_eq!(
            e("#ifdef x\n#else\n#else\n#endif"),
            "stage.wgsl:3: a second #else"
        );
        assert_eq!(
            e("\n#ifdef x\nfn f() {}"),
            "stage.wgsl:2: #ifdef without #endif"
        );
        assert_eq!(e("#include a"), "stage.wgsl:1: unknown directive #include");
        assert_eq!(e("#import"), "stage.wgsl:1: #import needs a name");
        assert_eq!(
            e("#ifdef x\n#endif x"),
            "stage.wgsl:2: #endif takes no argument"
        );
    }
}
