//! What a streamed answer holds in memory at most, charged to the server's memory
//! budget before its render starts (`server::memory`). Three parts:
//!
//! - the rows being assembled: the bands of tiles in flight ([`super::RowAssembler`]
//!   holds a band until all its tiles are in; tiles are taken in row-major order, so
//!   about one band a trace thread, and one more finishing);
//! - the encoded row a sink writes at once (for JSON and CSV a whole row of text);
//! - the response channel: up to `channel_chunks` chunks, each the bytes gathered
//!   for it (`chunk_bytes`) or one write larger than that, so a whole encoded row.
//!
//! The bound depends on the frame's width (a row), not its height: a very wide image
//! of hit data is what it prices high.

use std::mem::size_of;

use crate::format::HitFormat;
use crate::format::npy::NPY_RECORD_BYTES;
use crate::geometry::Surface;
use crate::render::Rect;
use crate::scene::Scene;

/// The most bytes of text a pixel of hit data takes, without its object's name: ten
/// numbers of up to 24 characters, two indices, and the member names.
const TEXT_PIXEL_BYTES: u64 = 512;

/// How the response is buffered: what the server's body channel allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Channel {
    /// Bytes gathered before a chunk is sent.
    pub chunk_bytes: usize,
    /// Chunks that may wait to be sent.
    pub chunks: usize,
}

/// The most memory streaming `region` of `scene` as `format` (`None`: a PNG) holds at
/// once, with tiles of `tile_px` traced by `threads` threads, through `channel`.
pub fn footprint(
    scene: &Scene,
    format: Option<HitFormat>,
    region: Rect,
    tile_px: u32,
    threads: usize,
    channel: Channel,
) -> u64 {
    let width = region.width as u64;
    let band_rows = tile_px.min(region.height).max(1) as u64;
    let longest_name = scene
        .objects
        .iter()
        .filter_map(|o| o.name.as_ref().map(|n| n.len() as u64))
        .max()
        .unwrap_or(0);
    // A pixel as the assembler holds it, and as one row of it is written.
    let (held, encoded) = match format {
        None => (size_of::<[u8; 3]>() as u64, 4),
        Some(HitFormat::Npy) => (NPY_RECORD_BYTES as u64, NPY_RECORD_BYTES as u64),
        // Names are escaped in JSON: up to six bytes a byte.
        Some(_) => (
            size_of::<Option<Surface>>() as u64,
            TEXT_PIXEL_BYTES + 6 * longest_name,
        ),
    };
    let bands = (threads as u64 + 2) * band_rows * width * held;
    // NDJSON writes a tile at a time, the others a row.
    let written = if format == Some(HitFormat::Ndjson) {
        tile_px as u64 * tile_px as u64
    } else {
        width
    };
    let row = written * encoded + 64;
    let chunk = channel.chunk_bytes as u64 + row;
    bands + row + channel.chunks as u64 * chunk
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

    const CHANNEL: Channel = Channel {
        chunk_bytes: 64 << 10,
        chunks: 32,
    };

    #[test]
    fn the_footprint_grows_with_the_width_not_the_height() {
        let s = scene(4000, 1);
        let wide = footprint(
            &s,
            Some(HitFormat::Json),
            Rect::frame(4_000_000, 1),
            64,
            2,
            CHANNEL,
        );
        let tall = footprint(
            &s,
            Some(HitFormat::Json),
            Rect::frame(1, 4_000_000),
            64,
            2,
            CHANNEL,
        );
        let square = footprint(
            &s,
            Some(HitFormat::Json),
            Rect::frame(2000, 2000),
            64,
            2,
            CHANNEL,
        );
        // A 4 M-pixel row of text, 32 times over in the channel: far over a GiB.
        assert!(wide > 32 * 4_000_000 * 500, "{wide}");
        assert!(tall < 64 << 20, "{tall}");
        assert!(square < 256 << 20, "{square}");
        let png = footprint(&s, None, Rect::frame(2000, 2000), 64, 2, CHANNEL);
        assert!(png < square);
    }

    /// What the sinks really write a row, against the estimate of one row.
    #[test]
    fn a_row_of_text_is_within_its_estimate() {
        let s = scene(300, 1);
        let r = crate::render::Renderer::new(std::sync::Arc::new(s));
        let hits = crate::grade::reference_hits(&r, &crate::render::Cancel::default()).unwrap();
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
