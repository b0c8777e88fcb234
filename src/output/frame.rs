//! A sink that keeps a whole region in memory, for what is used or written whole: the
//! grader's reference frames, and the float images (PFM, OpenEXR) `raytile render`
//! writes, whose formats cannot be streamed row by row in tile order.

use std::sync::Mutex;

use crate::render::{Rect, SinkClosed, Tile, TileSink};

/// Collects a region's pixels, row-major, from tiles in any order.
pub struct FrameSink<T> {
    region: Rect,
    pixels: Mutex<Vec<T>>,
}

impl<T: Clone + Default> FrameSink<T> {
    /// A sink for `region`, every pixel `T::default()` until its tile arrives.
    pub fn new(region: Rect) -> FrameSink<T> {
        FrameSink {
            region,
            pixels: Mutex::new(vec![T::default(); region.pixels() as usize]),
        }
    }

    /// The pixels, row-major over the region; `None` when a worker panicked while
    /// holding them.
    pub fn into_pixels(self) -> Option<Vec<T>> {
        self.pixels.into_inner().ok()
    }
}

impl<T: Send> TileSink<T> for FrameSink<T> {
    fn tile(&self, tile: Tile<T>) -> Result<(), SinkClosed> {
        let mut px = self
            .pixels
            .lock()
            .map_err(|_| SinkClosed("a worker panicked".into()))?;
        let (r, f) = (tile.rect, self.region);
        for (k, p) in tile.pixels.into_iter().enumerate() {
            let (u, v) = (r.x + k as u32 % r.width, r.y + k as u32 / r.width);
            let (Some(x), Some(y)) = (u.checked_sub(f.x), v.checked_sub(f.y)) else {
                continue;
            };
            if x < f.width
                && let Some(slot) = px.get_mut(y as usize * f.width as usize + x as usize)
            {
                *slot = p;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Cancel, Kernel, run};

    struct Coord;
    impl Kernel for Coord {
        type Pixel = (u32, u32);
        fn pixel(&self, u: u32, v: u32, _rays: &mut u64) -> (u32, u32) {
            (u, v)
        }
    }

    #[test]
    fn a_region_is_collected_in_row_major_order() {
        let region = Rect {
            x: 3,
            y: 2,
            width: 5,
            height: 4,
        };
        let sink = FrameSink::new(region);
        run(&Coord, region, 2, &Cancel::new(), &sink).unwrap();
        let px = sink.into_pixels().unwrap();
        assert_eq!(px.len(), 20);
        assert_eq!(px[0], (3, 2));
        assert_eq!(px[6], (4, 3));
        assert_eq!(px[19], (7, 5));
    }
}
