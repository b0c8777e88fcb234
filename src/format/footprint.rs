//! What reading a submission costs in memory, decided before it is decoded (the server
//! charges it to its memory budget first, `server::memory`), one estimate per family:
//!
//! - PNG images: from the header (width, height): the decoder's buffer at up to 8 bytes
//!   a pixel (16-bit RGBA), its rows, and the 3-byte RGB image;
//! - the other images (PPM, BMP, TGA, JPEG, PFM, OpenEXR): from the scene's frame, as
//!   their readers refuse another size from the header before decoding and give the
//!   decoder at most [`DecodeLimits::for_frame`]'s bytes; then the decoded raster;
//! - NPY: from the header's shape (and no more records than the data can hold): one
//!   record read a pixel;
//! - JSON, NDJSON and CSV hit data: from the size of the text, at the fewest bytes a
//!   pixel can take in each (`{"hit":false},` is 14), each pixel read into its record.
//!
//! Each is an upper bound of the peak; the tests measure the peak with a counting
//! allocator on the smallest pixels each format allows.

use std::mem::size_of;

use super::hit::{HitFormat, SubmittedHit};
use super::json::PixelIn;
use super::npy::NPY_MAGIC;
use super::png::PNG_SIGNATURE;
use super::raster::{DecodeLimits, RasterFormat};
use super::{Group, ReadError};

/// A submission's family, as far as it is known before reading it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Family {
    /// An image (a PNG is priced from its header, the others from the frame).
    Image(RasterFormat),
    /// Hit data in one of its formats.
    Hits(HitFormat),
}

/// What decoding a submission will take at most.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decoding {
    /// The peak while decoding, in bytes.
    pub peak: u64,
    /// What the decoded submission holds afterwards, in bytes.
    pub held: u64,
}

/// The fewest bytes of text a pixel takes: `{"hit":false},` in JSON and NDJSON, and in
/// CSV a row of its seven required columns, `0,0,0,,,,` and a newline.
const MIN_JSON_PIXEL: u64 = 14;
const MIN_CSV_PIXEL: u64 = 10;
/// The smallest NPY record: a bool and four 1-byte numbers would be 5 bytes; no dtype
/// the reader takes is smaller.
const MIN_NPY_RECORD: u64 = 5;

/// The estimate for `bytes` of `family` (`None`: told from the content as the grader
/// does, so priced as the costliest family it could be). A PNG whose header cannot be
/// read is refused here, as decoding would refuse it.
///
/// `frame` is the scene's `width × height`, which an image other than a PNG must match.
pub fn submission(
    bytes: &[u8],
    family: Option<Family>,
    frame: (u32, u32),
) -> Result<Decoding, ReadError> {
    let family = match family {
        Some(f) => f,
        None if bytes.starts_with(PNG_SIGNATURE) => Family::Image(RasterFormat::Png),
        None if bytes.starts_with(NPY_MAGIC) => Family::Hits(HitFormat::Npy),
        None => {
            let len = bytes.len() as u64;
            return Ok([HitFormat::Json, HitFormat::Ndjson, HitFormat::Csv]
                .into_iter()
                .map(|f| text(len, f))
                .fold(Decoding { peak: 0, held: 0 }, |a, b| Decoding {
                    peak: a.peak.max(b.peak),
                    held: a.held.max(b.held),
                }));
        }
    };
    Ok(match family {
        Family::Image(RasterFormat::Png) => png(bytes)?,
        Family::Image(f) => image_in_frame(f, frame),
        Family::Hits(HitFormat::Npy) => npy(bytes),
        Family::Hits(f) => text(bytes.len() as u64, f),
    })
}

/// The width and height in a PNG's header, read without decoding anything.
pub fn png_size(bytes: &[u8]) -> Result<(u32, u32), ReadError> {
    if !bytes.starts_with(PNG_SIGNATURE) {
        return Err(ReadError::NotPng);
    }
    // The signature, then the IHDR chunk: length (4), type (4), width (4), height (4).
    let ihdr = bytes
        .get(8..24)
        .filter(|h| &h[4..8] == b"IHDR")
        .ok_or_else(|| ReadError::CorruptPng("it has no IHDR chunk first".into()))?;
    let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    Ok((be(&ihdr[8..12]), be(&ihdr[12..16])))
}

