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
//! and types are `Int64`/`UInt8`, VTK's own types. Every array is encoded as it is written
//! (the `base64` crate's streaming encoder), the cells too: keeping their encoding between
//! frames would cost 35 B a spring for the run's length, to spare encoding a third of a file
//! that is written anyway.
//!
//! The `.pvd` lists each frame as `<DataSet timestep="t" file="<stem>/<stem>_000000.vtu"/>`
//! with t the frame time; it is written when the run ends, listing exactly the frames written.
//!
//! The XML is written by hand: the `vtkio` crate's last release is a 2023 release candidate (0.7.0-rc2)
//! whose default features build the C libraries of lz4 and xz, for files that are a few
//! lines of XML around base64.

use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use base64::engine::general_purpose::STANDARD;
use base64::write::EncoderWriter;
use glam::DVec3;
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
///
/// A frame is encoded as it is written: the sink keeps the springs' ends and rest lengths
/// (16 B a spring, within the header's share that `run` checks against the memory left) and
/// builds no per-frame array, so a frame of a 100³ cube (15.7 M springs, 0.7 GB of XML) takes
/// no more memory than the sink holds already.
pub struct VtkSink {
    dir: PathBuf,
    stem: String,
    /// What the `.pvd` puts before a frame's file name (the directory, as seen from it).
    href_prefix: String,
    index: Option<Box<dyn Write>>,
    particles: usize,
    springs: Vec<[u32; 2]>,
    rest: Vec<f64>,
    /// The surface triangles over the particles, then the mesh bodies' own, over the points
    /// after the particles.
    triangles: Vec<[i64; 3]>,
    /// The mesh bodies' meshes, whose vertices are points after the particles.
    embedded: Embedded,
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
            triangles: Vec::new(),
            embedded: Embedded::default(),
            written: Vec::new(),
        }
    }

    /// One `.vtu` of the frame at positions `x` (the particles' then the embedded vertices')
    /// and velocities `v`, to `out`.
    fn write_frame(
        &self,
        out: &mut impl Write,
        time: f64,
        x: &[&[DVec3]; 2],
        v: &[&[DVec3]; 2],
    ) -> io::Result<()> {
        let points = x[0].len() + x[1].len();
        let springs = self.springs.len();
        let cells = springs + self.triangles.len();
        let particles = x[0];
        let x = || x[0].iter().chain(x[1]);
        let v = || v[0].iter().chain(v[1]);
        // Rust's `{}` prints the shortest decimal that reads back to the same f64.
        write!(
            out,
            "<?xml version=\"1.0\"?>\n\
             <VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" \
             header_type=\"UInt64\">\n<UnstructuredGrid>\n<FieldData>\n\
             <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" \
             format=\"ascii\">{time}</DataArray>\n</FieldData>\n\
             <Piece NumberOfPoints=\"{points}\" NumberOfCells=\"{cells}\">\n\
             <PointData Scalars=\"speed\" Vectors=\"velocity\">\n"
        )?;
        let components = |v: &DVec3| v.to_array().map(f64::to_le_bytes);
        data_array(
            out,
            "Float64",
            "velocity",
            3,
            3 * points,
            v().flat_map(components),
        )?;
        let speed = v().map(|v| v.length().to_le_bytes());
        data_array(out, "Float64", "speed", 1, points, speed)?;
        out.write_all(b"</PointData>\n<CellData Scalars=\"strain\">\n")?;
        let kind = std::iter::repeat_n(KIND_SPRING, springs)
            .chain(std::iter::repeat_n(KIND_SURFACE, self.triangles.len()));
        data_array(out, "UInt8", "kind", 1, cells, kind.map(u8::to_le_bytes))?;
        let ends = |[a, b]: [u32; 2]| (particles[a as usize], particles[b as usize]);
        let strain = (self.springs.iter().zip(&self.rest))
            .map(|(&s, &rest)| strain(ends(s), rest))
            .chain(std::iter::repeat_n(f64::NAN, self.triangles.len()));
        data_array(
            out,
            "Float64",
            "strain",
            1,
            cells,
            strain.map(f64::to_le_bytes),
        )?;
        out.write_all(b"</CellData>\n<Points>\n")?;
        data_array(
            out,
            "Float64",
            "Points",
            3,
            3 * points,
            x().flat_map(components),
        )?;
        out.write_all(b"</Points>\n<Cells>\n")?;
        let connectivity = (self.springs.iter().flatten().map(|&i| i64::from(i)))
            .chain(self.triangles.iter().flatten().copied());
        let corners = 2 * springs + 3 * self.triangles.len();
        let connectivity = connectivity.map(i64::to_le_bytes);
        data_array(out, "Int64", "connectivity", 1, corners, connectivity)?;
        let offsets = (1..=springs)
            .map(|s| 2 * s as i64)
            .chain((1..=self.triangles.len()).map(|t| (2 * springs + 3 * t) as i64));
        data_array(
            out,
            "Int64",
            "offsets",
            1,
            cells,
            offsets.map(i64::to_le_bytes),
        )?;
        let types = std::iter::repeat_n(VTK_LINE, springs)
            .chain(std::iter::repeat_n(VTK_TRIANGLE, self.triangles.len()));
        data_array(out, "UInt8", "types", 1, cells, types.map(u8::to_le_bytes))?;
        out.write_all(b"</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n")
    }
}

