//! CSV: `frame,time,particle,x,y,z,vx,vy,vz`, one row per particle and frame. Numbers are
//! printed in Rust's shortest round-trip form, so they parse back to the same f64.

use std::io::{BufWriter, Write};

use super::{Frame, FrameSink, Header};

/// Writes CSV.
pub struct CsvSink<'w> {
    out: BufWriter<Box<dyn Write + 'w>>,
}

impl<'w> CsvSink<'w> {
    /// A sink writing to `out`.
    pub fn new(out: Box<dyn Write + 'w>) -> Self {
        CsvSink {
            out: BufWriter::new(out),
        }
    }
}

impl FrameSink for CsvSink<'_> {
    fn header(&mut self, _header: &Header) -> std::io::Result<()> {
        writeln!(self.out, "frame,time,particle,x,y,z,vx,vy,vz")
    }

    fn frame(&mut self, f: &Frame<'_>) -> std::io::Result<()> {
        for (i, (x, v)) in f.positions.iter().zip(f.velocities).enumerate() {
            writeln!(
                self.out,
                "{},{},{i},{},{},{},{},{},{}",
                f.index, f.time, x.x, x.y, x.z, v.x, v.y, v.z
            )?;
        }
        self.out.flush()
    }

    fn wants_springs(&self) -> bool {
        false
    }

    fn finish(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}
