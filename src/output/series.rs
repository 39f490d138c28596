//! What the per-frame formats (VTK, PLY, OBJ) share: frame file names, whole-file writes, the
//! surface mesh.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use glam::DVec3;
use softbody_scene::model::Embedded;

use super::Header;

/// The name of frame `index`'s file: `<stem>_<index, 6 digits or more>.<ext>`, so that the
/// files of a series sort in frame order.
pub(crate) fn frame_file_name(stem: &str, index: u64, ext: &str) -> String {
    format!("{stem}_{index:06}.{ext}")
}

/// Writes one file of `dir` whole: `body` fills a buffer, which is then flushed; an error
/// leaves a file the staging directory discards.
pub(crate) fn write_file(
    dir: &Path,
    name: &str,
    body: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> io::Result<()> {
    let path = dir.join(name);
    let named = |e: io::Error| io::Error::new(e.kind(), format!("{}: {e}", path.display()));
    let mut out = BufWriter::new(File::create(&path).map_err(named)?);
    body(&mut out).and_then(|()| out.flush()).map_err(named)
}

/// An error for a header that does not describe its own particles.
pub(crate) fn bad_header(what: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, what)
}

/// Checks that every index of `items` names one of `n` particles.
pub(crate) fn check_indices<const K: usize>(
    items: &[[u32; K]],
    n: usize,
    what: &str,
) -> io::Result<()> {
    match items.iter().flatten().find(|&&i| i as usize >= n) {
        Some(i) => Err(bad_header(format!(
            "a {what} names particle {i} of only {n}"
        ))),
        None => Ok(()),
    }
}

/// The mesh the PLY and OBJ writers export: the surface triangles over the particles they
/// use, then the mesh bodies' input meshes (their vertices weighted sums of particles,
/// [`softbody_scene::model::Embedded`]: each file's vertices and faces in its own order), plus
/// every particle of a body with neither (a particle set) as a lone vertex, so that such
/// bodies are not lost. Vertices are the particles in ascending order, then the embedded
/// vertices, the same every frame, which is what mesh-sequence importers need.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct SurfaceMesh {
    /// The particle of each of the first vertices, ascending.
    pub particles: Vec<u32>,
    /// The vertices after them.
    pub embedded: Embedded,
    /// Triangles over vertex numbers (0-based), outward counter-clockwise.
    pub faces: Vec<[u32; 3]>,
}

impl SurfaceMesh {
    pub fn new(header: &Header) -> io::Result<SurfaceMesh> {
        let n = header.particles;
        check_indices(&header.surface, n, "surface triangle")?;
        check_indices(&header.embedded.corners, n, "mesh vertex")?;
        let embedded = &header.embedded;
        if embedded.weights.len() != embedded.corners.len() {
            return Err(bad_header(format!(
                "{} mesh vertex weights for {} vertices",
                embedded.weights.len(),
                embedded.corners.len()
            )));
        }
        check_indices(
            &embedded.triangles,
            embedded.len(),
            "mesh triangle (of its vertices)",
        )?;
        let mut used = vec![false; n];
        for &i in header.surface.iter().flatten() {
            used[i as usize] = true;
        }
        for (b, body) in header.bodies.iter().enumerate() {
            let range = body.first as usize..(body.first as usize + body.count as usize).min(n);
            if !used[range.clone()].contains(&true) && !embedded.has_body(b as u32) {
                used[range].fill(true);
            }
        }
        let mut vertex = vec![u32::MAX; n];
        let mut particles = Vec::new();
        for (i, _) in used.iter().enumerate().filter(|(_, u)| **u) {
            vertex[i] = particles.len() as u32;
            particles.push(i as u32);
        }
        let shift = particles.len() as u32;
        let faces = header
            .surface
            .iter()
            .map(|t| t.map(|i| vertex[i as usize]))
            .chain(embedded.triangles.iter().map(|t| t.map(|i| shift + i)))
            .collect();
        Ok(SurfaceMesh {
            particles,
            embedded: embedded.clone(),
            faces,
        })
    }

    /// Each vertex's value from the particles' `values` (positions or velocities): the
    /// particles', then the embedded vertices'. `values` must cover every particle named.
    pub fn vertex_values(&self, values: &[DVec3]) -> io::Result<Vec<DVec3>> {
        let n = values.len();
        let named = self
            .particles
            .last()
            .copied()
            .max(self.embedded.max_particle());
        if let Some(p) = named.filter(|&p| p as usize >= n) {
            return Err(bad_header(format!(
                "the mesh names particle {p} of a frame of {n}"
            )));
        }
        let mut out: Vec<DVec3> = self.particles.iter().map(|&p| values[p as usize]).collect();
        self.embedded.apply_into(values, &mut out);
        Ok(out)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::output::HeaderBody;

    /// A header of `particles` particles in `bodies` (name, first, count) with `surface`.
    pub(crate) fn header(
        particles: usize,
        bodies: &[(&str, u32, u32)],
        springs: Vec<[u32; 2]>,
        rest: Vec<f64>,
        surface: Vec<[u32; 3]>,
    ) -> Header {
        Header {
            softbody_frames: 1,
            particles,
            bodies: bodies
                .iter()
                .map(|&(name, first, count)| HeaderBody {
                    name: name.to_owned(),
                    first,
                    count,
                })
                .collect(),
            integrator: "rk4".to_owned(),
            backend: "cpu".to_owned(),
            device: "test".to_owned(),
            dt: 0.001,
            frame_rate: 100.0,
            frames: 2,
            steps: 10,
            scene: None,
            scene_text: None,
            masses: vec![1.0; particles],
            stiffness: vec![100.0; springs.len()],
            damping: vec![0.0; springs.len()],
            springs,
            rest,
            surface,
            embedded: Embedded::default(),
        }
    }

    #[test]
    fn mesh_keeps_surface_particles_and_surfaceless_bodies() {
        // A tetrahedron body (particles 0..5, particle 4 inside) and a particle set (5..7).
        let h = header(
            7,
            &[("tet", 0, 5), ("dots", 5, 2)],
            vec![],
            vec![],
            vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
        );
        let mesh = SurfaceMesh::new(&h).unwrap();
        assert_eq!(mesh.particles, [0, 1, 2, 3, 5, 6]);
        assert_eq!(mesh.faces, [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]);

        // Renumbering skips the interior particle.
        let h = header(4, &[("b", 0, 4)], vec![], vec![], vec![[1, 2, 3]]);
        let mesh = SurfaceMesh::new(&h).unwrap();
        assert_eq!(mesh.particles, [1, 2, 3]);
        assert_eq!(mesh.faces, [[0, 1, 2]]);
    }

    #[test]
    fn mesh_refuses_out_of_range_triangles() {
        let h = header(3, &[("b", 0, 3)], vec![], vec![], vec![[0, 1, 3]]);
        let e = SurfaceMesh::new(&h).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
        assert!(e.to_string().contains("particle 3 of only 3"), "{e}");
    }

    #[test]
    fn frame_files_sort_in_frame_order() {
        assert_eq!(frame_file_name("run", 7, "vtu"), "run_000007.vtu");
        assert_eq!(frame_file_name("run", 1234567, "ply"), "run_1234567.ply");
    }
}
