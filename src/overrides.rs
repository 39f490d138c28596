//! Values given beside a scene file that replace its own, by one path: [`Setting`]s replace
//! any value of the scene *file*, by its key path, in the parsed TOML document before the scene
//! is built from it. The CLI's `--set KEY=VALUE`, its [`Overrides`] (`--integrator`, `--dt`,
//! `--duration`, `--fps`, which become settings of `[simulation]`), a sweep's parameters and
//! the Python package's keywords all go this way. Settings therefore go through the file's own
//! parsing and validation: a value of the wrong type, an unknown key or a refused number is
//! reported exactly as it would be in the file, and the message says which setting it came
//! from (`--set …`, `--dt …`), or, for a fault in the file's own values, points at their line
//! and lists the settings applied.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use softbody_scene::error::Seg;
use softbody_scene::{Diagnostic, Integrator, Invalid, KeyPath, Scene, SceneError};

/// Replacements for a scene's `[simulation]` values (the CLI's `--integrator`, `--dt`,
/// `--duration`, `--fps`); `None` keeps the scene's. They apply as [`Setting`]s
/// ([`Overrides::to_settings`]), so a bad combination is refused as the file's own values are,
/// naming the flag:
///
/// ```
/// use softbody::{Integrator, Overrides};
/// let path = "scenes/jelly-on-ground.toml".as_ref();
/// let overrides = Overrides { integrator: Some(Integrator::Rk4), dt: Some(1e-4), ..Overrides::default() };
/// let scene = softbody::load_scene(path, &overrides.to_settings())?;
/// assert_eq!(scene.simulation.integrator, Integrator::Rk4);
///
/// // 30 frames/s cannot be taken with one step per second.
/// let slow = Overrides { dt: Some(1.0), ..Overrides::default() };
/// let e = softbody::load_scene(path, &slow.to_settings()).unwrap_err();
/// assert!(e.to_string().contains("simulation.frame_rate"));
/// assert!(e.to_string().contains("(at most 1) (with --dt 1)"), "{e}");
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Overrides {
    /// The time integrator.
    pub integrator: Option<Integrator>,
    /// The time step, seconds.
    pub dt: Option<f64>,
    /// The simulated time, seconds.
    pub duration: Option<f64>,
    /// Frames per simulated second.
    pub frame_rate: Option<f64>,
}

impl Overrides {
    /// Whether nothing is overridden.
    pub fn is_empty(&self) -> bool {
        *self == Overrides::default()
    }

    /// The overrides as a file-name part: `rk4-dt0.0001-2s-60fps` (empty when there are none).
    /// Default output names carry it, so that a run with other settings does not replace the
    /// scene's own run's frames.
    pub fn label(&self) -> String {
        let parts = [
            self.integrator.map(|i| i.to_string()),
            self.dt.map(|x| format!("dt{x}")),
            self.duration.map(|x| format!("{x}s")),
            self.frame_rate.map(|x| format!("{x}fps")),
        ];
        parts.into_iter().flatten().collect::<Vec<_>>().join("-")
    }
}

impl Overrides {
    /// The overrides as [`Setting`]s of the scene file's `[simulation]` keys: applied to the
    /// file's text by [`scene_text`], they give the text of the scene that runs.
    pub fn to_settings(&self) -> Vec<Setting> {
        let pairs = [
            (
                "integrator",
                "--integrator",
                self.integrator
                    .map(|i| toml::Value::String(i.name().to_owned())),
            ),
            ("dt", "--dt", self.dt.map(toml::Value::Float)),
            (
                "duration",
                "--duration",
                self.duration.map(toml::Value::Float),
            ),
            (
                "frame_rate",
                "--fps",
                self.frame_rate.map(toml::Value::Float),
            ),
        ];
        pairs
            .into_iter()
            .filter_map(|(key, flag, value)| {
                let key = KeyPath::root().key("simulation").key(key);
                value.map(|value| Setting::at(key, value).from_flag(flag))
            })
            .collect()
    }
}

