//! Turns tiles, which finish in any order, into complete rows in order, so that row-major
//! outputs (PNG, JSON and NPY hit data) can be written while the rest is still tracing.
//! Only the bands of tiles still in flight are held in memory, and pixels are never
//! copied: a complete row is handed over as the slices of the tiles it crosses.

use std::collections::BTreeMap;

use crate::render::{Rect, Tile};

/// Collects tiles into bands (one tile-row each) and releases bands top to bottom.
pub struct RowAssembler<T> {
    region: Rect,
    tile_px: u32,
    bands: BTreeMap<u32, Band<T>>,
    next_band: u32,
}

struct Band<T> {
    tiles: Vec<Tile<T>>,
    filled: u64,
}

impl<T> RowAssembler<T> {
    /// For the tiles of `region` cut at `tile_px` (as [`crate::render::run`] cuts them).
    pub fn new(region: Rect, tile_px: u32) -> Self {
        Self {
            region,
            tile_px: tile_px.max(1),
            bands: BTreeMap::new(),
            next_band: 0,
        }
    }

    /// The region being assembled.
    pub fn region(&self) -> Rect {
        self.region
    }

    /// Rows of the region released so far.
    pub fn rows_done(&self) -> u32 {
        self.next_band
            .saturating_mul(self.tile_px)
            .min(self.region.height)
    }

    /// Whether every row has been released.
    pub fn is_complete(&self) -> bool {
        self.rows_done() >= self.region.height
    }

    /// Takes a tile; calls `emit(v, segments)` for every row that became complete, in
    /// order, where `segments` are the row's pieces left to right.
    pub fn push<E>(
        &mut self,
        tile: Tile<T>,
        mut emit: impl FnMut(u32, &[&[T]]) -> Result<(), E>,
    ) -> Result<(), E> {
        let band_index = (tile.rect.y - self.region.y) / self.tile_px;
        let band = self.bands.entry(band_index).or_insert_with(|| Band {
            tiles: Vec::new(),
            filled: 0,
        });
        band.filled += tile.rect.pixels();
        band.tiles.push(tile);
        loop {
            let top = self.region.y + self.next_band * self.tile_px;
            let h = self
                .tile_px
                .min((self.region.y + self.region.height).saturating_sub(top));
            let complete = self
                .bands
                .get(&self.next_band)
                .is_some_and(|b| b.filled >= h as u64 * self.region.width as u64);
            if h == 0 || !complete {
                return Ok(());
            }
            if let Some(mut band) = self.bands.remove(&self.next_band) {
                band.tiles.sort_by_key(|t| t.rect.x);
                let mut segments: Vec<&[T]> = Vec::with_capacity(band.tiles.len());
                for row in 0..h as usize {
                    segments.clear();
                    segments.extend(band.tiles.iter().map(|t| {
                        let w = t.rect.width as usize;
                        &t.pixels[row * w..(row + 1) * w]
                    }));
                    emit(top + row as u32, &segments)?;
                }
            }
            self.next_band += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_leave_in_order_whatever_the_tile_order() {
        let region = Rect {
            x: 2,
            y: 3,
            width: 5,
            height: 7,
        };
        let mut tiles = region.tiles(3);
        tiles.reverse();
        let mut a = RowAssembler::<(u32, u32)>::new(region, 3);
        let mut rows = Vec::new();
        for t in tiles {
            let pixels = (t.y..t.y + t.height)
                .flat_map(|v| (t.x..t.x + t.width).map(move |u| (u, v)))
                .collect();
            a.push::<()>(
                Tile {
                    rect: t,
                    pixels,
                    rays: 0,
                },
                |v, segs| {
                    rows.push((v, segs.concat()));
                    Ok(())
                },
            )
            .unwrap();
        }
        assert!(a.is_complete());
        assert_eq!(rows.len(), 7);
        for (k, (v, row)) in rows.iter().enumerate() {
            assert_eq!(*v, 3 + k as u32);
            assert_eq!(row, &(2..7).map(|u| (u, *v)).collect::<Vec<_>>());
        }
    }
}
