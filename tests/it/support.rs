//! Helpers shared by the integration tests.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The `raytile` binary cargo built for these tests.
pub fn raytile() -> Command {
    Command::new(env!("CARGO_BIN_EXE_raytile"))
}

/// Runs `raytile` with `args` and returns its output.
pub fn run(args: &[&str]) -> Output {
    raytile()
        .args(args)
        .output()
        .expect("the raytile binary runs")
}

/// A file of the shipped `scenes/` folder.
pub fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

/// A file of `tests/data/`.
pub fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("data")
        .join(name)
}

/// Writes `json` to a temporary scene file.
pub fn scene_file(dir: &tempfile::TempDir, name: &str, json: &serde_json::Value) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, serde_json::to_vec(json).expect("serialisable")).expect("temp dir writable");
    p
}

/// Decodes an 8-bit RGB PNG into (width, height, bytes).
pub fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut r = dec.read_info().expect("a PNG header");
    let mut buf = vec![0; r.output_buffer_size().expect("size")];
    let info = r.next_frame(&mut buf).expect("PNG data");
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}