/// An image of `format` decoded for a `frame`: what its decoder may take at most, then
/// the raster it keeps (8-bit RGB, or three 32-bit floats a pixel for float images).
fn image_in_frame(format: RasterFormat, (w, h): (u32, u32)) -> Decoding {
    let pixels = w as u64 * h as u64;
    let held = pixels * if format.is_linear() { 12 } else { 3 };
    Decoding {
        peak: DecodeLimits::for_frame(w, h).max_bytes as u64 + held,
        held,
    }
}

fn png(bytes: &[u8]) -> Result<Decoding, ReadError> {
    let (w, h) = png_size(bytes)?;
    let pixels = w as u64 * h as u64;
    // The decoder's output (the image crate keeps 16-bit samples: RGBA at 16 bits, 8
    // bytes a pixel), the RGB image, and rows of raw 16-bit RGBA (the current and the
    // previous) and the inflater's window.
    let held = pixels * 3;
    Ok(Decoding {
        peak: pixels * 8 + h as u64 + held + 4 * w as u64 * 8 + (1 << 20),
        held,
    })
}

/// The pixel count in an NPY header's `shape`, if it can be read there.
fn npy_shape(bytes: &[u8]) -> Option<u64> {
    let head = bytes.get(..bytes.len().min(4096))?;
    let text = std::str::from_utf8(head.get(10..)?).ok().or_else(|| {
        // A header that is ASCII followed by binary data: take the ASCII part.
        let end = head.iter().skip(10).position(|b| !b.is_ascii())? + 10;
        std::str::from_utf8(&head[10..end]).ok()
    })?;
    let at = text.find("'shape'").or_else(|| text.find("\"shape\""))?;
    let open = text[at..].find('(')? + at + 1;
    let close = text[open..].find(')')? + open;
    text[open..close]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .try_fold(1u64, |n, d| n.checked_mul(d.parse().ok()?))
}

fn npy(bytes: &[u8]) -> Decoding {
    let len = bytes.len() as u64;
    let most = len / MIN_NPY_RECORD;
    let n = npy_shape(bytes).map_or(most, |n| n.min(most));
    let held = n * size_of::<SubmittedHit>() as u64 + size_of::<Group>() as u64;
    Decoding {
        peak: held + (64 << 10),
        held,
    }
}

