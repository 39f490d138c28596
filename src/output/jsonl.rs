//! JSON Lines: the header object, then one object per frame, each on its own line and flushed
//! whole.

use std::io::Write;

use glam::DVec3;
use serde::Serialize;

use super::{Frame, FrameSink, Header};

/// Writes JSON Lines.
pub struct JsonlSink<'w> {
    out: Box<dyn Write + 'w>,
    line: Vec<u8>,
}

impl<'w> JsonlSink<'w> {
    /// A sink writing to `out`.
    pub fn new(out: Box<dyn Write + 'w>) -> Self {
        JsonlSink {
            out,
            line: Vec::new(),
        }
    }

    fn write_line(&mut self, value: &impl Serialize) -> std::io::Result<()> {
        self.line.clear();
        serde_json::to_writer(&mut self.line, value)?;
        self.line.push(b'\n');
        self.out.write_all(&self.line)?;
        self.out.flush()
    }
}

#[derive(Serialize)]
struct EnergyRecord {
    kinetic: f64,
    gravitational: f64,
    elastic: f64,
}

#[derive(Serialize)]
struct FrameRecord<'a> {
    frame: u64,
    time: f64,
    positions: &'a [DVec3],
    velocities: &'a [DVec3],
    energy: EnergyRecord,
}

impl FrameSink for JsonlSink<'_> {
    fn header(&mut self, header: &Header) -> std::io::Result<()> {
        self.write_line(header)
    }

    fn frame(&mut self, f: &Frame<'_>) -> std::io::Result<()> {
        self.write_line(&FrameRecord {
            frame: f.index,
            time: f.time,
            positions: f.positions,
            velocities: f.velocities,
            energy: EnergyRecord {
                kinetic: f.energies.kinetic,
                gravitational: f.energies.gravitational,
                elastic: f.energies.elastic,
            },
        })
    }

    fn finish(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}
