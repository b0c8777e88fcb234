//! Writes a scene with one height-field mesh of about 2·(K − 1)² triangles to standard
//! output: `cargo run --release --example gen_mesh -- 224 > mesh.json`.

use std::io::{self, Write};

use serde_json::json;

fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

fn main() -> io::Result<()> {
    let k: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .filter(|&k| k >= 2)
        .ok_or_else(|| io::Error::other("usage: gen_mesh K   (grid side, at least 2)"))?;
    let at = |i: usize| -10.0 + 20.0 * i as f64 / (k - 1) as f64;
    let mut positions = Vec::with_capacity(k * k);
    for j in 0..k {
        for i in 0..k {
            let (x, z) = (at(i), at(j));
            let y = 1.2 * (0.6 * x).sin() * (0.5 * z).cos() + 0.4 * (1.7 * x + 1.3 * z).sin() + 1.5;
            positions.push([round6(x), round6(y), round6(z)]);
        }
    }
    let mut indices = Vec::with_capacity(2 * (k - 1) * (k - 1));
    for j in 0..k - 1 {
        for i in 0..k - 1 {
            let (a, b, c, d) = (
                j * k + i,
                j * k + i + 1,
                (j + 1) * k + i,
                (j + 1) * k + i + 1,
            );
            indices.push([a, c, b]);
            indices.push([b, c, d]);
        }
    }
    let doc = json!({
        "version": 1,
        "image": {"width": 1280, "height": 720},
        "camera": {"focal_length": 1.2, "look_at": {"eye": [0, 11, 22], "target": [0, 0, 0], "up": [0, 1, 0]}},
        "objects": [{"name": "terrain", "shape": "mesh", "material": {"diffuse": [0.5, 0.7, 0.4]},
                     "positions": positions, "indices": indices}],
        "lights": [{"type": "point", "position": [6, 10, 8], "colour": [0.8, 0.8, 0.8]},
                   {"type": "point", "position": [-8, 6, 3], "colour": [0.4, 0.4, 0.5]}]
    });
    let mut out = io::BufWriter::new(io::stdout().lock());
    serde_json::to_writer(&mut out, &doc)?;
    writeln!(out)
}
