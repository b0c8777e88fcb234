//! 8-bit RGB images as grading sees them: decoding any PNG the `png` crate reads into
//! RGB (alpha dropped), encoding one, and shrinking a difference image so that failing
//! pixels stay visible.

use std::io::Cursor;

use super::GradeError;

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

    /// Decodes a PNG of any bit depth and colour type into 8-bit RGB: 16-bit samples keep
    /// their high byte, palettes and low bit depths are expanded, grey is copied to all
    /// three channels and alpha is dropped (not composited).
    ///
    /// With `expected` (the scene's `width × height`), a PNG of another size is refused
    /// from its header, before anything is decompressed: a small file cannot make the
    /// grader allocate more than that frame needs.
    pub fn decode_png(bytes: &[u8], expected: Option<(u32, u32)>) -> Result<RgbImage, GradeError> {
        if !bytes.starts_with(PNG_SIGNATURE) {
            return Err(GradeError::NotPng);
        }
        let limit = match expected {
            // The widest legitimate layout: 16-bit RGBA, 8 bytes a pixel, plus row filters.
            Some((w, h)) => (w as usize)
                .saturating_mul(h as usize)
                .saturating_mul(8)
                .saturating_add(h as usize)
                .saturating_add(1 << 20),
            None => DEFAULT_DECODE_BYTES,
        };
        let corrupt = |e: png::DecodingError| match e {
            png::DecodingError::LimitsExceeded => GradeError::CorruptPng(format!(
                "decoding it would need more than {} MiB",
                limit >> 20
            )),
            e => GradeError::CorruptPng(e.to_string()),
        };
        let mut dec =
            png::Decoder::new_with_limits(Cursor::new(bytes), png::Limits { bytes: limit });
        dec.set_transformations(png::Transformations::normalize_to_color8());
        let mut reader = dec.read_info().map_err(corrupt)?;
        if let Some((ew, eh)) = expected {
            let (w, h) = reader.info().size();
            if (w, h) != (ew, eh) {
                return Err(GradeError::SizeMismatch {
                    width: w,
                    height: h,
                    expected_width: ew,
                    expected_height: eh,
                });
            }
        }
        let size = reader
            .output_buffer_size()
            .filter(|&n| n <= limit)
            .ok_or_else(|| {
                GradeError::CorruptPng(format!(
                    "decoding it would need more than {} MiB",
                    limit >> 20
                ))
            })?;
        let mut buf = vec![0; size];
        let info = reader.next_frame(&mut buf).map_err(corrupt)?;
        buf.truncate(info.buffer_size());
        let (w, h) = (info.width, info.height);
        let channels = match info.color_type {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            png::ColorType::Rgba => 4,
            png::ColorType::Indexed => {
                return Err(GradeError::CorruptPng(
                    "the palette could not be expanded".into(),
                ));
            }
        };
        if info.bit_depth != png::BitDepth::Eight {
            return Err(GradeError::CorruptPng(format!(
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
            return Err(GradeError::CorruptPng("the image data is truncated".into()));
        }
        Ok(RgbImage {
            width: w,
            height: h,
            data,
        })
    }

    /// Encodes as an 8-bit RGB PNG.
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, self.width, self.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Balanced);
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

    /// Halves the size (rounding up); a block with any `keep` pixel becomes `keep`, so
    /// failures marked in that colour survive every halving; other blocks are averaged.
    pub fn halve(&self, keep: [u8; 3]) -> RgbImage {
        let (w, h) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut out = RgbImage {
            width: w,
            height: h,
            data: vec![0; w as usize * h as usize * 3],
        };
        for v in 0..h {
            for u in 0..w {
                let mut sum = [0u32; 3];
                let mut n = 0;
                let mut marked = false;
                for (du, dv) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (x, y) = (2 * u + du, 2 * v + dv);
                    if x < self.width && y < self.height {
                        let c = self.get(x, y);
                        marked |= c == keep;
                        for k in 0..3 {
                            sum[k] += c[k] as u32;
                        }
                        n += 1;
                    }
                }
                let c = if marked {
                    keep
                } else {
                    [0, 1, 2].map(|k| ((sum[k] + n / 2) / n.max(1)) as u8)
                };
                out.set(u, v, c);
            }
        }
        out
    }
}

