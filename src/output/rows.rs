//! Turns tiles, which finish in any order, into rows in order, so that row-major outputs
//! (PNG, JSON, NPY and CSV hit data) can be written while the rest is still tracing.
//! Pixels are never copied: a row leaves as the slices of the tiles it crosses.
//!
//! # What a streamed response holds
//!
//! A band is one row of tiles (they share their top and height). A band more than one
//! pixel high can leave only once its last tile is in; a band one pixel high leaves
//! tile by tile, each as soon as the tiles to its left have left. The sinks ask for
//! tiles of [`TileShape::rows`](crate::render::TileShape::rows): as high as `tile_px`
//! while a band spans at most [`BAND_PIXELS`](crate::render::BAND_PIXELS) pixels, one row high (and `tile_px²`
//! wide) past that. The server hands tiles out through a
//! [`TileCursor`](crate::render::TileCursor) at most `window` ahead of the oldest tile
//! being traced. So, whatever the frame's shape, a streamed response holds at most
//!
//! - tiles: `(BAND_PIXELS + window × tile_px²) × pixel bytes` in this assembler (the
//!   band being filled and the tiles finished ahead of a slower one), plus
//!   `lanes × tile_px²` pixels being traced (`lanes`, `window`: [`LANES_PER_THREAD`]
//!   and [`WINDOW_PER_LANE`] times the pool's threads);
//! - encoded bytes: what one tile releases — at most a band, so `BAND_PIXELS × record
//!   bytes` — beyond the body's `IN_FLIGHT_BYTES` (2 MiB, in chunks of at most 64 KiB:
//!   `crate::server::stream`), since a render parks before its next tile once that
//!   much waits for the client; the sinks write records in pieces of at most
//!   [`PIECE_BYTES`], never a whole row in one buffer;
//! - for a PNG, the encoder's own three rows (`3 × 3 × width` bytes: the previous and
//!   the current row and the filtered one), which the format needs.
//!
//! Pixel bytes: `size_of::<Option<Surface>>()` for JSON and CSV, NPY's record
//! (`NPY_RECORD_BYTES`, 101) for NPY, 3 for a PNG; record bytes: a JSON pixel object is
//! at most about 400 bytes, a CSV row about 250, an NPY record 101. With the defaults
//! (`tile_px` 32, two threads: 2 lanes, a window of 8) that is, for JSON, about
//! `(16 Ki + 10 × 1 Ki) × 88 B + 16 Ki × 400 B + 2 MiB`: under 12 MiB a response,
//! whatever the frame's width; for a PNG, under 3 MiB plus `9 × width` bytes.

use std::collections::BTreeMap;

use crate::render::{Rect, Tile};

/// Tiles traced at once per render, per thread of the pool.
pub const LANES_PER_THREAD: usize = 1;

/// How far (in tiles) a render may run ahead of its oldest tile being traced, per lane.
pub const WINDOW_PER_LANE: usize = 4;

/// The most tiles a sink queues for the worker writing now before the next
/// worker waits for it, and the most spent buffers it keeps for reuse.
pub const QUEUED_TILES: usize = 4;

/// The largest piece of encoded records a sink builds before it writes it.
pub const PIECE_BYTES: usize = 16 * 1024;

/// Collects tiles into bands and releases their rows top to bottom.
pub struct RowAssembler<T> {
    region: Rect,
    /// Bands by their top row.
    bands: BTreeMap<u32, Band<T>>,
    /// The top row of the next band to leave.
    next_y: u32,
    held: u64,
}

struct Band<T> {
    height: u32,
    /// Tiles by their left column.
    tiles: BTreeMap<u32, Tile<T>>,
    filled: u64,
    /// For a band one row high: the columns that have left.
    next_x: u32,
}

impl<T> RowAssembler<T> {
    /// For the tiles of `region`, cut in any shape whose bands share their top and
    /// height (as [`crate::render::TileShape::cut`] cuts them).
    pub fn new(region: Rect) -> Self {
        Self {
            region,
            bands: BTreeMap::new(),
            next_y: region.y,
            held: 0,
        }
    }

    /// The region being assembled.
    pub fn region(&self) -> Rect {
        self.region
    }

    /// Rows of the region released so far.
    pub fn rows_done(&self) -> u32 {
        self.next_y - self.region.y
    }

    /// Whether every row has been released.
    pub fn is_complete(&self) -> bool {
        self.rows_done() >= self.region.height
    }

    /// Pixels held now, waiting for the tiles before them.
    pub fn held_pixels(&self) -> u64 {
        self.held
    }

    /// Takes a tile; calls `emit(v, x, segments)` for every piece of a row that can
    /// leave now, in order: `segments` are the pixels of row `v` from column `x` on, left
    /// to right. A row leaves whole, or (in a band one row high) in pieces left to right.
    pub fn push<E>(
        &mut self,
        tile: Tile<T>,
        emit: impl FnMut(u32, u32, &[&[T]]) -> Result<(), E>,
    ) -> Result<(), E> {
        self.push_reclaiming(tile, emit, drop)
    }

