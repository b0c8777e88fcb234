//! OpenEXR (`.exr`, `image/x-exr`): linear images as 16- or 32-bit floats, read as a
//! submission and written by `raytile render -o x.exr` (32-bit float RGB, one part,
//! scan lines).
//!
//! Both directions go through the `image` crate's codec, which is the `exr` crate's:
//! reading takes any compression and half or full floats with R, G, B and optionally
//! A channels (decoded by [`super::raster::decode`] under its memory limit); an alpha
//! below 1 is refused, since the grader cannot tell what it should show through.
//!
//! The codec sizes its decompression buffers from the headers without the caller's
//! limit, so `check_headers` first reads the headers with the `exr` crate and refuses
//! a file whose blocks or pixels would take more than the limit (a file of a few
//! kilobytes can otherwise claim gigabytes).

use std::io::Cursor;

use image::{DynamicImage, ImageEncoder};

use super::ReadError;
use super::linear::LinearImage;

/// The format's name (and file extension).
pub const NAME: &str = "exr";

/// Its media type.
pub const MEDIA_TYPE: &str = "image/x-exr";

/// The four bytes every OpenEXR file starts with.
pub const MAGIC: &[u8] = &[0x76, 0x2f, 0x31, 0x01];

/// Encodes a 32-bit float RGB OpenEXR file.
pub fn write(img: &LinearImage) -> Result<Vec<u8>, String> {
    let mut out = Cursor::new(Vec::new());
    let bytes: Vec<u8> = img.data.iter().flat_map(|x| x.to_ne_bytes()).collect();
    image::codecs::openexr::OpenExrEncoder::new(&mut out)
        .write_image(
            &bytes,
            img.width,
            img.height,
            image::ExtendedColorType::Rgb32F,
        )
        .map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Refuses, from its headers alone, a file whose pixels or largest block would take
/// more than `limit_bytes` to decompress; deep data is no image to grade.
pub(super) fn check_headers(bytes: &[u8], limit_bytes: usize) -> Result<(), ReadError> {
    let corrupt = |message: String| ReadError::CorruptImage {
        format: "OpenEXR",
        message,
    };
    let too_large = ReadError::TooLarge {
        format: "OpenEXR",
        limit_bytes,
    };
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| corrupt(e.to_string()))?;
    let mut total = 0usize;
    for h in meta.headers.iter() {
        if h.deep {
            return Err(corrupt("it holds deep data, not an image".into()));
        }
        // The codec's B44 decompressor overflows on some crafted blocks (found by
        // fuzzing); B44 is lossy and rare in renderers' output, so it is refused.
        if matches!(
            h.compression,
            exr::compression::Compression::B44 | exr::compression::Compression::B44A
        ) {
            return Err(corrupt(
                "it is compressed with B44, which the grader does not read (lossy): write it \
                 uncompressed or with RLE, ZIP or PIZ"
                    .into(),
            ));
        }
        let (w, hh) = (h.layer_size.width(), h.layer_size.height());
        let (bw, bh) = match h.blocks {
            exr::meta::BlockDescription::Tiles(t) => (t.tile_size.width(), t.tile_size.height()),
            exr::meta::BlockDescription::ScanLines => (w, h.compression.scan_lines_per_block()),
        };
        // A bound on both the layer's pixels and its largest block, in checked
        // arithmetic: the sizes are the file's word.
        let bytes = h
            .channels
            .bytes_per_pixel
            .checked_mul(w.max(bw))
            .and_then(|x| x.checked_mul(hh.max(bh)))
            .ok_or_else(|| too_large.clone())?;
        total = total.checked_add(bytes).ok_or_else(|| too_large.clone())?;
    }
    if total > limit_bytes {
        return Err(too_large);
    }
    Ok(())
}

/// The linear RGB of a decoded EXR image, refusing pixels that are not opaque.
pub(super) fn linear(img: DynamicImage) -> Result<LinearImage, ReadError> {
    let (width, height) = (img.width(), img.height());
    let data = if img.color().has_alpha() {
        let rgba = img.into_rgba32f();
        let mut data = Vec::with_capacity(width as usize * height as usize * 3);
        for (k, px) in rgba.as_raw().chunks_exact(4).enumerate() {
            // A NaN alpha is not opaque either.
            if px[3].is_nan() || px[3] < 1.0 {
                return Err(ReadError::NotOpaque {
                    u: (k % width as usize) as u32,
                    v: (k / width as usize) as u32,
                    alpha: px[3].to_string(),
                });
            }
            data.extend_from_slice(&px[..3]);
        }
        data
    } else {
        img.into_rgb32f().into_raw()
    };
    Ok(LinearImage {
        width,
        height,
        data,
    })
}
