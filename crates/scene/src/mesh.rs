//! Triangle meshes from Wavefront OBJ files: the `v` positions in the file's order and the
//! faces over them (faces with more than three corners are split into a fan from their first
//! corner). Texture coordinates, normals, groups and materials are ignored, and material files
//! are never opened.
//!
//! The vertices are the file's own, none renumbered, merged, split or dropped: a vertex no face
//! uses stays at its index. A mesh body's exports give vertex i of the file as their vertex i,
//! which per-index transfers in Blender or Houdini rely on; a loader that makes one vertex per
//! (position, texture coordinate, normal) triple would turn a textured cube's 8 into 24.

use std::io::BufRead;
use std::path::Path;

use glam::DVec3;

use crate::scene::TriangleMesh;

/// Loads an OBJ file; the error is a sentence for the user.
pub fn load_obj(path: &Path) -> Result<TriangleMesh, String> {
    // A device or FIFO named as a mesh could be read forever.
    if !path.is_file() {
        return Err(format!("mesh file {} does not exist", path.display()));
    }
    let file = std::fs::File::open(path)
        .map_err(|e| format!("cannot read mesh file {}: {e}", path.display()))?;
    let invalid = |line: usize, why: String| {
        format!(
            "mesh file {} is not a valid OBJ file: line {line}: {why}",
            path.display()
        )
    };
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    let mut statement = String::new();
    let mut first_line = 0;
    for (n, line) in std::io::BufReader::new(file).split(b'\n').enumerate() {
        let line = line.map_err(|e| format!("cannot read mesh file {}: {e}", path.display()))?;
        let line = String::from_utf8_lossy(&line);
        if statement.is_empty() {
            first_line = n + 1;
        }
        // A backslash at the end of a line continues the statement on the next one.
        let line = line.trim_end();
        if let Some(part) = line.strip_suffix('\\') {
            statement.push_str(part);
            statement.push(' ');
            continue;
        }
        statement.push_str(line);
        let mut words = statement.split_whitespace();
        match words.next() {
            Some("v") => vertices.push(position(words).map_err(|e| invalid(first_line, e))?),
            Some("f") => {
                let corners = words
                    .map(|c| corner(c, vertices.len()))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|e| invalid(first_line, e))?;
                if corners.len() < 3 {
                    return Err(invalid(
                        first_line,
                        format!("a face has {} corners, fewer than 3", corners.len()),
                    ));
                }
                faces.push((first_line, corners));
            }
            _ => {}
        }
        statement.clear();
    }
    let count = u32::try_from(vertices.len())
        .map_err(|_| format!("mesh file {} has more than 2³² vertices", path.display()))?;
    let mut triangles = Vec::new();
    for (line, corners) in faces {
        // A positive index may name a vertex given after the face; a relative one cannot.
        if let Some(&i) = corners.iter().find(|&&i| i >= u64::from(count)) {
            return Err(invalid(
                line,
                format!("vertex {} does not exist: the file has {count}", i + 1),
            ));
        }
        let c: Vec<u32> = corners.into_iter().map(|i| i as u32).collect();
        triangles.extend((1..c.len() - 1).map(|k| [c[0], c[k], c[k + 1]]));
    }
    Ok(TriangleMesh {
        path: path.to_owned(),
        vertices,
        triangles,
    })
}

/// The position of a `v` statement: its first three numbers (a weight or a colour after them
/// is ignored).
fn position<'a>(mut words: impl Iterator<Item = &'a str>) -> Result<DVec3, String> {
    let mut p = [0.0; 3];
    for x in &mut p {
        let word = words
            .next()
            .ok_or("a vertex has fewer than three coordinates")?;
        *x = word
            .parse()
            .map_err(|_| format!("`{word}` is not a coordinate"))?;
    }
    Ok(DVec3::from(p))
}