/// One value of a scene file replaced by its key path: the CLI's `--set KEY=VALUE`
/// (`body[0].structural.stiffness=5000`, `terrain[0].friction=0.8`,
/// `simulation.integrator=rk4`), a sweep's parameter, a keyword of the Python package.
///
/// The key is a TOML key path: keys joined by `.`, `[i]` indexing an array or an array of
/// tables (`body[1]`, `simulation.gravity[1]`). The value is a TOML value (`5000`, `0.8`,
/// `[0.0, -1.62, 0.0]`, `{ stiffness = 1e4, damping = 10.0 }`, `"rk4"`); text that is not one
/// is taken as a string, so `simulation.integrator=rk4` needs no quotes. A setting replaces the
/// value at its key or adds the key (and the tables on its way) where it is missing; an index
/// must name an existing entry.
///
/// ```
/// use softbody::Setting;
/// let stiff: Setting = "body[0].structural.stiffness=5000".parse()?;
/// let scene = softbody::load_scene("scenes/jelly-on-ground.toml".as_ref(), &[stiff])?;
/// let softbody::scene::BodyShape::Cuboid(cube) = &scene.bodies[0].shape else { panic!() };
/// assert_eq!(cube.structural.unwrap().stiffness, 5000.0);
///
/// // Refused like the file's own value, naming the --set it came from.
/// let heavy: Setting = "body[0].mass=-2".parse()?;
/// let e = softbody::load_scene("scenes/jelly-on-ground.toml".as_ref(), &[heavy]).unwrap_err();
/// assert_eq!(
///     e.to_string(),
///     "scenes/jelly-on-ground.toml: body[0].mass: must be greater than zero, not -2 \
///      (from --set body[0].mass=-2)"
/// );
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    key: KeyPath,
    value: toml::Value,
    /// Where it came from, for messages.
    origin: Origin,
}

/// Where a setting came from: a `--set`, a flag of its own, or an entry of a table (a sweep
/// file's `set`, Python's `set=`).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Origin {
    Set,
    Flag(&'static str),
    Entry(&'static str),
}

impl Setting {
    /// The setting of `key` (a key path such as `body[0].mass`) to `value`.
    pub fn new(key: &str, value: toml::Value) -> Result<Setting, String> {
        Ok(Setting::at(parse_key(key)?, value))
    }

    /// The setting of a parsed key path.
    pub fn at(key: KeyPath, value: toml::Value) -> Setting {
        Setting {
            key,
            value,
            origin: Origin::Set,
        }
    }

    /// The setting as the flag `flag` gave it (`--dt 0.001` for `simulation.dt`): messages
    /// name the flag instead of a `--set`.
    pub fn from_flag(mut self, flag: &'static str) -> Setting {
        self.origin = Origin::Flag(flag);
        self
    }

    /// The setting as an entry of the table `table` gave it (`set` of a sweep file or of a
    /// Python call): messages say `set: body[0].mass = 2` instead of a `--set`.
    pub fn from_entry(mut self, table: &'static str) -> Setting {
        self.origin = Origin::Entry(table);
        self
    }

    /// Where it came from, as messages say it: `--set body[0].mass=2`, `--dt 0.001`, or
    /// `set: body[0].mass = 2`.
    pub fn origin(&self) -> String {
        match self.origin {
            Origin::Flag(flag) => match &self.value {
                toml::Value::String(s) => format!("{flag} {s}"),
                toml::Value::Float(x) => format!("{flag} {x}"),
                v => format!("{flag} {v}"),
            },
            Origin::Set => format!("--set {self}"),
            Origin::Entry(table) => format!("{table}: {} = {}", self.key, self.value),
        }
    }

    /// The key path it sets.
    pub fn key(&self) -> &KeyPath {
        &self.key
    }

    /// The value it sets.
    pub fn value(&self) -> &toml::Value {
        &self.value
    }

    /// The setting as a file-name part: `body0.structural.stiffness5000` (characters other
    /// than letters, digits, `.`, `_` and `-` dropped), for default output names.
    pub fn label(&self) -> String {
        let value = match &self.value {
            toml::Value::String(s) => s.clone(),
            v => v.to_string(),
        };
        format!("{}{value}", self.key)
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
            .collect()
    }
}

/// `KEY=VALUE`, as `--set` takes it: the value as TOML, or as a string where it is not TOML.
impl FromStr for Setting {
    type Err = String;
    fn from_str(s: &str) -> Result<Setting, String> {
        let Some((key, value)) = s.split_once('=') else {
            return Err(format!(
                "`{s}` is not KEY=VALUE (e.g. body[0].structural.stiffness=5000)"
            ));
        };
        // Parsed as `v = VALUE`, a second line would be another key, dropped with the table.
        if value.contains(['\n', '\r']) {
            return Err(format!(
                "the value of `{}` holds a line break: a value is one line of TOML",
                key.trim()
            ));
        }
        let value = value.trim();
        let value = format!("v = {value}")
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| toml::Value::String(value.to_owned()));
        Setting::new(key.trim(), value)
    }
}

