//! Every submission reader (PNG, hit data as JSON, NDJSON, NPY and CSV, and telling
//! them apart by content): any bytes give a submission or a reason, never a panic, a
//! hang or memory out of proportion. The first byte picks the hint, as a file name or a
//! media type would; the frame is the size a server checks a PNG's header against.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raytile::grade::submission::{Hint, Submission};

const HINTS: [Hint; 6] = [
    Hint::Auto,
    Hint::Png,
    Hint::Json,
    Hint::Ndjson,
    Hint::Npy,
    Hint::Csv,
];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let hint = HINTS[pick as usize % HINTS.len()];
    if let Err(e) = Submission::parse_for_frame(bytes, hint, 64, 48) {
        let _ = e.to_string();
    }
});
