//! PNG (`.png`, `image/png`): the images raytile renders and the ones it reads back, as
//! 8-bit RGB.
//!
//! Writing is always 8-bit RGB: a render streams rows through [`stream_writer`] (fast
//! compression, since the client is waiting), a difference image is encoded whole by
//! [`RgbImage::encode_png`] (balanced compression, since it is kept). [`PngReader`] reads
//! a server's band back under `render --servers`: the header first, so the wrong size is
//! refused before anything is decompressed. A student's PNG is read as every submitted
//! image is, by [`super::raster`], whose rules (16-bit rounding, no transparency) are the
//! grader's.

use std::io::{Cursor, Write};

/// The format's name (and file extension).
pub const NAME: &str = "png";

/// Its media type.
pub const MEDIA_TYPE: &str = "image/png";

/// The eight bytes every PNG starts with.
pub const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// An 8-bit RGB image, rows top to bottom, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height × 3` bytes.
    pub data: Vec<u8>,
}

impl RgbImage {
    /// An image from its pixels, row-major.
    pub fn from_pixels(width: u32, height: u32, pixels: &[[u8; 3]]) -> RgbImage {
        RgbImage {
            width,
            height,
            data: pixels.iter().flatten().copied().collect(),
        }
    }

    /// Its pixels, row-major.
    pub fn pixels(&self) -> Vec<[u8; 3]> {
        self.data
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect()
    }

    /// Pixel `(u, v)`.
    #[inline]
    pub fn get(&self, u: u32, v: u32) -> [u8; 3] {
        let k = 3 * (v as usize * self.width as usize + u as usize);
        [self.data[k], self.data[k + 1], self.data[k + 2]]
    }

    /// Sets pixel `(u, v)`.
    #[inline]
    pub fn set(&mut self, u: u32, v: u32, c: [u8; 3]) {
        let k = 3 * (v as usize * self.width as usize + u as usize);
        self.data[k..k + 3].copy_from_slice(&c);
    }

    /// Encodes as an 8-bit RGB PNG.
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let enc = encoder(
            &mut out,
            self.width,
            self.height,
            png::Compression::Balanced,
        );
        // Writing to memory fails only for an empty image or a size the data does not
        // match; both are programming errors here, and an empty result says so.
        let ok = enc
            .write_header()
            .and_then(|mut w| {
                w.write_image_data(&self.data)?;
                w.finish()
            })
            .is_ok();
        if ok { out } else { Vec::new() }
    }
}

/// How raytile writes every PNG: 8-bit RGB.
fn encoder<W: Write>(
    out: W,
    width: u32,
    height: u32,
    compression: png::Compression,
) -> png::Encoder<'static, W> {
    let mut enc = png::Encoder::new(out, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(compression);
    enc
}

/// Writes the header of a `width × height` PNG to `out` and returns the writer to
/// stream its rows into, one after the other (3 bytes a pixel); the trailer is written
/// by [`png::StreamWriter::finish`].
pub fn stream_writer<W: Write>(
    out: W,
    width: u32,
    height: u32,
) -> Result<png::StreamWriter<'static, W>, png::EncodingError> {
    encoder(out, width, height, png::Compression::Fast)
        .write_header()
        .and_then(|w| w.into_stream_writer())
}

/// Why a PNG could not be decoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PngError {
    /// Decoding would take more memory than the caller allows.
    #[error("decoding it would need more than {} MiB", .limit_bytes >> 20)]
    TooLarge {
        /// The allowance.
        limit_bytes: usize,
    },
    /// The bytes are not a PNG, or a broken one: the decoder's own words.
    #[error("{0}")]
    Corrupt(String),
}

impl PngError {
    fn decoding(e: png::DecodingError, limit_bytes: usize) -> PngError {
        match e {
            png::DecodingError::LimitsExceeded => PngError::TooLarge { limit_bytes },
            e => PngError::Corrupt(e.to_string()),
        }
    }
}

/// A PNG whose header has been read: its size is known and nothing is decompressed yet.
pub struct PngReader<'a> {
    reader: png::Reader<Cursor<&'a [u8]>>,
    limit_bytes: usize,
}

