//! Triangle meshes from Wavefront OBJ files (faces with more than three corners are
//! triangulated; materials are ignored).

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
    let (models, _materials) = tobj::load_obj(path, &options)
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