/// `KEY=VALUE`, the value written as TOML (what `--set` would take back).
impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}={}", self.key, self.value)
    }
}

/// A key path as settings write it: `simulation.dt`, `body[0].structural.stiffness`,
/// `simulation.gravity[1]`.
fn parse_key(text: &str) -> Result<KeyPath, String> {
    let bad = |why: &str| {
        Err(format!(
            "`{text}` is not a key path ({why}), e.g. body[0].mass"
        ))
    };
    let mut path = KeyPath::root();
    if text.is_empty() {
        return bad("it is empty");
    }
    for part in text.split('.') {
        let (name, mut rest) = part.split_at(part.find('[').unwrap_or(part.len()));
        let bare = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == '-';
        if name.is_empty() || !name.chars().all(bare) {
            return bad("keys are letters, digits, `_` and `-`, joined by `.`");
        }
        path = path.key(name);
        while !rest.is_empty() {
            let Some((index, after)) = rest
                .strip_prefix('[')
                .and_then(|r| r.split_once(']'))
                .and_then(|(i, after)| Some((i.trim().parse::<usize>().ok()?, after)))
            else {
                return bad("an index is a whole number in brackets, as in body[0]");
            };
            path = path.index(index);
            rest = after;
        }
    }
    Ok(path)
}

/// Loads a scene file with `settings` applied to its values (in order; a later one wins).
/// Without settings this is [`Scene::from_file`].
pub fn load_scene(path: &Path, settings: &[Setting]) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|cause| SceneError::Io {
        path: path.to_owned(),
        cause,
    })?;
    scene_from_toml(&text, path, settings)
}

/// Parses scene text with `settings` applied; `origin` names it in messages and anchors mesh
/// paths, as for [`Scene::from_toml`].
pub fn scene_from_toml(
    text: &str,
    origin: &Path,
    settings: &[Setting],
) -> Result<Scene, SceneError> {
    parse_with(text, origin, settings).map(|(scene, _)| scene)
}

/// The scene of `text` with `settings` applied, and the text of it ([`scene_text`]): edited
/// once, parsed once.
pub(crate) fn parse_with(
    text: &str,
    origin: &Path,
    settings: &[Setting],
) -> Result<(Scene, String), SceneError> {
    if settings.is_empty() {
        return Ok((Scene::from_toml(text, origin)?, text.to_owned()));
    }
    let edited = scene_text(text, origin, settings)?;
    let scene =
        Scene::from_toml(&edited, origin).map_err(|e| attribute(e, text, origin, settings))?;
    Ok((scene, edited))
}

