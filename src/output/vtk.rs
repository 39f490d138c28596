//! VTK for ParaView: a `.pvd` collection naming one `.vtu` (XML UnstructuredGrid) per frame.
//!
//! Each `.vtu` holds one piece:
//! - points: the particles (`Float64`), then the vertices of the mesh bodies' own meshes
//!   (weighted sums of particles, each file's vertices in its order), with point data
//!   `velocity` (3 components, m/s) and `speed` (|v|, m/s);
//! - cells: first every spring as a line (`VTK_LINE`, in the header's spring order), then every
//!   surface triangle (`VTK_TRIANGLE`, outward counter-clockwise: the cuboids' and lattice
//!   surfaces, then the mesh bodies' meshes, each file's faces in its order), with
//!   cell data `kind` (`UInt8`: 0 spring, 1 surface triangle; ParaView's Threshold on it
//!   shows either) and `strain` ((|x_a − x_b| − rest) / rest for springs, NaN for triangles);
//! - field data `TimeValue`: the frame's time, so a lone `.vtu` still knows it.
//!
//! One file with mixed cells rather than two pieces: one reader per frame in ParaView, and
//! point data shared by both. Arrays are inline `binary` (base64 of a `UInt64` byte count
//! followed by the little-endian values, `header_type="UInt64"`): a third of the size of ASCII
//! decimals, exact f64 bits, and still well-formed XML any parser reads. Connectivity, offsets
//! and types are `Int64`/`UInt8`, VTK's own types, and the same every frame, so they are
//! encoded once.
//!
//! The `.pvd` lists each frame as `<DataSet timestep="t" file="<stem>/<stem>_000000.vtu"/>`
//! with t the frame time; it is written when the run ends, listing exactly the frames written.
//!
//! Written by hand: the `vtkio` crate's last release is a 2023 release candidate (0.7.0-rc2)
//! whose default features build the C libraries of lz4 and xz, for files that are a few
//! lines of XML around base64.

use std::io::{self, Write};
use std::path::PathBuf;

use softbody_scene::model::Embedded;

use super::series::{self, check_indices, frame_file_name, write_file};
use super::{Frame, FrameSink, Header};

/// `VTK_LINE`, `VTK_TRIANGLE` (vtkCellType.h).
const VTK_LINE: u8 = 3;
const VTK_TRIANGLE: u8 = 5;

/// Cell data `kind` of springs and of surface triangles.
pub const KIND_SPRING: u8 = 0;
/// See [`KIND_SPRING`].
pub const KIND_SURFACE: u8 = 1;

/// Writes a ParaView series: `.vtu` frames into a directory and the `.pvd` at the end.
pub struct VtkSink {
    dir: PathBuf,
    stem: String,
    /// What the `.pvd` puts before a frame's file name (the directory, as seen from it).
    href_prefix: String,
    index: Option<Box<dyn Write>>,
    particles: usize,
    springs: Vec<[u32; 2]>,
    rest: Vec<f64>,
    triangles: usize,
    /// The mesh bodies' meshes, whose vertices are points after the particles.
    embedded: Embedded,
    /// `<Cells>` and the `kind` cell array: the same every frame.
    cells: String,
    kind: String,
    /// (time, file) of every frame written.
    written: Vec<(f64, String)>,
}

impl VtkSink {
    /// A sink writing frames into `dir` as `<stem>_000000.vtu`…, and the `.pvd` to `index`
    /// when it finishes, naming each frame `<href_prefix><file>`.
    pub fn new(dir: PathBuf, stem: String, href_prefix: String, index: Box<dyn Write>) -> Self {
        VtkSink {
            dir,
            stem,
            href_prefix,
            index: Some(index),
            particles: 0,
            springs: Vec::new(),
            rest: Vec::new(),
            triangles: 0,
            embedded: Embedded::default(),
            cells: String::new(),
            kind: String::new(),
            written: Vec::new(),
        }
    }
}

