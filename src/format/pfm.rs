//! PFM, the Portable Float Map (`.pfm`): linear images as 32-bit floats, read as a
//! submission and written by `raytile render -o x.pfm`.
//!
//! The layout (as Paul Debevec's HDRShop defined it, and NumPy scripts write it):
//!
//! ```text
//! PF\n                 "PF" colour (3 floats a pixel), "Pf" grey (1 float)
//! 640 480\n            width and height
//! -1.0\n               scale: its sign is the byte order (negative: little-endian)
//! <floats>             rows from the BOTTOM of the image to the top
//! ```
//!
//! The `image` crate has no PFM codec, and the format is this small, so it is read here.
//! Grey is copied to all three channels; the scale's magnitude is ignored (the values
//! are taken as they are, as every common reader does).

use super::ReadError;
use super::linear::LinearImage;

/// The format's name (and file extension).
pub const NAME: &str = "pfm";

/// Whether `bytes` start like a PFM file: `PF` or `Pf` and white space.
pub fn sniff(bytes: &[u8]) -> bool {
    matches!(bytes, [b'P', b'F' | b'f', c, ..] if c.is_ascii_whitespace())
}

fn corrupt(message: impl Into<String>) -> ReadError {
    ReadError::CorruptImage {
        format: "PFM",
        message: message.into(),
    }
}

/// Reads a PFM file. With `expected`, a file of another size is refused from its
/// header; `limit_bytes` bounds the decoded image (12 bytes a pixel).
pub fn read(
    bytes: &[u8],
    expected: Option<(u32, u32)>,
    limit_bytes: usize,
) -> Result<LinearImage, ReadError> {
    if !sniff(bytes) {
        return Err(corrupt("it does not start with `PF` or `Pf`"));
    }
    let channels = if bytes[1] == b'F' { 3 } else { 1 };
    // Three header tokens after the magic, each ended by one white-space byte; the
    // floats start right after the scale's.
    let mut at = 3;
    let mut token = || -> Result<&[u8], ReadError> {
        while bytes.get(at).is_some_and(u8::is_ascii_whitespace) {
            at += 1;
        }
        let start = at;
        while bytes.get(at).is_some_and(|b| !b.is_ascii_whitespace()) {
            at += 1;
        }
        if at >= bytes.len() {
            return Err(corrupt("the header is truncated"));
        }
        let t = &bytes[start..at];
        at += 1;
        Ok(t)
    };
    let number = |t: &[u8], what: &str| {
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.parse::<f64>().ok())
            .ok_or_else(|| {
                corrupt(format!(
                    "the {what} `{}` is not a number",
                    String::from_utf8_lossy(t)
                ))
            })
    };
    let dim = |t: &[u8], what: &str| {
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.parse::<u32>().ok())
            .filter(|&n| n > 0)
            .ok_or_else(|| {
                corrupt(format!(
                    "the {what} `{}` is not a positive whole number",
                    String::from_utf8_lossy(t)
                ))
            })
    };
    let width = dim(token()?, "width")?;
    let height = dim(token()?, "height")?;
    let scale = number(token()?, "scale")?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(corrupt("the scale must be a non-zero number"));
    }
    if let Some((ew, eh)) = expected
        && (width, height) != (ew, eh)
    {
        return Err(ReadError::SizeMismatch {
            width,
            height,
            expected_width: ew,
            expected_height: eh,
        });
    }
    let pixels = width as usize * height as usize;
    let decoded = pixels.saturating_mul(12);
    if decoded > limit_bytes {
        return Err(ReadError::TooLarge {
            format: "PFM",
            limit_bytes,
        });
    }
    let data = &bytes[at..];
    let need = pixels * channels * 4;
    if data.len() != need {
        return Err(corrupt(format!(
            "a {width} × {height} {} image holds {need} bytes of floats, this one {}",
            if channels == 3 { "colour" } else { "grey" },
            data.len()
        )));
    }
    let little = scale < 0.0;
    let f = |b: &[u8]| {
        let b = [b[0], b[1], b[2], b[3]];
        if little {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        }
    };
    let row_bytes = width as usize * channels * 4;
    let mut out = Vec::with_capacity(pixels * 3);
    // Rows are stored bottom to top.
    for row in data.chunks_exact(row_bytes).rev() {
        for px in row.chunks_exact(channels * 4) {
            if channels == 3 {
                out.extend(px.chunks_exact(4).map(f));
            } else {
                let g = f(px);
                out.extend_from_slice(&[g, g, g]);
            }
        }
    }
    Ok(LinearImage {
        width,
        height,
        data: out,
    })
}

/// Writes a colour PFM, little-endian.
pub fn write(img: &LinearImage) -> Vec<u8> {
    let header = format!("PF\n{} {}\n-1.0\n", img.width, img.height);
    let mut out = Vec::with_capacity(header.len() + img.data.len() * 4);
    out.extend_from_slice(header.as_bytes());
    let row = img.width as usize * 3;
    if row > 0 {
        for r in img.data.chunks_exact(row).rev() {
            for x in r {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> LinearImage {
        LinearImage::from_pixels(
            2,
            2,
            &[
                [0.0, 0.5, 1.0],
                [2.0, 3.0, 4.0],
                [5.0; 3],
                [-1.0, 1e-6, 1e6],
            ],
        )
    }

    #[test]
    fn what_is_written_reads_back_with_the_top_row_first() {
        let img = sample();
        let b = write(&img);
        assert!(b.starts_with(b"PF\n2 2\n-1.0\n"));
        // The first stored row is the bottom one.
        assert_eq!(&b[12..16], &5.0f32.to_le_bytes());
        assert_eq!(read(&b, Some((2, 2)), 1 << 20).unwrap(), img);
    }

    #[test]
    fn big_endian_and_grey() {
        let mut b = b"Pf\n2 1\n1.0\n".to_vec();
        for x in [0.25f32, 0.75] {
            b.extend_from_slice(&x.to_be_bytes());
        }
        let img = read(&b, None, 1 << 20).unwrap();
        assert_eq!(img.data, vec![0.25, 0.25, 0.25, 0.75, 0.75, 0.75]);
    }

    #[test]
    fn broken_files_say_what_is_wrong() {
        let b = write(&sample());
        let e = read(&b[..b.len() - 1], None, 1 << 20).unwrap_err();
        assert!(
            e.to_string()
                .contains("holds 48 bytes of floats, this one 47"),
            "{e}"
        );
        let e = read(b"PF\n2 x\n-1\n", None, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("height `x`"), "{e}");
        let e = read(b"PF\n2 2", None, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
        let e = read(b"PF\n2 2\n0\n", None, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("non-zero"), "{e}");
        assert!(matches!(
            read(&b, Some((3, 2)), 1 << 20),
            Err(ReadError::SizeMismatch { width: 2, .. })
        ));
        // A header claiming a huge image is refused before anything is allocated.
        assert!(matches!(
            read(b"PF\n60000 60000\n-1\n", None, 64 << 20),
            Err(ReadError::TooLarge { .. })
        ));
    }
}
