//! Turns tiles, which finish in any order, into complete rows in order, so that row-major
//! outputs (PNG, JSON and NPY hit data) can be written while the rest is still tracing.
//! Only the bands of tiles still in flight are held in memory.

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
    pixels: Vec<T>,
    filled: u64,
}

impl<T: Clone + Default> RowAssembler<T> {
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
        (self.next_band * self.tile_px).min(self.region.height)
    }

    /// Takes a tile; calls `emit(v, row)` for every row that became complete, in order.
    pub fn push<E>(
        &mut self,
        tile: Tile<T>,
        mut emit: impl FnMut(u32, &[T]) -> Result<(), E>,
    ) -> Result<(), E> {
        let r = tile.rect;
        let band_index = (r.y - self.region.y) / self.tile_px;
        let band_top = self.region.y + band_index * self.tile_px;
        let band_height = self
            .tile_px
            .min(self.region.y + self.region.height - band_top);
        let width = self.region.width as usize;
        let band = self.bands.entry(band_index).or_insert_with(|| Band {
            pixels: vec![T::default(); width * band_height as usize],
            filled: 0,
        });
        for row in 0..r.height as usize {
            let dst = (r.y - band_top) as usize + row;
            let start = dst * width + (r.x - self.region.x) as usize;
            band.pixels[start..start + r.width as usize].clone_from_slice(
                &tile.pixels[row * r.width as usize..(row + 1) * r.width as usize],
            );
        }
        band.filled += r.pixels();
        while let Some(band) = self.bands.get(&self.next_band) {
            let top = self.region.y + self.next_band * self.tile_px;
            let h = self.tile_px.min(self.region.y + self.region.height - top);
            if band.filled < h as u64 * width as u64 {
                break;
            }
            if let Some(band) = self.bands.remove(&self.next_band) {
                for (k, row) in band.pixels.chunks(width.max(1)).enumerate() {
                    emit(top + k as u32, row)?;
                }
            }
            self.next_band += 1;
        }
        Ok(())
    }

    /// Whether every row has been released.
    pub fn is_complete(&self) -> bool {
        self.rows_done() >= self.region.height
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
                |v, row| {
                    rows.push((v, row.to_vec()));
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
