//! Every submission reader (images as PNG, PPM, BMP, TGA, JPEG, PFM and OpenEXR, hit
//! data as JSON, NDJSON, NPY and CSV, and telling them apart by content): any bytes give
//! a submission or a reason, never a panic, a hang or memory out of proportion. The
//! first byte picks the hint, as a file name or a media type would (its low bits), and
//! whether the frame an image's header is checked against is known (its high bit).
#![no_main]

use libfuzzer_sys::fuzz_target;
use raytile::grade::submission::{Hint, Submission};

const HINTS: [Hint; 12] = [
    Hint::Auto,
    Hint::Png,
    Hint::Json,
    Hint::Ndjson,
    Hint::Npy,
    Hint::Csv,
    Hint::Ppm,
    Hint::Bmp,
    Hint::Tga,
    Hint::Jpeg,
    Hint::Pfm,
    Hint::Exr,
];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let hint = HINTS[(pick & 0x7f) as usize % HINTS.len()];
    // The seeded images are 32 × 24: with that frame they are decoded whole; with the
    // high bit set, no frame is known and only the default memory limit applies.
    let parsed = if pick & 0x80 == 0 {
        Submission::parse_for_frame(bytes, hint, 32, 24)
    } else {
        Submission::parse(bytes, hint)
    };
    if let Err(e) = parsed {
        let _ = e.to_string();
    }
});