/// Appends `bytes` to `out` in base64 (RFC 4648, padded).
fn base64(out: &mut String, bytes: &[u8]) {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    out.reserve(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (k, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> shift) as usize & 63] as char);
            } else {
                out.push('=');
            }
        }
    }
}

/// A `<DataArray>` in VTK's inline binary encoding: base64 of the byte count (`UInt64`) and
/// the values' little-endian bytes, one stream.
fn data_array(
    out: &mut String,
    vtk_type: &str,
    name: Option<&str>,
    components: usize,
    values: &[u8],
) {
    out.push_str("<DataArray type=\"");
    out.push_str(vtk_type);
    out.push('"');
    if let Some(name) = name {
        out.push_str(" Name=\"");
        out.push_str(name);
        out.push('"');
    }
    if components != 1 {
        out.push_str(&format!(" NumberOfComponents=\"{components}\""));
    }
    out.push_str(" format=\"binary\">");
    let mut raw = Vec::with_capacity(8 + values.len());
    raw.extend_from_slice(&(values.len() as u64).to_le_bytes());
    raw.extend_from_slice(values);
    base64(out, &raw);
    out.push_str("</DataArray>\n");
}

fn f64_bytes(values: impl IntoIterator<Item = f64>) -> Vec<u8> {
    values.into_iter().flat_map(f64::to_le_bytes).collect()
}

fn i64_bytes(values: impl IntoIterator<Item = i64>) -> Vec<u8> {
    values.into_iter().flat_map(i64::to_le_bytes).collect()
}

