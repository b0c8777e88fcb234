//! What a streamed answer holds in memory at most, charged to the server's memory
//! budget before its render starts (`server::memory`). The bound is the one
//! [`super::rows`] derives from the tiling, whatever the frame's shape:
//!
//! - tiles: the band being filled (at most [`BAND_PIXELS`] pixels, or one tile when
//!   tiles are larger), the tiles finished ahead of a slower one (`window` of them) and
//!   those being traced (`lanes`), each pixel as the assembler holds it; for a PNG
//!   also the tiles queued for the worker encoding ([`QUEUED_TILES`]), for NPY the
//!   encoded tiles queued for the worker writing and the spent buffers kept for reuse
//!   ([`QUEUED_TILES`] of them, or a band's records);
//! - encoded bytes: what one tile releases at once (a band's records), the pieces the
//!   sinks build ([`PIECE_BYTES`]), and what may wait for the client before the render
//!   parks (`in_flight_bytes`, the body's bound);
//! - for a PNG, the encoder's three rows of `3 × width` bytes, which the format needs.
//!
//! So it grows with neither the height nor, past the band, the width (except a PNG's
//! rows): a frame of 4 000 000 × 1 pixels of hit data costs what a square one does.

use std::mem::size_of;

use super::rows::{LANES_PER_THREAD, PIECE_BYTES, QUEUED_TILES, WINDOW_PER_LANE};
use crate::format::HitFormat;
use crate::format::npy::NPY_RECORD_BYTES;
use crate::geometry::Surface;
use crate::render::{BAND_PIXELS, Rect};
use crate::scene::Scene;

/// The most bytes of text a pixel of hit data takes, without its object's name: ten
/// numbers of up to 24 characters, two indices, and the member names.
const TEXT_PIXEL_BYTES: u64 = 512;

/// The most memory streaming `region` of `scene` as `format` (`None`: a PNG) holds at
/// once, with tiles of about `tile_px²` pixels traced by `threads` threads, when the
/// body lets `in_flight_bytes` wait for the client.
pub fn footprint(
    scene: &Scene,
    format: Option<HitFormat>,
    region: Rect,
    tile_px: u32,
    threads: usize,
    in_flight_bytes: usize,
) -> u64 {
    let longest_name = scene
        .objects
        .iter()
        .filter_map(|o| o.name.as_ref().map(|n| n.len() as u64))
        .max()
        .unwrap_or(0);
    // A pixel as the assembler holds it, and as it is written.
    let (held, encoded) = match format {
        None => (size_of::<[u8; 3]>() as u64, 4),
        Some(HitFormat::Npy) => (NPY_RECORD_BYTES as u64, NPY_RECORD_BYTES as u64),
        // Names are escaped in JSON: up to six bytes a byte.
        Some(_) => (
            size_of::<Option<Surface>>() as u64,
            TEXT_PIXEL_BYTES + 6 * longest_name,
        ),
    };
    let tile = tile_px.max(1) as u64 * tile_px.max(1) as u64;
    let lanes = (LANES_PER_THREAD * threads.max(1)) as u64;
    let window = WINDOW_PER_LANE as u64 * lanes;
    let band = BAND_PIXELS.max(tile);
    // A PNG queues tiles for the worker encoding; NPY queues encoded tiles for the
    // worker writing, and keeps spent buffers: as many tiles as it queues, or a band's
    // records.
    let (queued, spare_band) = match format {
        None => (QUEUED_TILES as u64, 0),
        Some(HitFormat::Npy) => (2 * QUEUED_TILES as u64, band),
        Some(_) => (0, 0),
    };
    let tiles = (band + spare_band + (window + lanes + queued) * tile) * held;
    let written = band * encoded + PIECE_BYTES as u64 + in_flight_bytes as u64;
    let png_rows = if format.is_none() {
        9 * region.width as u64
    } else {
        0
    };
    tiles + written + png_rows
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(w: u32, h: u32) -> Scene {
        let text = format!(
            r#"{{"version": 1, "image": {{"width": {w}, "height": {h}}},
                "camera": {{"focal_length": 1}},
                "objects": [{{"name": "ball", "shape": "sphere",
                              "transform": [{{"translate": [0, 0, 3]}}]}}],
                "lights": [{{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}}]}}"#
        );
        crate::scene::parse(text.as_bytes(), &crate::scene::Limits::default()).unwrap()
    }

    const IN_FLIGHT: usize = 2 << 20;

    #[test]
    fn the_footprint_grows_with_neither_the_width_nor_the_height() {
        let s = scene(4000, 1);
        let json = |w, h| {
            footprint(
                &s,
                Some(HitFormat::Json),
                Rect::frame(w, h),
                32,
                2,
                IN_FLIGHT,
            )
        };
        let (wide, tall, square) = (json(4_000_000, 1), json(1, 4_000_000), json(2000, 2000));
        // A 4 M-pixel row of text costs what a square frame does: tens of MiB, not GiB.
        assert_eq!(wide, square);
        assert_eq!(tall, square);
        assert!(square < 16 << 20, "{square}");
        let npy = footprint(
            &s,
            Some(HitFormat::Npy),
            Rect::frame(2000, 2000),
            32,
            2,
            IN_FLIGHT,
        );
        assert!(npy < square);
        // A PNG holds three encoder rows on top.
        let png = |w| footprint(&s, None, Rect::frame(w, 1), 32, 2, IN_FLIGHT);
        assert_eq!(png(16_777_216) - png(1), 9 * (16_777_216 - 1));
        // More threads, more tiles in flight.
        assert!(
            footprint(
                &s,
                Some(HitFormat::Json),
                Rect::frame(64, 64),
                32,
                8,
                IN_FLIGHT
            ) > json(64, 64)
        );
    }

    /// What the sinks really write a row, against the estimate of one row.
    #[test]
    fn a_row_of_text_is_within_its_estimate() {
        let s = scene(300, 1);
        let r = crate::render::Renderer::new(std::sync::Arc::new(s));
        let hits: Vec<_> = (0..300).map(|u| r.pixel_hit(u, 0)).collect();
        let mut json = Vec::new();
        let mut first = true;
        for (u, h) in hits.iter().enumerate() {
            let p = crate::format::PixelHit::new(&r.scene, u as u32, 0, h);
            crate::format::json::push_pixel(&mut json, &mut first, &p).unwrap();
        }
        assert!(hits.iter().any(Option::is_some));
        let per_pixel = json.len() as u64 / hits.len() as u64;
        assert!(per_pixel <= TEXT_PIXEL_BYTES + 6 * 4, "{per_pixel}");
    }
}
