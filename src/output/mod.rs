//! Sinks that stream a PNG or hit data while tiles are still tracing: they put tiles,
//! which finish in any order on any thread, into the order a format needs
//! ([`RowAssembler`]) and hand the rows to the writers of [`crate::format`], a tile to
//! whichever worker is writing ([`handoff`]); and the file they are written to
//! ([`OutputFile`]).
//!
//! [`RowAssembler`]: crate::output::RowAssembler
//! [`handoff`]: crate::output::handoff
//! [`OutputFile`]: crate::output::OutputFile

pub mod file;
pub mod footprint;
pub mod frame;
pub mod handoff;
pub mod hits;
pub mod png;
pub mod rows;

pub use file::OutputFile;
pub use footprint::footprint;
pub use frame::FrameSink;
pub use hits::HitSink;
pub use png::PngSink;
pub use rows::RowAssembler;

/// Hands `sink` the tiles it asks for over `region` (of about `tile_px²` pixels), the
/// last first, from `threads` threads taking them in turn, each pixel `pixel(u, v)`:
/// as a render's workers would, in an order that keeps rows waiting.
#[cfg(test)]
pub(crate) fn feed_from_threads<T: Send, S: crate::render::TileSink<T>>(
    sink: &S,
    region: crate::render::Rect,
    tile_px: u32,
    threads: usize,
    pixel: impl Fn(u32, u32) -> T + Sync,
) {
    use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
    let mut tiles = sink.tile_shape(region, tile_px).cut(region);
    tiles.reverse();
    let next = AtomicUsize::new(0);
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                while let Some(&t) = tiles.get(next.fetch_add(1, Relaxed)) {
                    sink.tile(crate::render::Tile::filled(t, &pixel)).unwrap();
                }
            });
        }
    });
}
