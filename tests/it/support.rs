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

/// A shipped scene with its image resized to `w × h`, written to `dir` (small frames
/// keep the grading tests quick).
pub fn resized_scene(dir: &tempfile::TempDir, name: &str, w: u32, h: u32) -> PathBuf {
    let bytes = std::fs::read(scene(name)).expect("a shipped scene");
    let mut doc: serde_json::Value = serde_json::from_slice(&bytes).expect("JSON");
    doc["image"]["width"] = w.into();
    doc["image"]["height"] = h.into();
    scene_file(dir, name, &doc)
}

/// Encodes 8-bit RGB pixels as a PNG.
pub fn encode_png(w: u32, h: u32, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().expect("PNG header");
    wr.write_image_data(rgb).expect("PNG data");
    wr.finish().expect("PNG end");
    out
}

/// Standard output parsed as JSON.
pub fn stdout_json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "stdout is not JSON ({e}): {}\nstderr: {}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

/// An 8 × 8 scene between two facing mirrors, the floor `y = 0` and the ceiling `y = 1`,
/// lit by one light: every pixel's ray but the centre's bounces between them until
/// `max_depth`, each bounce a level of the tracer's recursion.
pub fn facing_mirrors(max_depth: u32) -> serde_json::Value {
    let mirror = serde_json::json!({"diffuse": [0.1, 0.1, 0.1], "mirror": [0.9, 0.9, 0.9]});
    serde_json::json!({
        "version": 1,
        "image": {"width": 8, "height": 8},
        "camera": {"focal_length": 1.5, "transform": [{"translate": [0, 0.5, 0]}]},
        "max_depth": max_depth,
        "objects": [
            {"name": "floor", "shape": "plane", "material": mirror},
            {"name": "ceiling", "shape": "plane", "material": mirror, "transform": [
                {"rotate": {"axis": "x", "degrees": 180}}, {"translate": [0, 1, 0]}]}
        ],
        "lights": [{"type": "point", "position": [0, 0.5, 3], "colour": [1, 1, 1]}]
    })
}
