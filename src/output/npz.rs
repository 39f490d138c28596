//! NPZ (a zip of `.npy` arrays, what `numpy.load` reads): the frames — `time [F]`,
//! `positions [F,N,3]`, `velocities [F,N,3]`, `energy_kinetic`, `energy_gravitational`,
//! `energy_elastic [F]` (float64) — and what the run was, so that the archive describes itself:
//! `dt`, `frame_rate` (float64 scalars), `integrator`, `backend`, `device` (string scalars),
//! `masses [N]`, `springs [S,2]` (uint32), `rest_lengths`, `stiffness`, `damping [S]`,
//! `body_names [B]` (strings), `body_first`, `body_count [B]` (uint32), and `scene_text` (the
//! TOML of the scene that ran) and `scene_file` where the run had them. Strings are NumPy
//! unicode (`<U`), so `str(d["integrator"])` is `"rk4"`.
//!
//! The archive is staged in a temporary file (zip needs Seek) and copied to the output by
//! [`FrameSink::finish`]; it and the spools below are unnamed files (gone when closed, also
//! after a kill) in the staging directory: beside the destination ([`NpzSink::staged_in`]),
//! whose file system is the one that needs room for the archive, or `$TMPDIR` for a stream
//! ([`NpzSink::new`]). A failure there names the directory. What the run was goes in when the header comes, so that the sink keeps
//! none of it (the springs' arrays are 40 bytes a spring). The frame count is only known at the
//! end (a run may stop early), and `.npy` headers carry the shape, so frames are spooled to two
//! temporary files and go in at the end. Memory stays at one frame whatever the run's length.

use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use npyz::{DType, TypeStr, WriterBuilder};
use zip::write::SimpleFileOptions;

use super::{Frame, FrameSink, Header};

/// Writes NPZ.
pub struct NpzSink<'w> {
    out: Option<Box<dyn Write + 'w>>,
    times: Vec<f64>,
    /// Kinetic, gravitational and elastic energy of each frame.
    energies: [Vec<f64>; 3],
    /// The staged archive, buffered (npyz writes a value per call: unbuffered, a 100³ cube's
    /// 13 M springs took 100 s of write calls); opened by `header`.
    zip: Option<zip::ZipWriter<BufWriter<File>>>,
    /// Particles per frame, from the header.
    particles: u64,
    /// Spooled frames; taken by `finish`.
    spools: Option<(BufWriter<File>, BufWriter<File>)>,
    /// Where the archive and the spools are staged.
    staging: PathBuf,
}

impl<'w> NpzSink<'w> {
    /// A sink writing the archive to `out` when it finishes, staged in `$TMPDIR`.
    pub fn new(out: Box<dyn Write + 'w>) -> io::Result<Self> {
        Self::staged_in(std::env::temp_dir(), out)
    }

    /// A sink writing the archive to `out` when it finishes, staged in `dir` (the
    /// destination's directory).
    pub fn staged_in(dir: impl Into<PathBuf>, out: Box<dyn Write + 'w>) -> io::Result<Self> {
        let staging = dir.into();
        let spool = || {
            tempfile::tempfile_in(&staging)
                .map(BufWriter::new)
                .map_err(|e| in_staging(&staging, e))
        };
        let spools = Some((spool()?, spool()?));
        Ok(NpzSink {
            out: Some(out),
            times: Vec::new(),
            energies: Default::default(),
            zip: None,
            particles: 0,
            spools,
            staging,
        })
    }

    fn write_header(&mut self, header: &Header) -> io::Result<()> {
        let staged = tempfile::tempfile_in(&self.staging)?;
        let mut zip = zip::ZipWriter::new(BufWriter::new(staged));
        let n = header.particles as u64;
        let mut arrays = Arrays { zip: &mut zip };
        arrays.f64("dt", &[], &[header.dt])?;
        arrays.f64("frame_rate", &[], &[header.frame_rate])?;
        arrays.strings("integrator", &[], &[&header.integrator])?;
        arrays.strings("backend", &[], &[&header.backend])?;
        arrays.strings("device", &[], &[&header.device])?;
        arrays.f64("masses", &[n], &header.masses)?;
        let s = header.springs.len() as u64;
        arrays.u32("springs", &[s, 2], header.springs.iter().flatten())?;
        arrays.f64("rest_lengths", &[s], &header.rest)?;
        arrays.f64("stiffness", &[s], &header.stiffness)?;
        arrays.f64("damping", &[s], &header.damping)?;
        let b = header.bodies.len() as u64;
        let names: Vec<&str> = header.bodies.iter().map(|b| b.name.as_str()).collect();
        arrays.strings("body_names", &[b], &names)?;
        arrays.u32("body_first", &[b], header.bodies.iter().map(|b| &b.first))?;
        arrays.u32("body_count", &[b], header.bodies.iter().map(|b| &b.count))?;
        if let Some(text) = &header.scene_text {
            arrays.strings("scene_text", &[], &[text])?;
        }
        if let Some(file) = &header.scene {
            arrays.strings("scene_file", &[], &[file])?;
        }
        (self.zip, self.particles) = (Some(zip), n);
        Ok(())
    }

