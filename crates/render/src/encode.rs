//! Pictures and their files: 8-bit RGB images, PNG stills and animated GIFs.
//!
//! GIF holds at most 256 colours per frame: each frame gets its own palette from NeuQuant
//! (the `gif` crate's `Frame::from_rgb_speed`, a deterministic neural-net quantizer), and the
//! frames are shown 1/frame_rate apart in GIF's hundredths of a second, looping forever. Each
//! delay is rounded so that the first k pictures take round(100·k/frame_rate) hundredths in all
//! (at 30 pictures/s: 3, 4, 3, 3, 4, 3, …, never drifting from the simulated time), but is at
//! least 2 hundredths, since viewers slow shorter delays down: above 50 pictures/s a GIF plays
//! slower than real time.

use std::io::{self, Write};

/// An 8-bit RGB picture, rows from the top, three bytes per pixel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    width: u32,
    height: u32,
    pixels: Vec<u8>,
}

impl Image {
    /// An image from its bytes (`width · height · 3` of them, rows from the top).
    ///
    /// # Panics
    /// If `pixels` has another length (a programming error).
    pub fn from_rows(width: u32, height: u32, pixels: Vec<u8>) -> Image {
        assert_eq!(pixels.len(), width as usize * height as usize * 3);
        Image {
            width,
            height,
            pixels,
        }
    }

    /// Width, pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height, pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The RGB bytes, rows from the top.
    pub fn as_bytes(&self) -> &[u8] {
        &self.pixels
    }

    /// The colour of pixel (x, y), x from the left, y from the top.
    ///
    /// # Panics
    /// If the pixel is outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        assert!(x < self.width && y < self.height);
        let at = 3 * (y as usize * self.width as usize + x as usize);
        [self.pixels[at], self.pixels[at + 1], self.pixels[at + 2]]
    }

    /// Sets pixel (x, y) to `color`; a pixel outside the image is left out.
    pub fn set_pixel(&mut self, x: u32, y: u32, color: [u8; 3]) {
        if x < self.width && y < self.height {
            let at = 3 * (y as usize * self.width as usize + x as usize);
            self.pixels[at..at + 3].copy_from_slice(&color);
        }
    }

    /// Writes the image as a PNG file (8-bit RGB).
    pub fn write_png<W: Write>(&self, out: W) -> io::Result<()> {
        let mut encoder = png::Encoder::new(out, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(io::Error::other)?;
        writer
            .write_image_data(&self.pixels)
            .map_err(io::Error::other)?;
        writer.finish().map_err(io::Error::other)
    }
}

/// An animated GIF being written, frame by frame.
pub struct GifWriter<W: Write> {
    encoder: gif::Encoder<W>,
    width: u16,
    height: u16,
    /// Pictures per second.
    frame_rate: f64,
    /// Pictures written so far, and the hundredths of a second their delays add up to.
    pictures: u64,
    shown: u64,
}

impl<W: Write> std::fmt::Debug for GifWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GifWriter")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("frame_rate", &self.frame_rate)
            .field("pictures", &self.pictures)
            .finish_non_exhaustive()
    }
}

/// NeuQuant's sampling step: 1 is slowest and best, 30 fastest; 10 is the usual compromise.
const QUANTIZER_SPEED: i32 = 10;

fn gif_error(e: gif::EncodingError) -> io::Error {
    match e {
        gif::EncodingError::Io(e) => e,
        e => io::Error::other(e),
    }
}

impl<W: Write> GifWriter<W> {
    /// Starts a looping GIF of `width` × `height` pictures (each at most 65,535) shown at
    /// `frame_rate` pictures per second.
    pub fn new(out: W, width: u32, height: u32, frame_rate: f64) -> io::Result<GifWriter<W>> {
        let side = |v: u32| {
            u16::try_from(v).map_err(|_| {
                io::Error::new(io::ErrorKind::InvalidInput, "GIF sides are at most 65535")
            })
        };
        let (width, height) = (side(width)?, side(height)?);
        let mut encoder = gif::Encoder::new(out, width, height, &[]).map_err(gif_error)?;
        encoder
            .set_repeat(gif::Repeat::Infinite)
            .map_err(gif_error)?;
        Ok(GifWriter {
            encoder,
            width,
            height,
            frame_rate: if frame_rate.is_finite() && frame_rate > 0.0 {
                frame_rate
            } else {
                10.0
            },
            pictures: 0,
            shown: 0,
        })
    }

