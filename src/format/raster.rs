//! Images as students' ray tracers write them, told apart by their content and decoded
//! under a memory limit: PNG, PPM and the other Netpbm maps (P1–P7), BMP, TGA and JPEG
//! into 8-bit RGB, PFM and OpenEXR into linear floats.
//!
//! Decoding is the `image` crate's (PFM, which it lacks, is [`super::pfm`]), with its
//! allocation limit set from the caller's [`DecodeLimits`]; the size is read from the
//! header and checked against the frame before anything is decompressed.
//!
//! How every image becomes the 8-bit RGB that is compared:
//!
//! - 8-bit samples are taken as they are; grey is copied to all three channels;
//!   palettes and bit depths below 8 are expanded (PNG, BMP, TGA), and a Netpbm maxval
//!   other than 255 or 65535 is scaled to the full range;
//! - 16-bit samples (PNG, PPM with maxval 65535) are rounded to the nearest 8-bit value,
//!   `round(v · 255 / 65535)`;
//! - alpha is not composited: every pixel must be opaque (alpha at its maximum), else
//!   the image is refused ([`ReadError::NotOpaque`]), because the grader cannot know
//!   what a transparent pixel should show;
//! - float images are not reduced: they are compared in linear radiance
//!   ([`crate::grade::compare::linear`]).

use std::io::Cursor;

use image::{DynamicImage, ImageDecoder};

use super::ReadError;
use super::linear::LinearImage;
use super::png::{PNG_SIGNATURE, RgbImage};
use super::{exr, pfm};

/// Memory an image may take to decode when the caller sets no limit and the frame is
/// not known.
pub const DEFAULT_DECODE_BYTES: usize = 64 << 20;

/// An image format a submission may be in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RasterFormat {
    /// PNG, any colour type and bit depth.
    Png,
    /// Netpbm: PPM (P3, P6), PGM (P2, P5), PBM (P1, P4), PAM (P7).
    Pnm,
    /// Windows bitmap.
    Bmp,
    /// Truevision TGA.
    Tga,
    /// JPEG (lossy: it rarely matches exactly).
    Jpeg,
    /// Portable Float Map, linear.
    Pfm,
    /// OpenEXR, linear.
    Exr,
}

impl RasterFormat {
    /// Every format, in the order the documentation lists them.
    pub const ALL: [RasterFormat; 7] = [
        RasterFormat::Png,
        RasterFormat::Pnm,
        RasterFormat::Bmp,
        RasterFormat::Tga,
        RasterFormat::Jpeg,
        RasterFormat::Pfm,
        RasterFormat::Exr,
    ];

