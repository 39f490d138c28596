//! Writes the closed meshes the mesh-body scenes use: `scenes/torus.obj` (a torus, R = 0.2 m,
//! r = 0.08 m, 32 × 16 quads) and `scenes/star.obj` (a five-pointed star prism, tips at
//! 0.3 m, notches at 0.13 m, 0.12 m thick), both made by `softbody::scene::shapes` — no
//! third-party model files.
//!
//! ```text
//! cargo run --release --example mesh_shapes            # writes into scenes/
//! cargo run --release --example mesh_shapes -- DIR     # writes into DIR
//! ```

use std::path::PathBuf;

use softbody::scene::TriangleMesh;

fn main() -> std::io::Result<()> {
    let dir = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes"));
    let shapes = [
        (
            "torus.obj",
            TriangleMesh::torus(0.2, 0.08, 32, 16),
            "A torus lying flat: R = 0.2 m, r = 0.08 m, 32 x 16 quads (2 triangles each).\n\
             Written by `cargo run --example mesh_shapes` (TriangleMesh::torus).",
        ),
        (
            "star.obj",
            TriangleMesh::star_prism(5, 0.3, 0.13, 0.12),
            "A five-pointed star prism: tips at 0.3 m, notches at 0.13 m, 0.12 m thick.\n\
             Written by `cargo run --example mesh_shapes` (TriangleMesh::star_prism).",
        ),
    ];
    for (name, mesh, comment) in shapes {
        let path = dir.join(name);
        std::fs::write(&path, mesh.to_obj(comment))?;
        println!(
            "{}: {} vertices, {} triangles",
            path.display(),
            mesh.vertices.len(),
            mesh.triangles.len()
        );
    }
    Ok(())
}