fn text(len: u64, format: HitFormat) -> Decoding {
    let (n, read_as) = match format {
        // Read into a vector of pixels as sent, which grows by doubling, then into
        // records.
        HitFormat::Json | HitFormat::Ndjson => {
            (len / MIN_JSON_PIXEL, 2 * size_of::<PixelIn>() as u64)
        }
        HitFormat::Csv => (len / MIN_CSV_PIXEL, 0),
        HitFormat::Npy => (len / MIN_NPY_RECORD, 0),
    };
    let record = size_of::<SubmittedHit>() as u64;
    // The records' vector grows by doubling too; NDJSON has a group per line.
    let groups = if format == HitFormat::Ndjson {
        n * size_of::<Group>() as u64 * 2
    } else {
        0
    };
    Decoding {
        peak: n * (read_as + 2 * record) + groups + len + (64 << 10),
        held: n * record * 2 + groups,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{csv, json, ndjson, npy};
    use crate::measure;

    fn peak_of(bytes: &[u8], family: Family, read: impl FnOnce(&[u8]) -> bool) {
        let estimate = submission(bytes, Some(family), (1, 1)).unwrap();
        let ((ok, held), peak) = measure::peak(|| {
            let before = measure::live();
            let ok = read(bytes);
            (ok, measure::live().saturating_sub(before))
        });
        assert!(ok, "{family:?} did not read");
        assert!(
            estimate.peak >= peak,
            "{family:?}: estimate {} < peak {peak}",
            estimate.peak
        );
        assert!(
            estimate.held >= held,
            "{family:?}: held {held} > {}",
            estimate.held
        );
        // Told from the content, the estimate is no lower.
        assert!(submission(bytes, None, (1, 1)).unwrap().peak >= peak);
    }

    #[test]
    fn hit_data_of_the_smallest_pixels_stays_within_its_estimate() {
        crate::measure::alone_or_return!(hit_data_of_the_smallest_pixels_stays_within_its_estimate);
        let n = 200_000;
        let pixels = vec![r#"{"hit":false}"#; n].join(",");
        let doc = format!("[{pixels}]");
        peak_of(doc.as_bytes(), Family::Hits(HitFormat::Json), |b| {
            json::read(b).map(std::hint::black_box).is_ok()
        });
        let line = format!("{{\"pixels\": [{}]}}\n", [r#"{"hit":false}"#; 4].join(","));
        let lines = line.repeat(n / 4);
        peak_of(lines.as_bytes(), Family::Hits(HitFormat::Ndjson), |b| {
            ndjson::read(b).map(std::hint::black_box).is_ok()
        });
        let table = format!("u,v,hit,lambda,nx,ny,nz\n{}", "0,0,0,,,,\n".repeat(n));
        peak_of(table.as_bytes(), Family::Hits(HitFormat::Csv), |b| {
            csv::read(b).map(std::hint::black_box).is_ok()
        });
        let mut file = npy::npy_header(400, 500);
        for k in 0..200_000u32 {
            npy::npy_record(&mut file, k % 500, k / 500, &None);
        }
        peak_of(&file, Family::Hits(HitFormat::Npy), |b| {
            npy::read(b).map(std::hint::black_box).is_ok()
        });
    }

    /// A 16-bit RGBA PNG, the widest layout (8 bytes a pixel before reduction).
    fn rgba16(w: u32, h: u32) -> Vec<u8> {
        // Varied colours (so that it does not compress to nothing), opaque.
        let data: Vec<u8> = (0..w as usize * h as usize * 8)
            .map(|i| if i % 8 >= 6 { 0xFF } else { (i % 251) as u8 })
            .collect();
        crate::format::png::tests::encode(
            w,
            h,
            ::png::ColorType::Rgba,
            ::png::BitDepth::Sixteen,
            &data,
        )
    }

    #[test]
    fn a_png_is_priced_from_its_header_above_its_decoding() {
        crate::measure::alone_or_return!(a_png_is_priced_from_its_header_above_its_decoding);
        let file = rgba16(640, 480);
        assert_eq!(png_size(&file), Ok((640, 480)));
        let estimate = submission(&file, Some(Family::Image(RasterFormat::Png)), (1, 1)).unwrap();
        let limits = DecodeLimits::for_frame(640, 480);
        let (raster, peak) = measure::peak(|| {
            crate::format::raster::decode(&file, RasterFormat::Png, &limits).unwrap()
        });
        let crate::format::raster::Raster::Rgb8(img) = raster else {
            panic!("a PNG decodes to 8-bit RGB")
        };
        assert!(
            estimate.peak >= peak,
            "estimate {} < peak {peak}",
            estimate.peak
        );
        // The decoded buffer's own length.
        assert!(estimate.held >= img.pixels().len() as u64 * 3);
        assert_eq!(
            png_size(b"\x89PNG\r\n\x1a\nshort"),
            Err(ReadError::CorruptPng("it has no IHDR chunk first".into()))
        );
        assert_eq!(png_size(b"GIF89a"), Err(ReadError::NotPng));
    }

    #[test]
    fn the_npy_shape_is_read_from_the_header() {
        assert_eq!(npy_shape(&npy::npy_header(3, 7)), Some(21));
        assert_eq!(
            npy_shape(b"\x93NUMPY\x01\x00\x10\x00{'shape': (5,), }"),
            Some(5)
        );
        assert_eq!(npy_shape(b"\x93NUMPY"), None);
    }
}
