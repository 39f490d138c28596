//! PLY for Blender and Houdini: one `binary_little_endian` file per frame holding the surface
//! mesh ([`SurfaceMesh`]: the surface particles, then the mesh bodies' own meshes — the input
//! file's vertices and faces, in its order, each vertex's velocity the same weighted sum as
//! its position and its `particle` 0xFFFFFFFF — plus every particle of a body without a
//! surface as a lone vertex).
//!
//! ```text
//! ply
//! format binary_little_endian 1.0
//! comment softbody frame 12 time 0.12
//! element vertex V
//! property double x          ─┐
//! property double y           │ metres
//! property double z          ─┘
//! property double vx         ─┐
//! property double vy          │ m/s
//! property double vz         ─┘
//! property uint particle        the particle's number in the run
//! element face F
//! property list uchar uint vertex_indices   triangles, outward counter-clockwise
//! end_header
//! ```
//!
//! Binary rather than ASCII: about a third of the size, exact f64 bits, and read by Blender
//! (File → Import → Stanford PLY), Houdini, MeshLab and every PLY library alike. Vertices are in
//! ascending particle order and the faces the same in every frame, so a series imports as one
//! mesh whose vertices move. Written by hand: the header is a dozen lines, and `ply-rs` has not
//! been released since 2020.

use std::io::{self, Write};
use std::path::PathBuf;

use super::series::{SurfaceMesh, frame_file_name, write_file};
use super::{Frame, FrameSink, Header};

/// Writes one PLY file per frame into a directory.
pub struct PlySink {
    dir: PathBuf,
    stem: String,
    mesh: SurfaceMesh,
}

impl PlySink {
    /// A sink writing `<stem>_000000.ply`… into `dir`.
    pub fn new(dir: PathBuf, stem: String) -> Self {
        PlySink {
            dir,
            stem,
            mesh: SurfaceMesh::default(),
        }
    }
}

impl FrameSink for PlySink {
    fn header(&mut self, header: &Header) -> io::Result<()> {
        self.mesh = SurfaceMesh::new(header)?;
        Ok(())
    }

    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        let mesh = &self.mesh;
        let x = mesh.vertex_values(f.positions)?;
        let v = mesh.vertex_values(f.velocities)?;
        let name = frame_file_name(&self.stem, f.index, "ply");
        write_file(&self.dir, &name, |out| {
            write!(
                out,
                "ply\nformat binary_little_endian 1.0\ncomment softbody frame {} time {}\n\
                 element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
                 property double vx\nproperty double vy\nproperty double vz\n\
                 property uint particle\nelement face {}\n\
                 property list uchar uint vertex_indices\nend_header\n",
                f.index,
                f.time,
                x.len(),
                mesh.faces.len()
            )?;
            // Embedded vertices are no particle: 0xFFFFFFFF.
            let particle = mesh
                .particles
                .iter()
                .copied()
                .chain(std::iter::repeat(u32::MAX));
            for ((x, v), p) in x.iter().zip(&v).zip(particle) {
                for c in [x.x, x.y, x.z, v.x, v.y, v.z] {
                    out.write_all(&c.to_le_bytes())?;
                }
                out.write_all(&p.to_le_bytes())?;
            }
            for face in &mesh.faces {
                out.write_all(&[3])?;
                for i in face {
                    out.write_all(&i.to_le_bytes())?;
                }
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
    fn a_frame_is_header_vertices_and_faces() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = PlySink::new(dir.path().to_owned(), "m".to_owned());
        sink.header(&header(4, &[("b", 0, 4)], vec![], vec![], vec![[3, 2, 1]]))
            .unwrap();
        let x: Vec<DVec3> = (0..4).map(|i| DVec3::splat(i as f64 + 0.5)).collect();
        let v: Vec<DVec3> = (0..4).map(|i| DVec3::new(0.0, -(i as f64), 1.0)).collect();
        sink.frame(&Frame {
            index: 3,
            step: 30,
            time: 0.03,
            positions: &x,
            velocities: &v,
            energies: Energies::default(),
        })
        .unwrap();
        let bytes = std::fs::read(dir.path().join("m_000003.ply")).unwrap();
        let end = b"end_header\n";
        let at = bytes
            .windows(end.len())
            .position(|w| w == end)
            .expect("a header")
            + end.len();
        let head = std::str::from_utf8(&bytes[..at]).unwrap();
        assert!(
            head.contains("comment softbody frame 3 time 0.03\n"),
            "{head}"
        );
        assert!(head.contains("element vertex 3\n") && head.contains("element face 1\n"));
        let body = &bytes[at..];
        // 3 vertices of 6 doubles and a uint, one face of a count and 3 uints.
        assert_eq!(body.len(), 3 * 52 + 13);
        let f64_at = |o: usize| f64::from_le_bytes(body[o..o + 8].try_into().unwrap());
        let u32_at = |o: usize| u32::from_le_bytes(body[o..o + 4].try_into().unwrap());
        // Vertex 0 is particle 1.
        assert_eq!([f64_at(0), f64_at(8), f64_at(16)], [1.5; 3]);
        assert_eq!([f64_at(24), f64_at(32), f64_at(40)], [0.0, -1.0, 1.0]);
        assert_eq!(u32_at(48), 1);
        assert_eq!(u32_at(2 * 52 + 48), 3);
        assert_eq!(body[156], 3);
        assert_eq!([u32_at(157), u32_at(161), u32_at(165)], [2, 1, 0]);
    }
}