    /// Completes the staged archive with the frames' arrays, rewound to be copied out.
    fn complete(
        &mut self,
        mut zip: zip::ZipWriter<BufWriter<File>>,
        (positions, velocities): (BufWriter<File>, BufWriter<File>),
    ) -> io::Result<File> {
        let (frames, n) = (self.times.len() as u64, self.particles);
        let mut arrays = Arrays { zip: &mut zip };
        arrays.f64("time", &[frames], &self.times)?;
        copy_spooled(arrays.zip, "positions", &[frames, n, 3], positions)?;
        copy_spooled(arrays.zip, "velocities", &[frames, n, 3], velocities)?;
        let [kinetic, gravitational, elastic] = &self.energies;
        arrays.f64("energy_kinetic", &[frames], kinetic)?;
        arrays.f64("energy_gravitational", &[frames], gravitational)?;
        arrays.f64("energy_elastic", &[frames], elastic)?;
        let archive = zip.finish().map_err(io::Error::other)?;
        let mut archive = archive
            .into_inner()
            .map_err(io::IntoInnerError::into_error)?;
        archive.seek(SeekFrom::Start(0))?;
        Ok(archive)
    }
}

/// `e`, a failure in the staging directory `dir`, naming it.
fn in_staging(dir: &Path, e: io::Error) -> io::Error {
    io::Error::new(
        e.kind(),
        format!("cannot stage the NPZ arrays in {}: {e}", dir.display()),
    )
}

fn spool(to: &mut impl Write, values: &[glam::DVec3]) -> io::Result<()> {
    for v in values {
        for c in v.to_array() {
            to.write_all(&c.to_le_bytes())?;
        }
    }
    Ok(())
}

/// Writes one f64 array of `shape` read from a spool file into the archive.
fn copy_spooled<W: Write + Seek>(
    zip: &mut zip::ZipWriter<W>,
    name: &str,
    shape: &[u64],
    spool: BufWriter<File>,
) -> io::Result<()> {
    let mut file = spool.into_inner().map_err(|e| e.into_error())?;
    file.seek(SeekFrom::Start(0))?;
    start(zip, name, shape, 8)?;
    let mut writer = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut *zip)
        .begin_nd()?;
    let mut reader = BufReader::new(file);
    let mut buf = [0u8; 8];
    let count: u64 = shape.iter().product();
    for _ in 0..count {
        reader.read_exact(&mut buf)?;
        writer.push(&f64::from_le_bytes(buf))?;
    }
    writer.finish()
}

impl FrameSink for NpzSink<'_> {
    fn header(&mut self, header: &Header) -> io::Result<()> {
        self.write_header(header)
            .map_err(|e| in_staging(&self.staging, e))
    }

    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        let Some((positions, velocities)) = &mut self.spools else {
            return Err(io::Error::other("frame after finish"));
        };
        self.times.push(f.time);
        let e = f.energies;
        for (series, value) in self
            .energies
            .iter_mut()
            .zip([e.kinetic, e.gravitational, e.elastic])
        {
            series.push(value);
        }
        spool(positions, f.positions)
            .and_then(|()| spool(velocities, f.velocities))
            .map_err(|e| in_staging(&self.staging, e))
    }

    fn finish(&mut self) -> io::Result<()> {
        let (Some(mut out), Some(spools)) = (self.out.take(), self.spools.take()) else {
            return Ok(());
        };
        let Some(zip) = self.zip.take() else {
            return Err(io::Error::other("finish without a header"));
        };
        let archive = self
            .complete(zip, spools)
            .map_err(|e| in_staging(&self.staging, e))?;
        // Read here, written there: a failure of the output is the output's to name.
        let mut archive = BufReader::new(archive);
        loop {
            let chunk = archive
                .fill_buf()
                .map_err(|e| in_staging(&self.staging, e))?;
            if chunk.is_empty() {
                break;
            }
            out.write_all(chunk)?;
            let len = chunk.len();
            archive.consume(len);
        }
        out.flush()
    }
}

/// Starts the entry of array `name` of `shape` and elements of `size` bytes: stored (NumPy
/// maps stored entries), with zip64 sizes where it may pass 2 GiB.
fn start<W: Write + Seek>(
    zip: &mut zip::ZipWriter<W>,
    name: &str,
    shape: &[u64],
    size: u64,
) -> io::Result<()> {
    let bytes = shape.iter().product::<u64>() * size;
    let options = SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .large_file(bytes > u64::from(u32::MAX) / 2);
    zip.start_file(format!("{name}.npy"), options)
        .map_err(io::Error::other)
}

/// Writes whole arrays into the archive, one `.npy` entry each.
struct Arrays<'z, W: Write + Seek> {
    zip: &'z mut zip::ZipWriter<W>,
}

impl<W: Write + Seek> Arrays<'_, W> {
    fn f64(&mut self, name: &str, shape: &[u64], values: &[f64]) -> io::Result<()> {
        start(self.zip, name, shape, 8)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(shape)
            .writer(&mut *self.zip)
            .begin_nd()?;
        w.extend(values.iter().copied())?;
        w.finish()
    }

    fn u32<'a>(
        &mut self,
        name: &str,
        shape: &[u64],
        values: impl IntoIterator<Item = &'a u32>,
    ) -> io::Result<()> {
        start(self.zip, name, shape, 4)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(shape)
            .writer(&mut *self.zip)
            .begin_nd()?;
        w.extend(values.into_iter().copied())?;
        w.finish()
    }

    /// Strings as NumPy unicode (`<U` as wide as the longest, in characters): what
    /// `numpy.load` gives back as `str`.
    fn strings(&mut self, name: &str, shape: &[u64], values: &[&str]) -> io::Result<()> {
        let width = values
            .iter()
            .map(|v| v.chars().count())
            .max()
            .unwrap_or(0)
            .max(1);
        let dtype = DType::Plain(
            format!("<U{width}")
                .parse::<TypeStr>()
                .map_err(io::Error::other)?,
        );
        start(self.zip, name, shape, 4 * width as u64)?;
        let mut w = npyz::WriteOptions::<str>::new()
            .dtype(dtype)
            .shape(shape)
            .writer(&mut *self.zip)
            .begin_nd()?;
        for v in values {
            w.push(*v)?;
        }
        w.finish()
    }
}
