//! OpenEXR (`.exr`, `image/x-exr`): linear images as 16- or 32-bit floats, read as a
//! submission and written by `raytile render -o x.exr` (32-bit float RGB, one part,
//! scan lines).
//!
//! Both directions go through the `image` crate's codec, which is the `exr` crate's:
//! reading takes any compression and half or full floats with R, G, B and optionally
//! A channels (decoded by [`super::raster::decode`] under its memory limit); an alpha
//! below 1 is refused, since the grader cannot tell what it should show through.

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
