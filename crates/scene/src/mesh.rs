//! Triangle meshes from Wavefront OBJ files (faces with more than three corners are
//! triangulated; materials are ignored and their files never opened).

use std::path::Path;

use glam::DVec3;

use crate::scene::TriangleMesh;

/// Loads an OBJ file; the error is a sentence for the user.
pub fn load_obj(path: &Path) -> Result<TriangleMesh, String> {
    if !path.is_file() {
        return Err(format!("mesh file {} does not exist", path.display()));
    }
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let file = std::fs::File::open(path)
        .map_err(|e| format!("cannot read mesh file {}: {e}", path.display()))?;
    // Materials are unused, so an `mtllib` line is not followed: the file it names could be
    // anything (`/dev/zero`, a FIFO, a 4 GB texture library).
    let no_materials = |_: &Path| Err(tobj::LoadError::OpenFileFailed);
    let (models, _materials) =
        tobj::load_obj_buf(&mut std::io::BufReader::new(file), &options, no_materials)
            .map_err(|e| format!("mesh file {} is not a valid OBJ file: {e}", path.display()))?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for model in models {
        let base = vertices.len() as u32;
        let m = model.mesh;
        vertices.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| DVec3::new(p[0], p[1], p[2])),
        );
        triangles.extend(
            m.indices
                .chunks_exact(3)
                .map(|t| [base + t[0], base + t[1], base + t[2]]),
        );
    }
    Ok(TriangleMesh {
        path: path.to_owned(),
        vertices,
        triangles,
    })
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
}
