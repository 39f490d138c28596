//! Wavefront OBJ for Blender and Houdini: one ASCII file per frame holding the surface mesh
//! ([`SurfaceMesh`]: the surface particles, then the mesh bodies' own meshes — the input
//! file's vertices and faces, in its order — plus every particle of a body without a surface
//! as a lone vertex), `v x y z` lines then `f a b c` triangles (1-based, outward
//! counter-clockwise).
//!
//! Coordinates are printed in Rust's shortest round-trip form (`{:?}`: with an exponent when
//! tiny or huge, `1e-300` rather than 300 digits), so they read back to the same f64. OBJ has
//! no place for velocities or particle numbers: vertices are the mesh's particles in ascending
//! order, then the embedded vertices, the same in every frame (the PLY export carries both).

use std::io::{self, Write};
use std::path::PathBuf;

use super::series::{SurfaceMesh, frame_file_name, write_file};
use super::{Frame, FrameSink, Header};

/// Writes one OBJ file per frame into a directory.
pub struct ObjSink {
    dir: PathBuf,
    stem: String,
    mesh: SurfaceMesh,
}

impl ObjSink {
    /// A sink writing `<stem>_000000.obj`… into `dir`.
    pub fn new(dir: PathBuf, stem: String) -> Self {
        ObjSink {
            dir,
            stem,
            mesh: SurfaceMesh::default(),
        }
    }
}

impl FrameSink for ObjSink {
    fn header(&mut self, header: &Header) -> io::Result<()> {
        self.mesh = SurfaceMesh::new(header)?;
        Ok(())
    }

    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        let mesh = &self.mesh;
        let vertices = mesh.vertex_values(f.positions)?;
        let name = frame_file_name(&self.stem, f.index, "obj");
        write_file(&self.dir, &name, |out| {
            writeln!(
                out,
                "# softbody frame {} time {} s: {} vertices, {} triangles",
                f.index,
                f.time,
                vertices.len(),
                mesh.faces.len()
            )?;
            for x in &vertices {
                writeln!(out, "v {:?} {:?} {:?}", x.x, x.y, x.z)?;
            }
            for [a, b, c] in &mesh.faces {
                writeln!(out, "f {} {} {}", a + 1, b + 1, c + 1)?;
            }
            Ok(())
        })
    }

    fn wants_springs(&self) -> bool {
        false
    }

    fn finish(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::series::tests::header;
    use glam::DVec3;
    use softbody_scene::Energies;

    #[test]
    fn a_frame_is_vertices_and_one_based_faces() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = ObjSink::new(dir.path().to_owned(), "m".to_owned());
        sink.header(&header(4, &[("b", 0, 4)], vec![], vec![], vec![[1, 3, 2]]))
            .unwrap();
        let x = [
            DVec3::ZERO,
            DVec3::new(0.1, 0.2, 0.30000000000000004),
            DVec3::new(-1.0, 2.5, 1e-300),
            DVec3::Y,
        ];
        sink.frame(&Frame {
            index: 0,
            step: 0,
            time: 0.0,
            positions: &x,
            velocities: &[DVec3::ZERO; 4],
            energies: Energies::default(),
        })
        .unwrap();
        let text = std::fs::read_to_string(dir.path().join("m_000000.obj")).unwrap();
        let mut lines = text.lines();
        assert_eq!(
            lines.next(),
            Some("# softbody frame 0 time 0 s: 3 vertices, 1 triangles")
        );
        let rest: Vec<&str> = lines.collect();
        assert_eq!(
            rest[..3],
            [
                "v 0.1 0.2 0.30000000000000004",
                "v -1.0 2.5 1e-300",
                "v 0.0 1.0 0.0"
            ]
        );
        assert_eq!(rest[3..], ["f 1 3 2"]);
    }
}