    /// The delay after the next picture, hundredths of a second: what brings the pictures'
    /// total to round(100·k/frame_rate), at least 2.
    fn next_delay(&self) -> u16 {
        let due = (100.0 * (self.pictures + 1) as f64 / self.frame_rate).round() as u64;
        due.saturating_sub(self.shown).clamp(2, u64::from(u16::MAX)) as u16
    }

    /// Appends a picture (the size given to [`GifWriter::new`]).
    pub fn add(&mut self, image: &Image) -> io::Result<()> {
        if (image.width, image.height) != (u32::from(self.width), u32::from(self.height)) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "a GIF's pictures must all have the same size",
            ));
        }
        let mut frame =
            gif::Frame::from_rgb_speed(self.width, self.height, &image.pixels, QUANTIZER_SPEED);
        frame.delay = self.next_delay();
        self.encoder.write_frame(&frame).map_err(gif_error)?;
        self.pictures += 1;
        self.shown += u64::from(frame.delay);
        Ok(())
    }

    /// Ends the file and returns the writer.
    pub fn finish(self) -> io::Result<W> {
        self.encoder.into_inner().map_err(gif_error)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_and_gif_round_trip() {
        let pixels: Vec<u8> = (0..6 * 4 * 3).map(|k| (k * 7 % 256) as u8).collect();
        let image = Image::from_rows(6, 4, pixels.clone());
        assert_eq!(image.pixel(1, 0), [21, 28, 35]);
        let mut png_bytes = Vec::new();
        image.write_png(&mut png_bytes).unwrap();
        let decoder = png::Decoder::new(io::Cursor::new(png_bytes));
        let mut reader = decoder.read_info().unwrap();
        let mut back = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut back).unwrap();
        assert_eq!((info.width, info.height), (6, 4));
        assert_eq!(&back[..info.buffer_size()], &pixels[..]);

        let mut gif_writer = GifWriter::new(Vec::new(), 6, 4, 30.0).unwrap();
        for _ in 0..3 {
            gif_writer.add(&image).unwrap();
        }
        assert!(gif_writer.add(&Image::from_rows(1, 1, vec![0; 3])).is_err());
        let bytes = gif_writer.finish().unwrap();
        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options.read_info(io::Cursor::new(bytes)).unwrap();
        let mut delays = Vec::new();
        while let Some(frame) = decoder.read_next_frame().unwrap() {
            assert_eq!((frame.width, frame.height), (6, 4));
            delays.push(frame.delay);
        }
        assert_eq!(
            delays,
            [3, 4, 3],
            "a tenth of a second for 3 pictures at 30/s"
        );
    }

    /// The delays add up to the simulated time, to the nearest hundredth, after every picture
    /// (at up to 50 pictures per second; faster ones get the 2-hundredth minimum).
    #[test]
    fn gif_delays_add_up_to_the_simulated_time() {
        let image = Image::from_rows(1, 1, vec![0; 3]);
        for frame_rate in [7.0, 24.0, 29.97, 30.0, 50.0, 60.0] {
            let mut gif = GifWriter::new(Vec::new(), 1, 1, frame_rate).unwrap();
            let mut shown = 0u64;
            for k in 1..=200u64 {
                let delay = gif.next_delay();
                gif.add(&image).unwrap();
                shown += u64::from(delay);
                let due = (100.0 * k as f64 / frame_rate).round() as u64;
                if frame_rate <= 50.0 {
                    assert_eq!(shown, due, "{frame_rate}/s after {k} pictures");
                } else {
                    assert_eq!(delay, 2, "{frame_rate}/s");
                }
            }
        }
    }
}
