//! Tracing whatever scene a document describes: any valid scene (within the server's
//! default limits) is traced, shaded and explained at a few pixels, and a packet of its
//! primary rays is traced and shaded together, without a panic, a hang or an abort.
//! The scene target checks the document; this one the geometry and shading behind it.
#![no_main]

use std::sync::Arc;

use libfuzzer_sys::fuzz_target;
use raytile::grade::explain::{ExplainOptions, explain};
use raytile::render::shade::RayCount;
use raytile::render::{Packet, Renderer};
use raytile::scene::{Limits, parse};

fuzz_target!(|bytes: &[u8]| {
    let Ok(scene) = parse(bytes, &Limits::default()) else {
        return;
    };
    let r = Renderer::new(Arc::new(scene));
    let frame = r.frame();
    let (w, h) = (frame.width, frame.height);
    let mut rays = RayCount(0);
    // The corners and the centre: the frame's edges and its most likely hit.
    for (u, v) in [(0, 0), (w / 2, h / 2), (w - 1, h - 1)] {
        let _ = r.pixel_colour(u, v, &mut rays);
        let _ = r.pixel_hit(u, v);
    }
    let _ = explain(&r, w / 2, h / 2, &ExplainOptions::default());
    // A packet of 4 × 2 pixels at the top left, where the frame holds one.
    if w >= 4 && h >= 2 {
        let p = Packet::pair(0, 0);
        let shader = r.shader();
        let _ = r.pixel_colours8(&shader, p, true, &mut rays);
        let mut rows = [Vec::new(), Vec::new()];
        let [a, b] = &mut rows;
        r.pixel_hits8(p, true, [a, b]);
    }
});