/// Memory a PNG may take to decode when its expected size is not known.
pub const DEFAULT_DECODE_BYTES: usize = 64 << 20;

/// The eight bytes every PNG starts with.
pub const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

#[cfg(test)]
mod tests {
    use super::*;

    fn encode(w: u32, h: u32, ct: png::ColorType, depth: png::BitDepth, data: &[u8]) -> Vec<u8> {
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
    fn rgb_round_trip() {
        let img = RgbImage {
            width: 2,
            height: 1,
            data: vec![1, 2, 3, 250, 251, 252],
        };
        assert_eq!(RgbImage::decode_png(&img.encode_png(), None).unwrap(), img);
    }

    #[test]
    fn rgba_grey_and_16_bit_become_rgb8() {
        let rgba = encode(
            1,
            1,
            png::ColorType::Rgba,
            png::BitDepth::Eight,
            &[9, 8, 7, 0],
        );
        assert_eq!(
            RgbImage::decode_png(&rgba, None).unwrap().data,
            vec![9, 8, 7]
        );
        let grey = encode(
            2,
            1,
            png::ColorType::Grayscale,
            png::BitDepth::Eight,
            &[5, 6],
        );
        assert_eq!(
            RgbImage::decode_png(&grey, None).unwrap().data,
            vec![5, 5, 5, 6, 6, 6]
        );
        let wide = encode(
            1,
            1,
            png::ColorType::Rgb,
            png::BitDepth::Sixteen,
            &[0x12, 0x34, 0xab, 0xcd, 0xff, 0xff],
        );
        assert_eq!(
            RgbImage::decode_png(&wide, None).unwrap().data,
            vec![0x12, 0xab, 0xff]
        );
        let bits = encode(
            8,
            1,
            png::ColorType::Grayscale,
            png::BitDepth::One,
            &[0b1000_0001],
        );
        let d = RgbImage::decode_png(&bits, None).unwrap().data;
        assert_eq!(&d[..3], &[255, 255, 255]);
        assert_eq!(&d[3..6], &[0, 0, 0]);
    }

    #[test]
    fn garbage_and_truncated_files_are_errors() {
        assert!(matches!(
            RgbImage::decode_png(b"hello", None),
            Err(GradeError::NotPng)
        ));
        let img = RgbImage {
            width: 30,
            height: 30,
            data: vec![7; 2700],
        };
        let png = img.encode_png();
        assert!(matches!(
            RgbImage::decode_png(&png[..png.len() / 2], None),
            Err(GradeError::CorruptPng(_))
        ));
    }

    #[test]
    fn a_huge_header_is_refused_before_decoding() {
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
        let e = RgbImage::decode_png(&png, Some((1, 1))).unwrap_err();
        assert!(
            matches!(
                e,
                GradeError::SizeMismatch {
                    width: 60000,
                    height: 60000,
                    ..
                }
            ),
            "{e}"
        );
        let e = RgbImage::decode_png(&png, None).unwrap_err();
        assert!(e.to_string().contains("more than 64 MiB"), "{e}");
    }

    #[test]
    fn halving_keeps_marked_pixels() {
        let mut img = RgbImage {
            width: 3,
            height: 3,
            data: vec![100; 27],
        };
        img.set(2, 2, [255, 0, 255]);
        let h = img.halve([255, 0, 255]);
        assert_eq!((h.width, h.height), (2, 2));
        assert_eq!(h.get(1, 1), [255, 0, 255]);
        assert_eq!(h.get(0, 0), [100, 100, 100]);
    }
}