impl<'a> PngReader<'a> {
    /// Reads the signature and the header of `bytes`; decoding may use at most
    /// `limit_bytes` of memory.
    pub fn new(bytes: &'a [u8], limit_bytes: usize) -> Result<PngReader<'a>, PngError> {
        let mut dec =
            png::Decoder::new_with_limits(Cursor::new(bytes), png::Limits { bytes: limit_bytes });
        dec.set_transformations(png::Transformations::normalize_to_color8());
        let reader = dec
            .read_info()
            .map_err(|e| PngError::decoding(e, limit_bytes))?;
        Ok(PngReader {
            reader,
            limit_bytes,
        })
    }

    /// Its width and height.
    pub fn size(&self) -> (u32, u32) {
        self.reader.info().size()
    }

    /// Whether it is stored as 8-bit RGB, as raytile writes PNGs (then decoding converts
    /// nothing).
    pub fn is_rgb8(&self) -> bool {
        let info = self.reader.info();
        (info.color_type, info.bit_depth) == (png::ColorType::Rgb, png::BitDepth::Eight)
    }

    /// Decodes the image into 8-bit RGB.
    pub fn decode(mut self) -> Result<RgbImage, PngError> {
        let limit_bytes = self.limit_bytes;
        let size = self
            .reader
            .output_buffer_size()
            .filter(|&n| n <= limit_bytes)
            .ok_or(PngError::TooLarge { limit_bytes })?;
        let mut buf = vec![0; size];
        let info = self
            .reader
            .next_frame(&mut buf)
            .map_err(|e| PngError::decoding(e, limit_bytes))?;
        buf.truncate(info.buffer_size());
        let (w, h) = (info.width, info.height);
        let channels = match info.color_type {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            png::ColorType::Rgba => 4,
            png::ColorType::Indexed => {
                return Err(PngError::Corrupt(
                    "the palette could not be expanded".into(),
                ));
            }
        };
        if info.bit_depth != png::BitDepth::Eight {
            return Err(PngError::Corrupt(format!(
                "unexpected bit depth {:?} after conversion to 8 bits",
                info.bit_depth
            )));
        }
        let stride = info.line_size;
        let mut data = Vec::with_capacity(w as usize * h as usize * 3);
        for row in buf.chunks(stride.max(1)).take(h as usize) {
            for px in row.chunks_exact(channels).take(w as usize) {
                match channels {
                    1 | 2 => data.extend_from_slice(&[px[0], px[0], px[0]]),
                    _ => data.extend_from_slice(&px[..3]),
                }
            }
        }
        if data.len() != w as usize * h as usize * 3 {
            return Err(PngError::Corrupt("the image data is truncated".into()));
        }
        Ok(RgbImage {
            width: w,
            height: h,
            data,
        })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A PNG written by the `png` crate's encoder: the other readers' tests use it too.
    pub(crate) fn encode(
        w: u32,
        h: u32,
        ct: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
    ) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(ct);
        enc.set_depth(depth);
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(data).unwrap();
        wr.finish().unwrap();
        out
    }

    #[test]
    fn rgb_round_trip_and_every_colour_type_as_rgb8() {
        let img = RgbImage {
            width: 2,
            height: 1,
            data: vec![1, 2, 3, 250, 251, 252],
        };
        let bytes = img.encode_png();
        let r = PngReader::new(&bytes, 1 << 20).unwrap();
        assert_eq!(r.decode().unwrap(), img);
        let wide = encode(
            1,
            1,
            png::ColorType::Rgba,
            png::BitDepth::Sixteen,
            &[0x12, 0x34, 0xab, 0xcd, 0xff, 0xff, 0, 0],
        );
        let r = PngReader::new(&wide, 1 << 20).unwrap();
        assert!(!r.is_rgb8());
        assert_eq!(r.decode().unwrap().data, vec![0x12, 0xab, 0xff]);
    }

    #[test]
    fn truncated_files_and_huge_headers_are_errors() {
        let img = RgbImage {
            width: 30,
            height: 30,
            data: vec![7; 2700],
        };
        let png = img.encode_png();
        let e = PngReader::new(&png[..png.len() / 2], 1 << 20)
            .and_then(PngReader::decode)
            .unwrap_err();
        assert!(matches!(e, PngError::Corrupt(_)), "{e}");
        assert!(matches!(
            PngReader::new(b"hello", 1 << 20).map(|r| r.size()),
            Err(PngError::Corrupt(_))
        ));
        // A 1 × 1 image whose header is patched to claim 60000 × 60000 pixels.
        let mut png = RgbImage {
            width: 1,
            height: 1,
            data: vec![1, 2, 3],
        }
        .encode_png();
        png[16..20].copy_from_slice(&60000u32.to_be_bytes());
        png[20..24].copy_from_slice(&60000u32.to_be_bytes());
        // Keep the chunk valid: CRC-32 of the type and data.
        let mut crc = !0u32;
        for &b in &png[12..29] {
            crc ^= b as u32;
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        png[29..33].copy_from_slice(&(!crc).to_be_bytes());
        let r = PngReader::new(&png, 64 << 20).unwrap();
        assert_eq!(r.size(), (60000, 60000));
        let e = r.decode().unwrap_err();
        assert!(e.to_string().contains("more than 64 MiB"), "{e}");
    }

    #[test]
    fn a_streamed_image_reads_back_and_its_header_comes_first() {
        // The stream owns its writer; this one leaves the bytes behind.
        #[derive(Clone, Default)]
        struct Shared(std::rc::Rc<std::cell::RefCell<Vec<u8>>>);
        impl Write for Shared {
            fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
                self.0.borrow_mut().write(buf)
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let shared = Shared::default();
        let mut s = stream_writer(shared.clone(), 2, 2).unwrap();
        s.write_all(&[1, 2, 3, 4, 5, 6]).unwrap();
        s.write_all(&[7, 8, 9, 10, 11, 12]).unwrap();
        s.finish().unwrap();
        let out = shared.0.take();
        let r = PngReader::new(&out, 1 << 20).unwrap();
        assert_eq!(r.size(), (2, 2));
        assert!(r.is_rgb8());
        let img = r.decode().unwrap();
        assert_eq!(img.data, (1..=12).collect::<Vec<u8>>());
        assert_eq!(img.pixels()[3], [10, 11, 12]);
        let grey = encode(1, 1, png::ColorType::Grayscale, png::BitDepth::Eight, &[5]);
        assert!(!PngReader::new(&grey, 1 << 20).unwrap().is_rgb8());
    }
}