/// The scene text with `settings` applied: the TOML document re-written with their values
/// (comments and layout are not kept). Frame files hold it, so that they describe the scene
/// that ran. A path that cannot be set (an index past the end, a key under a number) is an
/// error naming the setting; the values themselves are checked when the text is loaded.
pub fn scene_text(text: &str, origin: &Path, settings: &[Setting]) -> Result<String, SceneError> {
    if settings.is_empty() {
        return Ok(text.to_owned());
    }
    // A file that does not parse is reported as the file would be, without the settings.
    let mut doc: toml::Table = match text.parse() {
        Ok(doc) => doc,
        Err(_) => {
            return Err(Scene::from_toml(text, origin).err().unwrap_or_else(|| {
                unlocated(
                    origin,
                    KeyPath::root(),
                    "the scene is not a TOML table".into(),
                )
            }));
        }
    };
    for setting in settings {
        set(&mut doc, setting).map_err(|message| {
            unlocated(
                origin,
                setting.key.clone(),
                format!("{message} (from {})", setting.origin()),
            )
        })?;
    }
    toml::to_string(&doc).map_err(|e| {
        unlocated(
            origin,
            KeyPath::root(),
            format!("cannot write the scene with the settings: {e}"),
        )
    })
}

/// An error about a value that is not in the file (it came from a setting): no line to show.
fn unlocated(file: &Path, key: KeyPath, message: String) -> SceneError {
    SceneError::Invalid(Box::new(Diagnostic {
        file: file.to_owned(),
        line: 0,
        column: 0,
        key,
        message,
        source_line: String::new(),
    }))
}

/// Puts the setting's value at its key path in `doc`, making the tables on its way.
fn set(doc: &mut toml::Table, setting: &Setting) -> Result<(), String> {
    let segments = &setting.key.0;
    let mut node = DocNode::Table(doc);
    for (depth, seg) in segments.iter().enumerate() {
        let last = depth + 1 == segments.len();
        let here = KeyPath(segments[..depth].to_vec());
        node = match (node, seg) {
            (DocNode::Table(t), Seg::Key(k)) if last => {
                t.insert(k.clone(), setting.value.clone());
                return Ok(());
            }
            (DocNode::Table(t), Seg::Key(k)) => {
                let child = match (t.contains_key(k), &segments[depth + 1]) {
                    (true, _) => t.get_mut(k).expect("present"),
                    (false, Seg::Key(_)) => t
                        .entry(k.clone())
                        .or_insert(toml::Value::Table(toml::Table::new())),
                    // An array the file does not have is its default, which the document
                    // does not hold: an entry of it cannot be changed alone.
                    (false, Seg::Index(_)) => {
                        let at = here.key(k);
                        return Err(format!(
                            "{at} is not in the file (its default applies): set it whole, \
                             as in {at}=[...]"
                        ));
                    }
                };
                DocNode::of(child)
            }
            (DocNode::Array(a), Seg::Index(i)) => {
                let len = a.len();
                let Some(child) = a.get_mut(*i) else {
                    let at = here.to_string();
                    return Err(match len {
                        0 => {
                            format!("{at} has no entries; --set changes entries, it cannot add one")
                        }
                        n => format!(
                            "{at} has {n} entries ({at}[0] to {at}[{}]); --set changes entries, \
                             it cannot add one",
                            n - 1
                        ),
                    });
                };
                if last {
                    *child = setting.value.clone();
                    return Ok(());
                }
                DocNode::of(child)
            }
            (DocNode::Table(_), Seg::Index(_)) => {
                return Err(format!(
                    "{here} is a table, not an array: it takes a key, not an index"
                ));
            }
            (DocNode::Array(_), Seg::Key(_)) => {
                return Err(format!(
                    "{here} is an array: it takes an index such as {here}[0]"
                ));
            }
            (DocNode::Other(kind), _) => {
                return Err(format!("{here} is {kind}: nothing can be set inside it"));
            }
        };
    }
    Ok(())
}