/// `s` escaped for an XML attribute value in double quotes.
fn escape_attribute(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

/// The strain of each spring at `x`: (|x_a − x_b| − rest) / rest.
pub fn strains(springs: &[[u32; 2]], rest: &[f64], x: &[glam::DVec3]) -> Vec<f64> {
    springs
        .iter()
        .zip(rest)
        .map(|(&[a, b], &r)| ((x[a as usize] - x[b as usize]).length() - r) / r)
        .collect()
}

impl FrameSink for VtkSink {
    fn header(&mut self, header: &Header) -> io::Result<()> {
        self.take_header(header.clone())
    }

    fn take_header(&mut self, mut header: Header) -> io::Result<()> {
        let n = header.particles;
        check_indices(&header.springs, n, "spring")?;
        check_indices(&header.surface, n, "surface triangle")?;
        check_indices(&header.embedded.corners, n, "mesh vertex")?;
        let embedded = &header.embedded;
        check_indices(
            &embedded.triangles,
            embedded.len(),
            "mesh triangle (of its vertices)",
        )?;
        if embedded.weights.len() != embedded.corners.len() {
            return Err(series::bad_header(format!(
                "{} mesh vertex weights for {} vertices",
                embedded.weights.len(),
                embedded.corners.len()
            )));
        }
        if header.rest.len() != header.springs.len() {
            return Err(series::bad_header(format!(
                "{} rest lengths for {} springs",
                header.rest.len(),
                header.springs.len()
            )));
        }
        self.particles = n;
        self.springs = std::mem::take(&mut header.springs);
        self.rest = std::mem::take(&mut header.rest);
        self.triangles = header.surface.len() + embedded.triangles.len();
        self.embedded = embedded.clone();

        // The embedded vertices are points after the particles.
        let lines = self.springs.iter().flatten().map(|&i| i64::from(i));
        let triangles = header.surface.iter().flatten().map(|&i| i64::from(i));
        let meshes = embedded
            .triangles
            .iter()
            .flatten()
            .map(|&i| (n + i as usize) as i64);
        let connectivity = i64_bytes(lines.chain(triangles).chain(meshes));
        let offsets = i64_bytes(
            (1..=self.springs.len())
                .map(|s| 2 * s as i64)
                .chain((1..=self.triangles).map(|t| (2 * self.springs.len() + 3 * t) as i64)),
        );
        let types: Vec<u8> = std::iter::repeat_n(VTK_LINE, self.springs.len())
            .chain(std::iter::repeat_n(VTK_TRIANGLE, self.triangles))
            .collect();
        let mut cells = String::from("<Cells>\n");
        data_array(&mut cells, "Int64", Some("connectivity"), 1, &connectivity);
        data_array(&mut cells, "Int64", Some("offsets"), 1, &offsets);
        data_array(&mut cells, "UInt8", Some("types"), 1, &types);
        cells.push_str("</Cells>\n");
        self.cells = cells;

        let kind: Vec<u8> = std::iter::repeat_n(KIND_SPRING, self.springs.len())
            .chain(std::iter::repeat_n(KIND_SURFACE, self.triangles))
            .collect();
        self.kind.clear();
        data_array(&mut self.kind, "UInt8", Some("kind"), 1, &kind);
        Ok(())
    }

    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        if f.positions.len() != self.particles || f.velocities.len() != self.particles {
            return Err(series::bad_header(format!(
                "a frame of {} positions and {} velocities for {} particles",
                f.positions.len(),
                f.velocities.len(),
                self.particles
            )));
        }
        let strain = strains(&self.springs, &self.rest, f.positions)
            .into_iter()
            .chain(std::iter::repeat_n(f64::NAN, self.triangles));
        let cells = self.springs.len() + self.triangles;
        let (x, v) = if self.embedded.is_empty() {
            (f.positions.to_vec(), f.velocities.to_vec())
        } else {
            let mut x = f.positions.to_vec();
            self.embedded.apply_into(f.positions, &mut x);
            let mut v = f.velocities.to_vec();
            self.embedded.apply_into(f.velocities, &mut v);
            (x, v)
        };

        let mut xml = String::new();
        xml.push_str(
            "<?xml version=\"1.0\"?>\n\
             <VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" \
             header_type=\"UInt64\">\n<UnstructuredGrid>\n<FieldData>\n",
        );
        // Rust's `{}` prints the shortest decimal that reads back to the same f64.
        xml.push_str(&format!(
            "<DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" \
             format=\"ascii\">{}</DataArray>\n</FieldData>\n",
            f.time
        ));
        xml.push_str(&format!(
            "<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{cells}\">\n\
             <PointData Scalars=\"speed\" Vectors=\"velocity\">\n",
            x.len()
        ));
        data_array(
            &mut xml,
            "Float64",
            Some("velocity"),
            3,
            &f64_bytes(v.iter().flat_map(|v| v.to_array())),
        );
        data_array(
            &mut xml,
            "Float64",
            Some("speed"),
            1,
            &f64_bytes(v.iter().map(|v| v.length())),
        );
        xml.push_str("</PointData>\n<CellData Scalars=\"strain\">\n");
        xml.push_str(&self.kind);
        data_array(&mut xml, "Float64", Some("strain"), 1, &f64_bytes(strain));
        xml.push_str("</CellData>\n<Points>\n");
        data_array(
            &mut xml,
            "Float64",
            Some("Points"),
            3,
            &f64_bytes(x.iter().flat_map(|x| x.to_array())),
        );
        xml.push_str("</Points>\n");
        xml.push_str(&self.cells);
        xml.push_str("</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");

        let name = frame_file_name(&self.stem, f.index, "vtu");
        write_file(&self.dir, &name, |out| out.write_all(xml.as_bytes()))?;
        self.written.push((f.time, name));
        Ok(())
    }

    fn finish(&mut self) -> io::Result<()> {
        let Some(mut out) = self.index.take() else {
            return Ok(());
        };
        out.write_all(
            b"<?xml version=\"1.0\"?>\n\
              <VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n\
              <Collection>\n",
        )?;
        for (time, name) in &self.written {
            writeln!(
                out,
                "<DataSet timestep=\"{time}\" group=\"\" part=\"0\" file=\"{}\"/>",
                escape_attribute(&format!("{}{name}", self.href_prefix))
            )?;
        }
        out.write_all(b"</Collection>\n</VTKFile>\n")?;
        out.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::series::tests::header;
    use glam::DVec3;
    use softbody_scene::Energies;

    #[test]
    fn base64_matches_rfc_4648() {
        // The test vectors of RFC 4648 §10.
        for (plain, encoded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            let mut out = String::new();
            base64(&mut out, plain.as_bytes());
            assert_eq!(out, encoded, "{plain:?}");
        }
    }

    #[test]
    fn attributes_are_escaped() {
        assert_eq!(
            escape_attribute(r#"a&b<c>"d'"#),
            "a&amp;b&lt;c&gt;&quot;d&apos;"
        );
    }

    #[test]
    fn strain_is_relative_extension() {
        let x = [
            DVec3::ZERO,
            DVec3::new(3.0, 4.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ];
        let s = strains(&[[0, 1], [2, 0]], &[4.0, 2.0], &x);
        assert_eq!(s, [0.25, -0.5]);
    }

    /// A writer whose bytes the test reads afterwards (the sink owns its `.pvd` writer).
    struct Shared(std::rc::Rc<std::cell::RefCell<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.0.borrow_mut().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn frames_and_collection_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let pvd = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
        let mut sink = VtkSink::new(
            dir.path().to_owned(),
            "a&b".to_owned(),
            "a&b/".to_owned(),
            Box::new(Shared(pvd.clone())),
        );
        let h = header(
            3,
            &[("t", 0, 3)],
            vec![[0, 1], [1, 2]],
            vec![1.0, 2.0],
            vec![[0, 1, 2]],
        );
        sink.header(&h).unwrap();
        let x = [DVec3::ZERO, DVec3::X * 2.0, DVec3::new(2.0, 1.0, 0.0)];
        let v = [DVec3::new(3.0, 4.0, 0.0), DVec3::ZERO, DVec3::Y];
        for (index, time) in [(0, 0.0), (1, 0.1)] {
            sink.frame(&Frame {
                index,
                step: index * 100,
                time,
                positions: &x,
                velocities: &v,
                energies: Energies::default(),
            })
            .unwrap();
        }
        sink.finish().unwrap();

        let pvd = String::from_utf8(pvd.borrow().clone()).unwrap();
        assert!(
            pvd.contains(
                r#"<DataSet timestep="0" group="" part="0" file="a&amp;b/a&amp;b_000000.vtu"/>"#
            ),
            "{pvd}"
        );
        assert!(
            pvd.contains(r#"timestep="0.1" group="" part="0" file="a&amp;b/a&amp;b_000001.vtu""#)
        );
        let vtu = std::fs::read_to_string(dir.path().join("a&b_000001.vtu")).unwrap();
        assert!(
            vtu.contains(r#"<Piece NumberOfPoints="3" NumberOfCells="3">"#),
            "{vtu}"
        );
        assert!(vtu.contains(r#"format="ascii">0.1</DataArray>"#));
        // The strains: spring 0 stretched from 1 to 2 (1.0), spring 1 from 2 to 1 (-0.5), NaN.
        let mut expect = String::new();
        data_array(
            &mut expect,
            "Float64",
            Some("strain"),
            1,
            &f64_bytes([1.0, -0.5, f64::NAN]),
        );
        assert!(vtu.contains(&expect), "{vtu}");
        // Offsets 2, 4 for the lines, 7 for the triangle.
        let mut expect = String::new();
        data_array(
            &mut expect,
            "Int64",
            Some("offsets"),
            1,
            &i64_bytes([2, 4, 7]),
        );
        assert!(vtu.contains(&expect));
    }

    #[test]
    fn a_header_with_a_bad_spring_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = VtkSink::new(
            dir.path().to_owned(),
            "s".to_owned(),
            "s/".to_owned(),
            Box::new(io::sink()),
        );
        let h = header(2, &[("b", 0, 2)], vec![[0, 2]], vec![1.0], vec![]);
        assert_eq!(
            sink.header(&h).unwrap_err().kind(),
            io::ErrorKind::InvalidData
        );
        let h = header(2, &[("b", 0, 2)], vec![[0, 1]], vec![], vec![]);
        assert_eq!(
            sink.header(&h).unwrap_err().kind(),
            io::ErrorKind::InvalidData
        );
    }
}
