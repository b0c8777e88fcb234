//! Writes a scene of N random spheres resting on a floor to standard output.
//!
//! `cargo run --release --example gen_spheres -- 100000 [--seed S] > spheres.json`
//!
//! Deterministic: the same N and seed give the same bytes. The spheres keep a constant
//! density (about 0.4 per unit² of floor), so the frame looks alike at any N.

use std::io::{self, Write};

use serde_json::json;

/// A small deterministic generator (xorshift64*), so the output never depends on a crate's
/// version of its random streams.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

fn main() -> io::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: gen_spheres N [--seed S]";
    let n: usize = args
        .first()
        .and_then(|a| a.parse().ok())
        .ok_or_else(|| io::Error::other(usage))?;
    let seed: u64 = match args.iter().position(|a| a == "--seed") {
        Some(i) => args
            .get(i + 1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| io::Error::other(usage))?,
        None => 1,
    };
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let half = 0.8 * (n as f64).sqrt();
    let materials: serde_json::Map<String, serde_json::Value> = (0..8)
        .map(|i| {
            let c = [
                round6(rng.range(0.2, 0.9)),
                round6(rng.range(0.2, 0.9)),
                round6(rng.range(0.2, 0.9)),
            ];
            (
                format!("m{i}"),
                json!({"diffuse": c, "specular": [0.3, 0.3, 0.3], "shininess": 40}),
            )
        })
        .collect();
    let mut objects =
        vec![json!({"name": "floor", "shape": "plane", "material": {"diffuse": [0.6, 0.6, 0.6]}})];
    for i in 0..n {
        let r = round6(rng.range(0.2, 0.8));
        let (x, z) = (
            round6(rng.range(-half, half)),
            round6(rng.range(-half, half)),
        );
        objects.push(json!({"shape": "sphere", "material": format!("m{}", i % 8),
            "transform": [{"scale": r}, {"translate": [x, r, z]}]}));
    }
    let doc = json!({
        "version": 1,
        "image": {"width": 1280, "height": 720},
        "camera": {"focal_length": 1.2, "look_at": {"eye": [0.0, round6(0.35 * half + 2.0), round6(1.15 * half + 3.0)],
                                                   "target": [0, 0, 0], "up": [0, 1, 0]}},
        "materials": materials,
        "objects": objects,
        "lights": [{"type": "point", "position": [6, 10, 8], "colour": [0.8, 0.8, 0.8]},
                   {"type": "point", "position": [-8, 6, 3], "colour": [0.4, 0.4, 0.5]}]
    });
    let mut out = io::BufWriter::new(io::stdout().lock());
    serde_json::to_writer(&mut out, &doc)?;
    writeln!(out)
}