/// The 0-based position index of a face corner (`p`, `p/t`, `p//n` or `p/t/n`), `seen`
/// vertices read before it: 1-based, or negative counting back from the last vertex read.
fn corner(word: &str, seen: usize) -> Result<u64, String> {
    let first = word.split('/').next().unwrap_or_default();
    let bad = || {
        format!("`{word}` is not a face corner (a vertex number, then optionally /texture/normal)")
    };
    let i: i64 = first.parse().map_err(|_| bad())?;
    match i {
        0 => Err(format!(
            "`{word}` names vertex 0: OBJ counts vertices from 1"
        )),
        1.. => Ok(i as u64 - 1),
        _ => (seen as u64).checked_sub(i.unsigned_abs()).ok_or_else(|| {
            format!("`{word}` counts back past the first vertex: {seen} are given before it")
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An `mtllib` line naming something that must not be read (a device that never ends, a
    /// missing file) does not stop the mesh from loading.
    #[test]
    fn material_libraries_are_not_opened() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tri.obj");
        std::fs::write(
            &path,
            "mtllib /dev/zero\nmtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl x\nf 1 2 3\n",
        )
        .unwrap();
        let mesh = load_obj(&path).unwrap();
        assert_eq!(mesh.vertices.len(), 3);
        assert_eq!(mesh.triangles, [[0, 1, 2]]);
    }

    /// The unit cube as Blender writes it (`tests/data/blender-cube.obj`: `vt` and `vn`,
    /// corners `v/vt/vn`, quads), its faces naming vertex 5 first and vertex 1 last, and vertex
    /// 9, after the faces, used by none: the mesh is the file's nine positions in the file's
    /// order, the faces' corners its position indices (relative ones counted back from the last
    /// `v` before them), each quad split into two triangles from its first corner.
    #[test]
    fn vertices_are_the_files_in_the_files_order() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/blender-cube.obj");
        let mesh = load_obj(&path).unwrap();
        let v = |x: f64, y: f64, z: f64| DVec3::new(x, y, z);
        assert_eq!(
            mesh.vertices,
            [
                v(1., 1., 0.),
                v(1., 0., 0.),
                v(1., 1., 1.),
                v(1., 0., 1.),
                v(0., 1., 0.),
                v(0., 0., 0.),
                v(0., 1., 1.),
                v(0., 0., 1.),
                v(0.5, 0.5, 2.),
            ]
        );
        assert_eq!(
            mesh.triangles,
            [
                [4, 6, 2],
                [4, 2, 0],
                [7, 3, 2],
                [7, 2, 6],
                [7, 6, 4],
                [7, 4, 5],
                [5, 1, 3],
                [5, 3, 7],
                [1, 0, 2],
                [1, 2, 3],
                [5, 4, 0],
                [5, 0, 1],
            ]
        );
    }

    /// A corner naming no vertex, or a face of two corners, is refused with its line.
    #[test]
    fn bad_faces_are_refused_with_their_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.obj");
        let error = |text: &str| {
            std::fs::write(&path, text).unwrap();
            let e = load_obj(&path).unwrap_err();
            e.split_once("is not a valid OBJ file: ")
                .unwrap()
                .1
                .to_owned()
        };
        let v = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        assert_eq!(
            error(&format!("{v}f 1 2 4\n")),
            "line 4: vertex 4 does not exist: the file has 3"
        );
        assert_eq!(
            error(&format!("{v}f 0 1 2\n")),
            "line 4: `0` names vertex 0: OBJ counts vertices from 1"
        );
        assert_eq!(
            error(&format!("{v}f -1 -2 -4\n")),
            "line 4: `-4` counts back past the first vertex: 3 are given before it"
        );
        assert_eq!(
            error(&format!("{v}f 1/1 2/2\n")),
            "line 4: a face has 2 corners, fewer than 3"
        );
        assert_eq!(
            error("v 0 0\n"),
            "line 1: a vertex has fewer than three coordinates"
        );
        // A statement continued over two lines is reported at its first.
        assert_eq!(
            error(&format!("{v}f 1 \\\n 2 x\n")),
            "line 4: `x` is not a face corner (a vertex number, then optionally /texture/normal)"
        );
    }
}
