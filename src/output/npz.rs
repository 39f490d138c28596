//! NPZ (a zip of `.npy` arrays, what `numpy.load` reads): `time [F]`, `positions [F,N,3]`,
//! `velocities [F,N,3]` (float64) and `springs [S,2]` (uint32).
//!
//! The frame count is only known at the end (a run may stop early), and `.npy` headers carry
//! the shape, so frames are spooled to two temporary files and the archive is written by
//! [`FrameSink::finish`]. Memory stays at one frame whatever the run's length.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Seek, SeekFrom, Write};

use npyz::WriterBuilder;
use zip::write::SimpleFileOptions;

use super::{Frame, FrameSink, Header};

/// Writes NPZ.
pub struct NpzSink<'w> {
    out: Option<Box<dyn Write + 'w>>,
    times: Vec<f64>,
    particles: usize,
    springs: Vec<[u32; 2]>,
    /// Spooled frames; taken by `finish`.
    spools: Option<(BufWriter<File>, BufWriter<File>)>,
}

impl<'w> NpzSink<'w> {
    /// A sink writing the archive to `out` when it finishes.
    pub fn new(out: Box<dyn Write + 'w>) -> io::Result<Self> {
        Ok(NpzSink {
            out: Some(out),
            times: Vec::new(),
            particles: 0,
            springs: Vec::new(),
            spools: Some((
                BufWriter::new(tempfile::tempfile()?),
                BufWriter::new(tempfile::tempfile()?),
            )),
        })
    }
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
    options: SimpleFileOptions,
) -> io::Result<()> {
    let mut file = spool.into_inner().map_err(|e| e.into_error())?;
    file.seek(SeekFrom::Start(0))?;
    zip.start_file(format!("{name}.npy"), options)
        .map_err(io::Error::other)?;
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
        self.particles = header.particles;
        self.springs = header.springs.clone();
        Ok(())
    }

    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        let Some((positions, velocities)) = &mut self.spools else {
            return Err(io::Error::other("frame after finish"));
        };
        self.times.push(f.time);
        spool(positions, f.positions)?;
        spool(velocities, f.velocities)
    }

    fn finish(&mut self) -> io::Result<()> {
        let (Some(mut out), Some((positions, velocities))) = (self.out.take(), self.spools.take())
        else {
            return Ok(());
        };
        // zip needs Seek; stage the archive in a temporary file, then copy it out.
        let mut zip = zip::ZipWriter::new(tempfile::tempfile()?);
        let frames = self.times.len() as u64;
        let n = self.particles as u64;
        let big = frames * n * 24 > u32::MAX as u64 / 2;
        let options = SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored)
            .large_file(big);
        zip.start_file("time.npy", options)
            .map_err(io::Error::other)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[frames])
            .writer(&mut zip)
            .begin_nd()?;
        w.extend(self.times.iter().copied())?;
        w.finish()?;
        copy_spooled(&mut zip, "positions", &[frames, n, 3], positions, options)?;
        copy_spooled(&mut zip, "velocities", &[frames, n, 3], velocities, options)?;
        zip.start_file("springs.npy", options)
            .map_err(io::Error::other)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[self.springs.len() as u64, 2])
            .writer(&mut zip)
            .begin_nd()?;
        w.extend(self.springs.iter().flatten().copied())?;
        w.finish()?;
        let mut archive = zip.finish().map_err(io::Error::other)?;
        archive.seek(SeekFrom::Start(0))?;
        io::copy(&mut archive, &mut out)?;
        out.flush()
    }
}