    /// Its name in reports (`"png"`, `"ppm"`, `"bmp"`, `"tga"`, `"jpeg"`, `"pfm"`,
    /// `"exr"`).
    pub const fn name(self) -> &'static str {
        match self {
            RasterFormat::Png => super::png::NAME,
            RasterFormat::Pnm => "ppm",
            RasterFormat::Bmp => "bmp",
            RasterFormat::Tga => "tga",
            RasterFormat::Jpeg => "jpeg",
            RasterFormat::Pfm => pfm::NAME,
            RasterFormat::Exr => exr::NAME,
        }
    }

    /// Its name in sentences.
    pub const fn title(self) -> &'static str {
        match self {
            RasterFormat::Png => "PNG",
            RasterFormat::Pnm => "PPM",
            RasterFormat::Bmp => "BMP",
            RasterFormat::Tga => "TGA",
            RasterFormat::Jpeg => "JPEG",
            RasterFormat::Pfm => "PFM",
            RasterFormat::Exr => "OpenEXR",
        }
    }

    /// Whether it holds linear floats (compared before gamma and quantisation).
    pub const fn is_linear(self) -> bool {
        matches!(self, RasterFormat::Pfm | RasterFormat::Exr)
    }

    /// The format of a name or file extension (`ppm`, `pgm`, `pbm`, `pnm`, `pam`, `jpg`,
    /// `jpeg`, `tga`, …), case-insensitive.
    pub fn from_name(s: &str) -> Option<RasterFormat> {
        Some(match s.trim().to_ascii_lowercase().as_str() {
            "png" => RasterFormat::Png,
            "ppm" | "pgm" | "pbm" | "pnm" | "pam" => RasterFormat::Pnm,
            "bmp" | "dib" => RasterFormat::Bmp,
            "tga" | "targa" | "icb" | "vda" | "vst" => RasterFormat::Tga,
            "jpg" | "jpeg" | "jpe" | "jfif" => RasterFormat::Jpeg,
            "pfm" => RasterFormat::Pfm,
            "exr" => RasterFormat::Exr,
            _ => return None,
        })
    }

    /// The format of a media type (`image/png`, `image/x-portable-pixmap`, `image/bmp`,
    /// `image/x-tga`, `image/jpeg`, `image/x-exr`, …), parameters ignored.
    pub fn from_media_type(t: &str) -> Option<RasterFormat> {
        let essence = t
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        Some(match essence.as_str() {
            "image/png" => RasterFormat::Png,
            "image/x-portable-pixmap"
            | "image/x-portable-graymap"
            | "image/x-portable-bitmap"
            | "image/x-portable-anymap"
            | "image/x-portable-arbitrarymap" => RasterFormat::Pnm,
            "image/bmp" | "image/x-bmp" | "image/x-ms-bmp" => RasterFormat::Bmp,
            "image/x-tga" | "image/x-targa" | "image/tga" | "image/targa" => RasterFormat::Tga,
            "image/jpeg" | "image/jpg" | "image/pjpeg" => RasterFormat::Jpeg,
            "image/x-portable-floatmap" => RasterFormat::Pfm,
            exr::MEDIA_TYPE | "image/aces" => RasterFormat::Exr,
            _ => return None,
        })
    }

    /// The format `bytes` are in, told from their first bytes; `None` for anything that
    /// is no image.
    pub fn sniff(bytes: &[u8]) -> Option<RasterFormat> {
        if bytes.starts_with(PNG_SIGNATURE) {
            return Some(RasterFormat::Png);
        }
        if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
            return Some(RasterFormat::Jpeg);
        }
        if bytes.starts_with(exr::MAGIC) {
            return Some(RasterFormat::Exr);
        }
        if pfm::sniff(bytes) {
            return Some(RasterFormat::Pfm);
        }
        if matches!(bytes, [b'P', b'1'..=b'7', c, ..] if c.is_ascii_whitespace()) {
            return Some(RasterFormat::Pnm);
        }
        if is_bmp(bytes) {
            return Some(RasterFormat::Bmp);
        }
        if is_tga(bytes) {
            return Some(RasterFormat::Tga);
        }
        None
    }

    fn codec(self) -> image::ImageFormat {
        match self {
            RasterFormat::Png => image::ImageFormat::Png,
            RasterFormat::Pnm => image::ImageFormat::Pnm,
            RasterFormat::Bmp => image::ImageFormat::Bmp,
            RasterFormat::Tga => image::ImageFormat::Tga,
            RasterFormat::Jpeg => image::ImageFormat::Jpeg,
            RasterFormat::Pfm | RasterFormat::Exr => image::ImageFormat::OpenExr,
        }
    }
}

/// `BM`, then (after the 14-byte file header) the size of one of the DIB headers.
fn is_bmp(b: &[u8]) -> bool {
    b.len() >= 18
        && b.starts_with(b"BM")
        && matches!(
            u32::from_le_bytes([b[14], b[15], b[16], b[17]]),
            12 | 16 | 40 | 52 | 56 | 64 | 108 | 124
        )
}

/// TGA has no signature at its start: the 18-byte header must be a consistent one (a
/// colour map exactly for colour-mapped images, a known image type and pixel depth, a
/// size), or the file ends in the TGA 2.0 footer. Text never matches: its second byte
/// (the colour-map type) would have to be 0 or 1.
fn is_tga(b: &[u8]) -> bool {
    if b.ends_with(b"TRUEVISION-XFILE.\0") {
        return true;
    }
    if b.len() < 18 {
        return false;
    }
    let (map, kind, depth) = (b[1], b[2], b[16]);
    let mapped = matches!(kind, 1 | 9);
    let known = matches!(kind, 1 | 2 | 3 | 9 | 10 | 11);
    let size = u16::from_le_bytes([b[12], b[13]]) > 0 && u16::from_le_bytes([b[14], b[15]]) > 0;
    known && (map == 1) == mapped && map <= 1 && matches!(depth, 8 | 15 | 16 | 24 | 32) && size
}

