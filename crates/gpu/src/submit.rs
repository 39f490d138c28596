//! [`Submitter`]: command encoders, submissions, read-backs, and the solver's record of device
//! failures.
//!
//! A device failure (validation outside an error scope, a lost device, a read-back that never
//! completes) is recorded once and reported again by every later call: after it nothing the
//! device computes can be trusted.

use std::sync::Arc;
use std::sync::mpsc;
use std::time::Duration;

use softbody_scene::StepError;

use crate::device::Gpu;

/// How often a read-back that is not mapped yet polls the device.
const MAP_POLL: Duration = Duration::from_millis(1);
/// How long a read-back waits for its mapping after its submission is done.
const MAP_WAIT: Duration = Duration::from_secs(60);

/// Encodes, submits and reads back for one solver.
pub(crate) struct Submitter {
    gpu: Arc<Gpu>,
    /// Mappable; grown on demand.
    readback: wgpu::Buffer,
    /// The first device failure.
    failed: Option<String>,
}

impl Submitter {
    /// A submitter with a read-back buffer of `bytes` (it grows when a read needs more).
    pub fn new(gpu: Arc<Gpu>, bytes: u64) -> Submitter {
        Submitter {
            readback: readback_buffer(&gpu.device, bytes),
            gpu,
            failed: None,
        }
    }

    /// Bytes of the read-back buffer.
    pub fn readback_bytes(&self) -> u64 {
        self.readback.size()
    }

    /// The queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.gpu.queue
    }

    /// A new command encoder.
    pub fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    /// `encode` into one compute pass of a new command encoder.
    pub fn encode_pass(
        &self,
        label: &str,
        encode: impl FnOnce(&mut wgpu::ComputePass<'_>),
    ) -> wgpu::CommandEncoder {
        let mut encoder = self.encoder(label);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(label),
                timestamp_writes: None,
            });
            encode(&mut pass);
        }
        encoder
    }

    /// Submits `encoder` without waiting.
    pub fn submit(&self, encoder: wgpu::CommandEncoder) {
        self.gpu.queue.submit([encoder.finish()]);
    }

    /// Ok, or the recorded device failure.
    pub fn healthy(&mut self) -> Result<(), StepError> {
        if self.failed.is_none() {
            self.failed = self.gpu.errors.get();
        }
        match &self.failed {
            Some(e) => Err(StepError::Device(format!("{e} (on {})", self.gpu.name()))),
            None => Ok(()),
        }
    }

    /// Records `message` as the device failure (unless one is recorded) and reports it.
    pub fn fail(&mut self, message: String) -> StepError {
        let failed = self.failed.get_or_insert(message);
        StepError::Device(format!("{failed} (on {})", self.gpu.name()))
    }

    /// Waits until everything submitted has run.
    pub fn wait(&mut self) -> Result<(), StepError> {
        self.healthy()?;
        if let Err(e) = self.gpu.device.poll(wgpu::PollType::wait_indefinitely()) {
            self.healthy()?;
            return Err(self.fail(format!("the GPU did not finish its work: {e}")));
        }
        self.healthy()
    }

    /// Submits `encoder` after appending copies of `sources` (buffer, bytes) into the read-back
    /// buffer, waits, and returns the bytes, in order.
    pub fn submit_and_read(
        &mut self,
        mut encoder: wgpu::CommandEncoder,
        sources: &[(&wgpu::Buffer, u64)],
    ) -> Result<Vec<u8>, StepError> {
        let total: u64 = sources.iter().map(|&(_, bytes)| bytes).sum();
        if total > self.readback.size() {
            self.readback = readback_buffer(&self.gpu.device, total);
        }
        let mut offset = 0;
        for &(buffer, bytes) in sources {
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(buffer, 0, &self.readback, offset, bytes);
                offset += bytes;
            }
        }
        let index = self.gpu.queue.submit([encoder.finish()]);
        if offset == 0 {
            return Ok(Vec::new());
        }
        let readback = self.readback.clone();
        let slice = readback.slice(0..offset);
        let (sender, receiver) = mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        if let Err(e) = self.gpu.device.poll(wgpu::PollType::Wait {
            submission_index: Some(index),
            timeout: None,
        }) {
            self.healthy()?;
            return Err(self.fail(format!("the GPU did not finish its work: {e}")));
        }
        // The map callback runs in whichever thread polls the device next (another solver's,
        // when solvers share it): wait for it, polling meanwhile.
        let mut waited = Duration::ZERO;
        let mapped = loop {
            match receiver.recv_timeout(MAP_POLL) {
                Ok(result) => break Some(result),
                Err(mpsc::RecvTimeoutError::Timeout) if waited < MAP_WAIT => {
                    waited += MAP_POLL;
                    let _ = self.gpu.device.poll(wgpu::PollType::Poll);
                }
                Err(_) => break None,
            }
        };
        self.healthy()?;
        match mapped {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(self.fail(format!("cannot read results back: {e}"))),
            None => return Err(self.fail("the read-back never completed".to_owned())),
        }
        let bytes = match slice.get_mapped_range() {
            Ok(view) => view.to_vec(),
            Err(e) => return Err(self.fail(format!("cannot read results back: {e}"))),
        };
        readback.unmap();
        Ok(bytes)
    }
}

fn readback_buffer(device: &wgpu::Device, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: bytes.max(8).next_multiple_of(8),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}
