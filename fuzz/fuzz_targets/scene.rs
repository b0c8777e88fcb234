//! The scene document: any bytes through parsing and validation must give a scene or
//! a list of problems, never a panic, a hang or unbounded memory.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raytile::scene::{Limits, parse};

fuzz_target!(|bytes: &[u8]| {
    match parse(bytes, &Limits::default()) {
        Ok(_) => {}
        Err(e) => {
            // Every problem renders as text (the CLI and the server both print them).
            let _ = e.to_string();
        }
    }
});