/// What a decoder may take: the frame a submission must match (checked from the header,
/// before decoding) and the memory the decoded image may occupy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecodeLimits {
    /// The scene's `width × height`, when known.
    pub frame: Option<(u32, u32)>,
    /// Bytes the decoded image (and the decoder's buffers) may take.
    pub max_bytes: usize,
}

impl DecodeLimits {
    /// The limits for a frame of `width × height`: room for its widest layout (16-bit
    /// RGBA or 32-bit float RGBA, 16 bytes a pixel) and a megabyte for the decoder.
    pub fn for_frame(width: u32, height: u32) -> DecodeLimits {
        DecodeLimits {
            frame: Some((width, height)),
            max_bytes: (width as usize)
                .saturating_mul(height as usize)
                .saturating_mul(16)
                .saturating_add(1 << 20),
        }
    }
}

impl Default for DecodeLimits {
    fn default() -> Self {
        DecodeLimits {
            frame: None,
            max_bytes: DEFAULT_DECODE_BYTES,
        }
    }
}

/// A decoded image: 8-bit RGB, or linear floats.
#[derive(Debug, Clone, PartialEq)]
pub enum Raster {
    /// From PNG, PPM, BMP, TGA or JPEG.
    Rgb8(RgbImage),
    /// From PFM or OpenEXR.
    Linear(LinearImage),
}

/// A decoder's error as a [`ReadError`] in the format's words.
fn decoding(format: RasterFormat, limit_bytes: usize) -> impl Fn(image::ImageError) -> ReadError {
    move |e| {
        let message = match e {
            image::ImageError::Limits(_) => {
                return ReadError::TooLarge {
                    format: format.title(),
                    limit_bytes,
                };
            }
            image::ImageError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                "the file ends too early (it is truncated)".to_owned()
            }
            e => e.to_string(),
        };
        corrupt(format, message)
    }
}

fn corrupt(format: RasterFormat, message: String) -> ReadError {
    match format {
        RasterFormat::Png => ReadError::CorruptPng(message),
        f => ReadError::CorruptImage {
            format: f.title(),
            message,
        },
    }
}

/// Decodes `bytes` as `format` under `limits`.
pub fn decode(
    bytes: &[u8],
    format: RasterFormat,
    limits: &DecodeLimits,
) -> Result<Raster, ReadError> {
    if format == RasterFormat::Pfm {
        return pfm::read(bytes, limits.frame, limits.max_bytes).map(Raster::Linear);
    }
    if format == RasterFormat::Exr {
        exr::check_headers(bytes, limits.max_bytes)?;
    }
    let err = decoding(format, limits.max_bytes);
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), format.codec());
    let mut l = image::Limits::default();
    l.max_alloc = Some(limits.max_bytes as u64);
    reader.limits(l);
    let decoder = reader.into_decoder().map_err(&err)?;
    let (width, height) = decoder.dimensions();
    if let Some((ew, eh)) = limits.frame
        && (width, height) != (ew, eh)
    {
        return Err(ReadError::SizeMismatch {
            width,
            height,
            expected_width: ew,
            expected_height: eh,
        });
    }
    if decoder.total_bytes() > limits.max_bytes as u64 {
        return Err(ReadError::TooLarge {
            format: format.title(),
            limit_bytes: limits.max_bytes,
        });
    }
    let img = DynamicImage::from_decoder(decoder).map_err(&err)?;
    if format.is_linear() {
        exr::linear(img).map(Raster::Linear)
    } else {
        to_rgb8(img).map(Raster::Rgb8)
    }
}

/// 16 bits to 8, rounded: `round(v · 255 / 65535)`.
#[inline]
fn round16(v: u16) -> u8 {
    ((v as u32 * 255 + 32767) / 65535) as u8
}