    /// As [`RowAssembler::push`], and hands every tile's pixel buffer to `spent` once
    /// its rows have left, so a sink can reuse it for a later tile instead of
    /// allocating (and page-faulting) a fresh one.
    pub fn push_reclaiming<E>(
        &mut self,
        tile: Tile<T>,
        mut emit: impl FnMut(u32, u32, &[&[T]]) -> Result<(), E>,
        mut spent: impl FnMut(Vec<T>),
    ) -> Result<(), E> {
        let r = tile.rect;
        self.held += r.pixels();
        let band = self.bands.entry(r.y).or_insert_with(|| Band {
            height: r.height,
            tiles: BTreeMap::new(),
            filled: 0,
            next_x: self.region.x,
        });
        band.filled += r.pixels();
        band.tiles.insert(r.x, tile);
        let width = self.region.width as u64;
        let right = self.region.x + self.region.width;
        loop {
            let y = self.next_y;
            let Some(band) = self.bands.get_mut(&y) else {
                return Ok(());
            };
            if band.height == 1 {
                while let Some(t) = band.tiles.first_entry().filter(|t| *t.key() == band.next_x) {
                    let t = t.remove();
                    band.next_x += t.rect.width;
                    self.held -= t.rect.pixels();
                    emit(y, t.rect.x, &[&t.pixels])?;
                    spent(t.pixels);
                }
                if band.next_x < right {
                    return Ok(());
                }
            } else {
                if band.filled < band.height as u64 * width {
                    return Ok(());
                }
                let mut segments: Vec<&[T]> = Vec::with_capacity(band.tiles.len());
                for row in 0..band.height as usize {
                    segments.clear();
                    segments.extend(band.tiles.values().map(|t| {
                        let w = t.rect.width as usize;
                        &t.pixels[row * w..(row + 1) * w]
                    }));
                    emit(y + row as u32, self.region.x, &segments)?;
                }
                self.held -= band.filled;
            }
            let height = band.height;
            if let Some(band) = self.bands.remove(&y) {
                band.tiles.into_values().for_each(|t| spent(t.pixels));
            }
            self.next_y = y + height;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{BAND_PIXELS, TileShape};

    fn tile(t: Rect) -> Tile<(u32, u32)> {
        Tile::filled(t, |u, v| (u, v))
    }

    /// Pushes `tiles`, returns the rows rebuilt from the pieces and checks that pieces
    /// came in order.
    fn assemble(region: Rect, tiles: Vec<Rect>) -> Vec<(u32, Vec<(u32, u32)>)> {
        let mut a = RowAssembler::<(u32, u32)>::new(region);
        let mut rows: Vec<(u32, Vec<(u32, u32)>)> = Vec::new();
        for t in tiles {
            a.push::<()>(tile(t), |v, x, segs| {
                let piece = segs.concat();
                assert_eq!(piece[0], (x, v));
                match rows.last_mut() {
                    Some((last, row)) if *last == v => row.extend(piece),
                    _ => rows.push((v, piece)),
                }
                Ok(())
            })
            .unwrap();
        }
        assert!(a.is_complete());
        assert_eq!(a.held_pixels(), 0);
        rows
    }

    #[test]
    fn every_tile_buffer_comes_back_once_its_rows_have_left() {
        let region = Rect {
            x: 0,
            y: 0,
            width: 6,
            height: 4,
        };
        for shape in [TileShape::square(2), TileShape::rows(region, 2)] {
            let mut tiles = shape.cut(region);
            tiles.reverse();
            let mut a = RowAssembler::<(u32, u32)>::new(region);
            let mut back = Vec::new();
            for t in tiles.iter().copied() {
                a.push_reclaiming::<()>(tile(t), |_, _, _| Ok(()), |p| back.push(p[0]))
                    .unwrap();
            }
            back.sort();
            let mut corners: Vec<(u32, u32)> = tiles.iter().map(|t| (t.x, t.y)).collect();
            corners.sort();
            assert_eq!(back, corners, "{shape:?}");
        }
    }

    #[test]
    fn rows_leave_in_order_whatever_the_tile_order_or_shape() {
        let region = Rect {
            x: 2,
            y: 3,
            width: 5,
            height: 7,
        };
        for (w, h) in [(3, 3), (2, 1), (5, 1), (1, 4)] {
            let mut tiles = region.tiles_of(w, h);
            tiles.reverse();
            let rows = assemble(region, tiles);
            assert_eq!(rows.len(), 7);
            for (k, (v, row)) in rows.iter().enumerate() {
                assert_eq!(*v, 3 + k as u32);
                assert_eq!(row, &(2..7).map(|u| (u, *v)).collect::<Vec<_>>());
            }
        }
    }

    #[test]
    fn a_wide_frame_is_released_tile_by_tile() {
        let region = Rect::frame(4_000_000, 2);
        let shape = TileShape::rows(region, 32);
        assert_eq!(shape.height, 1);
        let mut a = RowAssembler::<u8>::new(region);
        let mut out = 0u64;
        let mut most = 0;
        let tiles = shape.cut(region);
        // Tiles finish a little out of order: each pair swapped.
        for pair in tiles.chunks(2) {
            for t in pair.iter().rev() {
                let px = vec![0u8; t.pixels() as usize];
                a.push::<()>(
                    Tile {
                        rect: *t,
                        pixels: px,
                        rays: 0,
                    },
                    |_, _, segs| {
                        out += segs.iter().map(|s| s.len() as u64).sum::<u64>();
                        Ok(())
                    },
                )
                .unwrap();
                most = most.max(a.held_pixels());
            }
        }
        assert_eq!(out, region.pixels());
        assert!(
            most <= shape.pixels(),
            "held {most} pixels of a {}-pixel row",
            region.width
        );
    }

    #[test]
    fn a_band_of_a_narrow_frame_is_held_until_complete_and_no_longer() {
        let region = Rect::frame(4096, 64);
        let shape = TileShape::rows(region, 32);
        let mut a = RowAssembler::<u8>::new(region);
        let mut most = 0;
        for t in shape.cut(region) {
            a.push::<()>(
                Tile {
                    rect: t,
                    pixels: vec![0; t.pixels() as usize],
                    rays: 0,
                },
                |_, _, _| Ok(()),
            )
            .unwrap();
            most = most.max(a.held_pixels());
        }
        assert!(a.is_complete());
        assert!(most < BAND_PIXELS, "held {most} pixels");
    }
}