/// Where a setting's walk through the document is.
enum DocNode<'a> {
    Table(&'a mut toml::Table),
    Array(&'a mut Vec<toml::Value>),
    /// A value that holds nothing: its kind, for the message.
    Other(&'static str),
}

impl<'a> DocNode<'a> {
    fn of(value: &'a mut toml::Value) -> DocNode<'a> {
        match value {
            toml::Value::Table(t) => DocNode::Table(t),
            toml::Value::Array(a) => DocNode::Array(a),
            toml::Value::String(_) => DocNode::Other("a string"),
            toml::Value::Integer(_) => DocNode::Other("an integer"),
            toml::Value::Float(_) => DocNode::Other("a float"),
            toml::Value::Boolean(_) => DocNode::Other("a boolean"),
            toml::Value::Datetime(_) => DocNode::Other("a date"),
        }
    }
}

/// The error of the scene with settings applied, said as the user knows the scene: a fault in
/// a value a setting gave (at or under its key, or in a table it made) names that setting;
/// any other is located in the original file, listing the settings applied.
fn attribute(error: SceneError, text: &str, origin: &Path, settings: &[Setting]) -> SceneError {
    let SceneError::Invalid(d) = error else {
        return error;
    };
    let original: Option<toml::Table> = text.parse().ok();
    let in_file = |key: &KeyPath| original.as_ref().is_some_and(|doc| lookup(doc, key));
    let starts_with = |a: &KeyPath, b: &KeyPath| a.0.starts_with(&b.0);
    let from = settings
        .iter()
        .rev()
        .find(|s| starts_with(&d.key, &s.key) || (starts_with(&s.key, &d.key) && !in_file(&d.key)));
    match from {
        Some(s) => unlocated(
            origin,
            d.key,
            format!("{} (from {})", d.message, s.origin()),
        ),
        None => {
            let list: Vec<String> = settings.iter().map(Setting::origin).collect();
            let message = format!("{} (with {})", d.message, list.join(", "));
            Invalid::new(d.key, message).locate(origin, text)
        }
    }
}

/// Whether `doc` holds a value at `key`.
fn lookup(doc: &toml::Table, key: &KeyPath) -> bool {
    let mut node: Option<&toml::Value> = None;
    for (depth, seg) in key.0.iter().enumerate() {
        let next = match (depth, seg, node) {
            (0, Seg::Key(k), _) => doc.get(k),
            (_, Seg::Key(k), Some(toml::Value::Table(t))) => t.get(k),
            (_, Seg::Index(i), Some(toml::Value::Array(a))) => a.get(*i),
            _ => None,
        };
        match next {
            Some(v) => node = Some(v),
            None => return false,
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_label_names_each_override() {
        assert_eq!(Overrides::default().label(), "");
        let all = Overrides {
            integrator: Some(Integrator::Rk4),
            dt: Some(1e-4),
            duration: Some(2.0),
            frame_rate: Some(60.0),
        };
        assert_eq!(all.label(), "rk4-dt0.0001-2s-60fps");
        let dt = Overrides {
            dt: Some(1.0 / 60.0),
            ..Overrides::default()
        };
        assert_eq!(dt.label(), "dt0.016666666666666666");
    }

    const TEXT: &str = "[simulation]\ndt = 0.001\nduration = 0.1\nframe_rate = 100.0\n\
                        [[body]]\nkind = \"particles\"\npositions = [[0.0, 1.0, 0.0]]\nmasses = [1.0]\n";

    fn scene_with(o: &Overrides, origin: &str) -> Result<Scene, SceneError> {
        scene_from_toml(TEXT, Path::new(origin), &o.to_settings())
    }

    #[test]
    fn nothing_overridden_keeps_the_scene() {
        let before = Scene::from_toml(TEXT, Path::new("s.toml")).unwrap();
        assert!(Overrides::default().is_empty());
        assert!(Overrides::default().to_settings().is_empty());
        let after = scene_with(&Overrides::default(), "s.toml").unwrap();
        assert_eq!(after.simulation, before.simulation);
    }

    #[test]
    fn every_override_replaces_its_setting() {
        let o = Overrides {
            integrator: Some(Integrator::Midpoint),
            dt: Some(0.002),
            duration: Some(0.5),
            frame_rate: Some(25.0),
        };
        assert!(!o.is_empty());
        let sim = scene_with(&o, "s.toml").unwrap().simulation;
        assert_eq!(sim.integrator, Integrator::Midpoint);
        assert_eq!((sim.dt, sim.duration, sim.frame_rate), (0.002, 0.5, 25.0));
    }

    /// The frame rate an override makes impossible is named with the flag that set it, and a
    /// fault in the file's own value lists the flags applied.
    #[test]
    fn a_bad_combination_names_the_file_the_key_and_the_flags() {
        let o = Overrides {
            integrator: Some(Integrator::Rk4),
            frame_rate: Some(5000.0),
            ..Overrides::default()
        };
        let text = scene_with(&o, "dir/s.toml").unwrap_err().to_string();
        assert!(
            text.starts_with("dir/s.toml: simulation.frame_rate: "),
            "{text}"
        );
        assert!(text.contains("more than one frame per step"), "{text}");
        assert!(text.ends_with("(from --fps 5000)"), "{text}");
        let slow = Overrides {
            dt: Some(1.0),
            integrator: Some(Integrator::Rk4),
            ..Overrides::default()
        };
        let text = scene_with(&slow, "s.toml").unwrap_err().to_string();
        // The file's own frame rate, on its line 4: 100 frames/s need dt ≤ 0.01 s.
        assert!(
            text.starts_with("s.toml:4:14: simulation.frame_rate: "),
            "{text}"
        );
        // The located message shows the file's line after it.
        assert!(
            text.contains("(at most 1) (with --integrator rk4, --dt 1)\n"),
            "{text}"
        );
        let negative = Overrides {
            duration: Some(-1.0),
            ..Overrides::default()
        };
        let text = scene_with(&negative, "s.toml").unwrap_err().to_string();
        assert!(text.contains("simulation.duration"), "{text}");
        assert!(text.ends_with("(from --duration -1)"), "{text}");
    }
}

#[cfg(test)]
mod setting_tests {
    use super::*;
    use softbody_scene::BodyShape;

    const SCENE: &str = "\
[simulation]
dt = 0.001
duration = 0.1
frame_rate = 100.0

[[body]]
name = \"cube\"
kind = \"cuboid\"
size = [1.0, 1.0, 1.0]
resolution = [3, 3, 3]
mass = 2.0
structural = { stiffness = 100.0 }

[[terrain]]
kind = \"plane\"
normal = [0.0, 1.0, 0.0]
friction = 0.3
";

    fn load(settings: &[&str]) -> Result<Scene, SceneError> {
        let settings: Vec<Setting> = settings.iter().map(|s| s.parse().unwrap()).collect();
        scene_from_toml(SCENE, Path::new("s.toml"), &settings)
    }

    fn cube(scene: &Scene) -> &softbody_scene::Cuboid {
        match &scene.bodies[0].shape {
            BodyShape::Cuboid(c) => c,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn keys_parse_into_paths_and_values_into_toml() {
        let s: Setting = "body[0].structural.stiffness=5000".parse().unwrap();
        assert_eq!(s.key().to_string(), "body[0].structural.stiffness");
        assert_eq!(*s.value(), toml::Value::Integer(5000));
        assert_eq!(s.to_string(), "body[0].structural.stiffness=5000");
        assert_eq!(s.label(), "body0.structural.stiffness5000");
        let s: Setting = "simulation.integrator=rk4".parse().unwrap();
        assert_eq!(*s.value(), toml::Value::String("rk4".into()));
        assert_eq!(s.to_string(), "simulation.integrator=\"rk4\"");
        let s: Setting = " simulation.gravity = [0, -1.62, 0] ".parse().unwrap();
        assert_eq!(s.value().as_array().unwrap().len(), 3);
        let s: Setting = "simulation.gravity[1]=-1.62".parse().unwrap();
        assert_eq!(s.key().0.len(), 3);
        for bad in [
            "mass",
            "=1",
            "body[x].mass=1",
            "body[0.mass=1",
            "a..b=1",
            "a b=1",
        ] {
            let e = bad.parse::<Setting>().unwrap_err();
            assert!(e.contains("is not"), "{bad}: {e}");
        }
    }

    /// A value is one line: text after a line break would be dropped or taken for more keys.
    #[test]
    fn a_value_with_a_line_break_is_refused() {
        for (bad, key) in [
            ("body[0].mass=2\n3", "body[0].mass"),
            ("body[0].mass=2\nsize = [1, 1, 1]", "body[0].mass"),
            ("a=1\r\n", "a"),
        ] {
            assert_eq!(
                bad.parse::<Setting>(),
                Err(format!(
                    "the value of `{key}` holds a line break: a value is one line of TOML"
                )),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn settings_replace_values_add_keys_and_tables() {
        let scene = load(&[
            "body[0].structural.stiffness=5000",
            "body[0].bending={ stiffness = 7.5, damping = 0.5 }",
            "terrain[0].friction=0.8",
            "simulation.integrator=rk4",
            "simulation.gravity=[0.0, -9.81, 0.0]",
            "simulation.gravity[1]=-1.62",
            "simulation.drag=0.25",
        ])
        .unwrap();
        let c = cube(&scene);
        assert_eq!(c.structural.unwrap().stiffness, 5000.0);
        assert_eq!(c.bending.unwrap().stiffness, 7.5);
        assert_eq!(c.bending.unwrap().damping, 0.5);
        assert_eq!(scene.terrain[0].friction, 0.8);
        assert_eq!(scene.simulation.integrator, Integrator::Rk4);
        assert_eq!(scene.simulation.gravity.y, -1.62);
        assert_eq!(scene.simulation.drag, 0.25);
        // Everything else as in the file.
        let plain = Scene::from_toml(SCENE, Path::new("s.toml")).unwrap();
        assert_eq!(scene.simulation.dt, plain.simulation.dt);
        assert_eq!(cube(&scene).mass, cube(&plain).mass);
        // A later setting of the same key wins.
        let scene = load(&["body[0].mass=3", "body[0].mass=4.5"]).unwrap();
        assert_eq!(cube(&scene).mass, 4.5);
    }

    #[test]
    fn a_bad_value_is_refused_as_the_file_would_refuse_it_naming_the_setting() {
        let e = load(&["body[0].mass=-2"]).unwrap_err().to_string();
        assert_eq!(
            e,
            "s.toml: body[0].mass: must be greater than zero, not -2 (from --set body[0].mass=-2)"
        );
        // A type error from the parser, and an unknown key, likewise.
        let e = load(&["terrain[0].friction=high"]).unwrap_err();
        let d = e.diagnostic().unwrap();
        assert_eq!(d.key.to_string(), "terrain[0].friction");
        assert_eq!(d.line, 0, "not in the file: no line");
        assert!(d.message.contains("invalid type: string \"high\""), "{e}");
        assert!(
            d.message
                .ends_with("(from --set terrain[0].friction=\"high\")"),
            "{e}"
        );
        let e = load(&["simulation.frobnicate=1"]).unwrap_err();
        let d = e.diagnostic().unwrap();
        assert_eq!(d.key.to_string(), "simulation.frobnicate");
        assert!(d.message.contains("unknown field `frobnicate`"), "{e}");
        assert!(
            d.message.ends_with("(from --set simulation.frobnicate=1)"),
            "{e}"
        );
        // A table a setting made, refused for its kind of body, names that setting too.
        let e = load(&["body[0].positions=[[0.0, 0.0, 0.0]]"]).unwrap_err();
        assert!(
            e.to_string().contains("(from --set body[0].positions="),
            "{e}"
        );
    }

    #[test]
    fn a_fault_of_the_file_is_located_in_the_file_listing_the_settings() {
        // dt = 0.05 leaves frame_rate = 100 (in the file, line 4) with more than one frame
        // per step.
        let e = load(&["simulation.dt=0.05", "terrain[0].friction=0.5"]).unwrap_err();
        let d = e.diagnostic().unwrap();
        assert_eq!(d.key.to_string(), "simulation.frame_rate");
        assert_eq!((d.line, d.column), (4, 14));
        assert_eq!(d.source_line, "frame_rate = 100.0");
        assert!(
            d.message
                .ends_with("(with --set simulation.dt=0.05, --set terrain[0].friction=0.5)"),
            "{e}"
        );
    }

    #[test]
    fn a_path_that_cannot_be_set_names_the_setting() {
        let e = load(&["body[1].mass=1"]).unwrap_err().to_string();
        assert_eq!(
            e,
            "s.toml: body[1].mass: body has 1 entries (body[0] to body[0]); --set changes \
             entries, it cannot add one (from --set body[1].mass=1)"
        );
        let e = load(&["simulation.dt.x=1"]).unwrap_err().to_string();
        assert!(
            e.contains("simulation.dt is a float: nothing can be set inside it"),
            "{e}"
        );
        let e = load(&["simulation[0]=1"]).unwrap_err().to_string();
        assert!(e.contains("simulation is a table, not an array"), "{e}");
        let e = load(&["simulation.gravity[1]=-1.62"])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(
                "simulation.gravity is not in the file (its default applies): set it whole, as \
                 in simulation.gravity=[...]"
            ),
            "{e}"
        );
        let e = load(&["body.mass=1"]).unwrap_err().to_string();
        assert!(e.contains("body is an array: it takes an index"), "{e}");
    }

    #[test]
    fn the_scene_text_with_settings_and_overrides_loads_as_the_same_scene() {
        let settings: Vec<Setting> = ["body[0].mass=3.25", "terrain[0].friction=0.7"]
            .iter()
            .map(|s| s.parse().unwrap())
            .collect();
        let overrides = Overrides {
            integrator: Some(Integrator::Midpoint),
            dt: Some(1.0 / 3000.0),
            ..Overrides::default()
        };
        let all: Vec<Setting> = settings
            .into_iter()
            .chain(overrides.to_settings())
            .collect();
        let (scene, text) = parse_with(SCENE, Path::new("s.toml"), &all).unwrap();
        assert_eq!(text, scene_text(SCENE, Path::new("s.toml"), &all).unwrap());
        assert_eq!(scene.simulation.integrator, Integrator::Midpoint);
        let again = Scene::from_toml(&text, Path::new("s.toml")).unwrap();
        assert_eq!(again, scene, "{text}");
        assert_eq!(again.simulation.dt.to_bits(), (1.0f64 / 3000.0).to_bits());
        // Without settings the text is the file's, comments and all.
        assert_eq!(scene_text(SCENE, Path::new("s.toml"), &[]).unwrap(), SCENE);
    }

    #[test]
    fn a_broken_file_is_reported_as_without_settings() {
        let broken = "[simulation\ndt = 1\n";
        let s: Setting = "simulation.dt=0.1".parse().unwrap();
        let with = scene_from_toml(broken, Path::new("b.toml"), &[s]).unwrap_err();
        let without = Scene::from_toml(broken, Path::new("b.toml")).unwrap_err();
        assert_eq!(with.to_string(), without.to_string());
    }
}