/// Samples with `channels` per pixel (1 grey, 2 grey and alpha, 3 RGB, 4 RGBA) as 8-bit
/// RGB; `None` is the first pixel that is not opaque, with its alpha.
fn reduce<T: Copy + PartialEq + ToString>(
    samples: &[T],
    channels: usize,
    opaque: T,
    to8: impl Fn(T) -> u8,
    out: &mut Vec<u8>,
) -> Result<(), (usize, String)> {
    for (k, px) in samples.chunks_exact(channels).enumerate() {
        if channels.is_multiple_of(2) && px[channels - 1] != opaque {
            return Err((k, px[channels - 1].to_string()));
        }
        if channels < 3 {
            let g = to8(px[0]);
            out.extend_from_slice(&[g, g, g]);
        } else {
            out.extend_from_slice(&[to8(px[0]), to8(px[1]), to8(px[2])]);
        }
    }
    Ok(())
}

/// The comparison's 8-bit RGB of an image (the rules are in the module's comment).
fn to_rgb8(img: DynamicImage) -> Result<RgbImage, ReadError> {
    let (width, height) = (img.width(), img.height());
    let mut data = Vec::with_capacity(width as usize * height as usize * 3);
    let id = |x: u8| x;
    let reduced = match img {
        DynamicImage::ImageRgb8(b) => {
            data = b.into_raw();
            Ok(())
        }
        DynamicImage::ImageLuma8(b) => reduce(b.as_raw(), 1, 0, id, &mut data),
        DynamicImage::ImageLumaA8(b) => reduce(b.as_raw(), 2, u8::MAX, id, &mut data),
        DynamicImage::ImageRgba8(b) => reduce(b.as_raw(), 4, u8::MAX, id, &mut data),
        DynamicImage::ImageLuma16(b) => reduce(b.as_raw(), 1, 0, round16, &mut data),
        DynamicImage::ImageLumaA16(b) => reduce(b.as_raw(), 2, u16::MAX, round16, &mut data),
        DynamicImage::ImageRgb16(b) => reduce(b.as_raw(), 3, 0, round16, &mut data),
        DynamicImage::ImageRgba16(b) => reduce(b.as_raw(), 4, u16::MAX, round16, &mut data),
        // Float layouts come only from float formats, which are not reduced; should a
        // codec produce another, its 16-bit RGBA is as close as any.
        other => {
            let b = other.into_rgba16();
            reduce(b.as_raw(), 4, u16::MAX, round16, &mut data)
        }
    };
    if let Err((k, alpha)) = reduced {
        return Err(ReadError::NotOpaque {
            u: (k % width.max(1) as usize) as u32,
            v: (k / width.max(1) as usize) as u32,
            alpha,
        });
    }
    Ok(RgbImage {
        width,
        height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::ImageEncoder;

    fn none() -> DecodeLimits {
        DecodeLimits::default()
    }

    fn rgb8(bytes: &[u8]) -> Result<RgbImage, ReadError> {
        let f = RasterFormat::sniff(bytes).ok_or(ReadError::NotPng)?;
        match decode(bytes, f, &none())? {
            Raster::Rgb8(i) => Ok(i),
            Raster::Linear(_) => panic!("linear"),
        }
    }

    use crate::format::png::tests::encode as png;

    #[test]
    fn png_of_every_colour_type_becomes_rgb8() {
        use png::{BitDepth, ColorType};
        let grey = png(2, 1, ColorType::Grayscale, BitDepth::Eight, &[5, 6]);
        assert_eq!(rgb8(&grey).unwrap().data, vec![5, 5, 5, 6, 6, 6]);
        let wide = png(
            1,
            1,
            ColorType::Rgb,
            BitDepth::Sixteen,
            &[0x12, 0x80, 0xab, 0x7f, 0xff, 0xff],
        );
        // 0x1280 = 4736 → 18.43 → 18; 0xab7f = 43903 → 170.83 → 171.
        assert_eq!(rgb8(&wide).unwrap().data, vec![18, 171, 255]);
        let bits = png(8, 1, ColorType::Grayscale, BitDepth::One, &[0b1000_0001]);
        let d = rgb8(&bits).unwrap().data;
        assert_eq!((&d[..3], &d[3..6]), (&[255u8; 3][..], &[0u8; 3][..]));
        let opaque = png(1, 1, ColorType::Rgba, BitDepth::Eight, &[9, 8, 7, 255]);
        assert_eq!(rgb8(&opaque).unwrap().data, vec![9, 8, 7]);
        let grey_alpha = png(
            2,
            1,
            ColorType::GrayscaleAlpha,
            BitDepth::Sixteen,
            &[0, 0, 255, 255, 255, 255, 0, 1],
        );
        let e = rgb8(&grey_alpha).unwrap_err();
        assert_eq!(
            e,
            ReadError::NotOpaque {
                u: 1,
                v: 0,
                alpha: "1".into()
            }
        );
        let mut out = Vec::new();
        let mut e = png::Encoder::new(&mut out, 2, 1);
        e.set_color(ColorType::Indexed);
        e.set_depth(BitDepth::Eight);
        e.set_palette(vec![10, 20, 30, 40, 50, 60]);
        let mut w = e.write_header().unwrap();
        w.write_image_data(&[1, 0]).unwrap();
        w.finish().unwrap();
        assert_eq!(rgb8(&out).unwrap().data, vec![40, 50, 60, 10, 20, 30]);
    }

    #[test]
    fn ppm_ascii_with_comments_binary_and_16_bit() {
        // As "Ray Tracing in One Weekend" prints it, with a comment and ragged spacing.
        let p3 = b"P3\n# made by hand\n2 1\n255\n 255 0 0\n0   128\t255\n";
        assert_eq!(rgb8(p3).unwrap().data, vec![255, 0, 0, 0, 128, 255]);
        let mut p6 = b"P6 1 1 65535\n".to_vec();
        p6.extend_from_slice(&[0x12, 0x80, 0xff, 0xff, 0, 0]);
        assert_eq!(rgb8(&p6).unwrap().data, vec![18, 255, 0]);
        let p2 = b"P2 1 1 15 15\n";
        assert_eq!(rgb8(p2).unwrap().data, vec![255, 255, 255]);
        let e = rgb8(b"P6 2 2 255\n\x01\x02").unwrap_err();
        assert!(
            matches!(&e, ReadError::CorruptImage { format: "PPM", .. }),
            "{e}"
        );
        assert!(e.to_string().contains("truncated"), "{e}");
    }

    #[test]
    fn bmp_tga_and_jpeg_by_an_encoder_of_their_own() {
        let pixels = [200u8, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110];
        let mut bmp = Vec::new();
        image::codecs::bmp::BmpEncoder::new(&mut bmp)
            .write_image(&pixels, 2, 2, image::ExtendedColorType::Rgb8)
            .unwrap();
        assert_eq!(RasterFormat::sniff(&bmp), Some(RasterFormat::Bmp));
        assert_eq!(rgb8(&bmp).unwrap().data, pixels);
        let mut tga = Vec::new();
        image::codecs::tga::TgaEncoder::new(&mut tga)
            .write_image(&pixels, 2, 2, image::ExtendedColorType::Rgb8)
            .unwrap();
        assert_eq!(RasterFormat::sniff(&tga), Some(RasterFormat::Tga));
        assert_eq!(rgb8(&tga).unwrap().data, pixels);
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 100)
            .write_image(&[128; 8 * 8 * 3], 8, 8, image::ExtendedColorType::Rgb8)
            .unwrap();
        assert_eq!(RasterFormat::sniff(&jpeg), Some(RasterFormat::Jpeg));
        let d = rgb8(&jpeg).unwrap().data;
        assert!(d.iter().all(|&x| x.abs_diff(128) <= 1), "{d:?}");
        let e = rgb8(&jpeg[..jpeg.len() / 2]).unwrap_err();
        assert!(
            matches!(e, ReadError::CorruptImage { format: "JPEG", .. }),
            "{e}"
        );
    }

    #[test]
    fn exr_round_trip_and_alpha() {
        let img = LinearImage::from_pixels(2, 1, &[[0.25, 1.5, 0.0], [1e-4, 7.0, 0.5]]);
        let b = exr::write(&img).unwrap();
        assert_eq!(RasterFormat::sniff(&b), Some(RasterFormat::Exr));
        let back = decode(&b, RasterFormat::Exr, &DecodeLimits::for_frame(2, 1)).unwrap();
        assert_eq!(back, Raster::Linear(img));
        assert!(matches!(
            decode(&b, RasterFormat::Exr, &DecodeLimits::for_frame(1, 2)),
            Err(ReadError::SizeMismatch { width: 2, .. })
        ));
        let e = decode(&b[..b.len() - 8], RasterFormat::Exr, &none()).unwrap_err();
        assert!(
            matches!(
                e,
                ReadError::CorruptImage {
                    format: "OpenEXR",
                    ..
                }
            ),
            "{e}"
        );
        let mut rgba = Cursor::new(Vec::new());
        let px: Vec<u8> = [0.5f32, 0.5, 0.5, 0.5]
            .iter()
            .flat_map(|x| x.to_ne_bytes())
            .collect();
        image::codecs::openexr::OpenExrEncoder::new(&mut rgba)
            .write_image(&px, 1, 1, image::ExtendedColorType::Rgba32F)
            .unwrap();
        let e = decode(rgba.get_ref(), RasterFormat::Exr, &none()).unwrap_err();
        assert!(matches!(e, ReadError::NotOpaque { u: 0, v: 0, .. }), "{e}");
    }

    #[test]
    fn an_exr_whose_blocks_claim_gigabytes_is_refused_before_decoding() {
        // Found by the submission fuzz target: 1.9 kB whose header makes the codec
        // allocate 1.5 GB for one block.
        let bytes = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/fixtures/submissions/bad-inflate.exr"
        ))
        .unwrap();
        let e = decode(&bytes, RasterFormat::Exr, &DecodeLimits::for_frame(32, 24)).unwrap_err();
        assert!(matches!(e, ReadError::TooLarge { .. }), "{e}");
    }

    #[test]
    fn an_exr_compressed_with_b44_is_refused_before_its_codec_can_overflow() {
        // Found by the submission fuzz target: a B44 block on which the codec's
        // decompressor overflows (a panic wherever overflow checks are on).
        let bytes = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/fixtures/submissions/bad-b44.exr"
        ))
        .unwrap();
        for limits in [DecodeLimits::for_frame(32, 24), none()] {
            let e = decode(&bytes, RasterFormat::Exr, &limits).unwrap_err();
            assert!(
                matches!(&e, ReadError::CorruptImage { message, .. } if message.contains("B44")),
                "{e}"
            );
        }
    }

    #[test]
    fn sizes_are_checked_from_the_header_and_memory_is_bounded() {
        let img = RgbImage {
            width: 3,
            height: 2,
            data: vec![1; 18],
        };
        let b = img.encode_png();
        let limits = DecodeLimits::for_frame(2, 2);
        assert!(matches!(
            decode(&b, RasterFormat::Png, &limits),
            Err(ReadError::SizeMismatch {
                width: 3,
                height: 2,
                ..
            })
        ));
        let tight = DecodeLimits {
            frame: None,
            max_bytes: 10,
        };
        assert!(matches!(
            decode(&b, RasterFormat::Png, &tight),
            Err(ReadError::TooLarge { .. })
        ));
        // A PPM header claiming 60000 × 60000 pixels is refused, not allocated.
        assert!(matches!(
            decode(b"P6 60000 60000 255\n", RasterFormat::Pnm, &none()),
            Err(ReadError::TooLarge { .. })
        ));
    }

    #[test]
    fn sniffing() {
        assert_eq!(
            RasterFormat::sniff(b"P3\n1 1\n255\n"),
            Some(RasterFormat::Pnm)
        );
        assert_eq!(
            RasterFormat::sniff(b"PF\n1 1\n-1\n"),
            Some(RasterFormat::Pfm)
        );
        for text in [
            &b"u,v,hit,lambda"[..],
            b"{\"pixels\": []}",
            b"[{\"hit\": false}]",
            b"BMW,1,2",
            b"Pixel data",
            &[0xff; 100],
        ] {
            assert_eq!(RasterFormat::sniff(text), None, "{text:?}");
        }
        assert_eq!(RasterFormat::from_name("JPG"), Some(RasterFormat::Jpeg));
        assert_eq!(
            RasterFormat::from_media_type("image/x-portable-pixmap; charset=x"),
            Some(RasterFormat::Pnm)
        );
    }
}