/// Writes a `<DataArray>` of `count` values in VTK's inline binary encoding: base64 of the
/// byte count (`UInt64`) and the values' little-endian bytes, one stream, encoded as the
/// values come.
fn data_array<const B: usize>(
    out: &mut impl Write,
    vtk_type: &str,
    name: &str,
    components: usize,
    count: usize,
    values: impl Iterator<Item = [u8; B]>,
) -> io::Result<()> {
    write!(out, "<DataArray type=\"{vtk_type}\" Name=\"{name}\"")?;
    if components != 1 {
        write!(out, " NumberOfComponents=\"{components}\"")?;
    }
    out.write_all(b" format=\"binary\">")?;
    let mut encoder = BufWriter::with_capacity(1 << 16, EncoderWriter::new(&mut *out, &STANDARD));
    encoder.write_all(&((count * B) as u64).to_le_bytes())?;
    let mut written = 0;
    for value in values {
        encoder.write_all(&value)?;
        written += 1;
    }
    if written != count {
        // The byte count is already out: a wrong count would make the file unreadable.
        return Err(io::Error::other(format!(
            "the VTK array {name} has {written} values, not {count}"
        )));
    }
    encoder.into_inner().map_err(|e| e.into_error())?.finish()?;
    out.write_all(b"</DataArray>\n")
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

/// The strain of a spring between `a` and `b`: (|a − b| − rest) / rest.
fn strain((a, b): (DVec3, DVec3), rest: f64) -> f64 {
    ((a - b).length() - rest) / rest
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
        // The embedded vertices are points after the particles.
        let surface = header.surface.iter().map(|t| t.map(i64::from));
        let meshes = (embedded.triangles.iter()).map(|t| t.map(|i| (n + i as usize) as i64));
        self.triangles = surface.chain(meshes).collect();
        self.embedded = std::mem::take(&mut header.embedded);
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
        let (x, v) = (
            self.embedded.apply(f.positions),
            self.embedded.apply(f.velocities),
        );
        let name = frame_file_name(&self.stem, f.index, "vtu");
        write_file(&self.dir, &name, |out| {
            self.write_frame(out, f.time, &[f.positions, &x], &[f.velocities, &v])
        })?;
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
    use softbody_scene::Energies;

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
        assert_eq!(strain((x[0], x[1]), 4.0), 0.25);
        assert_eq!(strain((x[2], x[0]), 2.0), -0.5);
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

    /// A one-component array as VTK's inline binary encoding spells it: base64 of the byte
    /// count and the values in one stream (the RFC 4648 test vectors of the `base64` crate's
    /// padded standard alphabet).
    fn array<const B: usize, const N: usize>(
        vtk_type: &str,
        name: &str,
        values: [[u8; B]; N],
    ) -> String {
        use base64::Engine;
        let mut raw = ((B * N) as u64).to_le_bytes().to_vec();
        raw.extend(values.iter().flatten());
        format!(
            "<DataArray type=\"{vtk_type}\" Name=\"{name}\" format=\"binary\">{}</DataArray>\n",
            base64::engine::general_purpose::STANDARD.encode(raw)
        )
    }

    /// The encoder's output equals the whole stream's encoding, whatever the buffer sizes.
    #[test]
    fn an_array_is_its_stream_in_base64() {
        for n in [0, 1, 2, 3, 10_000] {
            let values: Vec<u8> = (0..n).map(|i| (i * 7 + 3) as u8).collect();
            let mut out = Vec::new();
            data_array(&mut out, "UInt8", "a", 1, n, values.iter().map(|&b| [b])).unwrap();
            let mut raw = (n as u64).to_le_bytes().to_vec();
            raw.extend(&values);
            use base64::Engine;
            let expect = format!(
                "<DataArray type=\"UInt8\" Name=\"a\" format=\"binary\">{}</DataArray>\n",
                base64::engine::general_purpose::STANDARD.encode(raw)
            );
            assert_eq!(String::from_utf8(out).unwrap(), expect, "{n} bytes");
        }
        // A count that does not match the values is an error, not a file with a wrong length.
        let mut out = Vec::new();
        let err = data_array(&mut out, "UInt8", "a", 1, 3, [[1u8], [2]].into_iter()).unwrap_err();
        assert!(err.to_string().contains("2 values, not 3"), "{err}");
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
        let expect = array(
            "Float64",
            "strain",
            [1.0, -0.5, f64::NAN].map(f64::to_le_bytes),
        );
        assert!(vtu.contains(&expect), "{vtu}");
        // Offsets 2, 4 for the lines, 7 for the triangle.
        let expect = array("Int64", "offsets", [2i64, 4, 7].map(i64::to_le_bytes));
        assert!(vtu.contains(&expect), "{vtu}");
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
