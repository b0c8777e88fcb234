//! The tile loop, written once: the frame (or a region of it) is cut into tiles, rayon
//! workers take them in row-major order from a shared counter, trace every pixel with a
//! [`Kernel`], and push each finished tile into a [`TileSink`]. What differs between a
//! PNG, hit data and a progress bar is the kernel or the sink, never the loop.
//!
//! Every pixel is computed from its own `(u, v)` in full-frame coordinates, so the
//! result does not depend on the tile size, the thread count or the order tiles finish.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use rayon::prelude::*;

use super::Rect;
use super::cost::RayBudget;

/// Default tile edge in pixels.
pub const DEFAULT_TILE_PX: u32 = 32;

/// A finished tile: its rectangle and its pixels, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Tile<T> {
    /// Where it lies in the frame.
    pub rect: Rect,
    /// One value per pixel, row-major within the tile.
    pub pixels: Vec<T>,
    /// Rays traced for it (primary and secondary).
    pub rays: u64,
}

/// What a pixel reports.
pub trait Kernel: Sync {
    /// A pixel's value.
    type Pixel: Send;
    /// Computes pixel `(u, v)` of the full frame, adding the rays it traced to `rays`.
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> Self::Pixel;
}

/// Where finished tiles go. Called from the worker threads, in the order tiles finish.
pub trait TileSink<T>: Sync {
    /// Takes a finished tile. An error stops the render (e.g. the client left).
    fn tile(&self, tile: Tile<T>) -> Result<(), SinkClosed>;
}

/// A sink's way of saying it wants no more tiles.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the output was closed: {0}")]
pub struct SinkClosed(pub String);

/// Why a render stopped before its last tile.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Stopped {
    /// Someone cancelled it (a client disconnect, a deadline, shutdown).
    #[error("the render was cancelled")]
    Cancelled,
    /// The sink refused a tile.
    #[error(transparent)]
    Sink(#[from] SinkClosed),
}

/// A flag that stops a render between tiles, and within a tile between rows; cheap to
/// clone and share. It may carry a ray budget ([`Cancel::with_ray_limit`]): the tile loop
/// charges it the rays it traces, and the flag goes up once they pass the limit.
#[derive(Debug, Clone, Default)]
pub struct Cancel {
    flag: Arc<AtomicBool>,
    budget: Option<Arc<RayBudget>>,
}

impl Cancel {
    /// A fresh, uncancelled token.
    pub fn new() -> Self {
        Self::default()
    }

    /// A fresh token that also stops the render once it has traced more than `limit`
    /// rays.
    pub fn with_ray_limit(limit: u64) -> Self {
        Cancel {
            flag: Arc::default(),
            budget: Some(Arc::new(RayBudget::new(limit))),
        }
    }

    /// Asks every holder to stop.
    pub fn cancel(&self) {
        self.flag.store(true, Ordering::Relaxed);
    }

    /// Whether it was cancelled (also when its ray budget ran out).
    pub fn is_cancelled(&self) -> bool {
        self.flag.load(Ordering::Relaxed)
    }

    /// Charges `rays` traced to the budget, if there is one, and cancels once it is
    /// exceeded.
    #[inline]
    pub fn charge(&self, rays: u64) {
        if let Some(b) = &self.budget
            && b.charge(rays)
        {
            self.cancel();
        }
    }

    /// Whether the ray budget ran out (which cancelled the render).
    pub fn is_over_budget(&self) -> bool {
        self.budget.as_ref().is_some_and(|b| b.is_exceeded())
    }

    /// The ray budget, if the token carries one.
    pub fn budget(&self) -> Option<&RayBudget> {
        self.budget.as_deref()
    }
}

/// What a finished render counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Tiles traced.
    pub tiles: u64,
    /// Rays traced.
    pub rays: u64,
    /// Time spent tracing, summed over the worker threads (sinks not included).
    pub trace_thread_time: std::time::Duration,
}

/// Traces every tile of `region` with `kernel` into `sink`, on the current rayon pool.
/// Blocks until the last tile is handed over, or until cancelled.
pub fn run<K: Kernel, S: TileSink<K::Pixel>>(
    kernel: &K,
    region: Rect,
    tile_px: u32,
    cancel: &Cancel,
    sink: &S,
) -> Result<RenderStats, Stopped> {
    let rects = region.tiles(tile_px);
    let next = AtomicUsize::new(0);
    let rays = std::sync::atomic::AtomicU64::new(0);
    let nanos = std::sync::atomic::AtomicU64::new(0);
    // Each task takes the *next* tile from the counter, whatever rayon's split, so tiles
    // start (and mostly finish) in row-major order and streamed rows leave early.
    (0..rects.len())
        .into_par_iter()
        .with_max_len(1)
        .try_for_each(|_| {
            if cancel.is_cancelled() {
                return Err(Stopped::Cancelled);
            }
            let r = rects[next.fetch_add(1, Ordering::Relaxed)];
            let started = std::time::Instant::now();
            let mut pixels = Vec::with_capacity(r.pixels() as usize);
            let mut n = 0u64;
            for v in r.y..r.y + r.height {
                let before = n;
                for u in r.x..r.x + r.width {
                    pixels.push(kernel.pixel(u, v, &mut n));
                }
                // Charged by the row, not the pixel: one atomic add per row costs nothing
                // next to the row, and a costly render still stops within a row.
                cancel.charge(n - before);
                if cancel.is_cancelled() {
                    return Err(Stopped::Cancelled);
                }
            }
            rays.fetch_add(n, Ordering::Relaxed);
            nanos.fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
            sink.tile(Tile {
                rect: r,
                pixels,
                rays: n,
            })
            .map_err(|e| {
                cancel.cancel();
                Stopped::Sink(e)
            })
        })?;
    Ok(RenderStats {
        tiles: rects.len() as u64,
        rays: rays.into_inner(),
        trace_thread_time: std::time::Duration::from_nanos(nanos.into_inner()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn tiles_cover_the_region_once() {
        let r = Rect {
            x: 3,
            y: 5,
            width: 70,
            height: 33,
        };
        let tiles = r.tiles(32);
        assert_eq!(tiles.len(), 3 * 2);
        assert_eq!(tiles.iter().map(Rect::pixels).sum::<u64>(), r.pixels());
        assert!(tiles.iter().all(|t| t.within(&r)));
        assert_eq!(
            tiles[2],
            Rect {
                x: 67,
                y: 5,
                width: 6,
                height: 32
            }
        );
    }

    struct Coord;
    impl Kernel for Coord {
        type Pixel = (u32, u32);
        fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> (u32, u32) {
            *rays += 1;
            (u, v)
        }
    }

    struct Collect(Mutex<Vec<Tile<(u32, u32)>>>);
    impl TileSink<(u32, u32)> for Collect {
        fn tile(&self, t: Tile<(u32, u32)>) -> Result<(), SinkClosed> {
            self.0
                .lock()
                .map_err(|e| SinkClosed(e.to_string()))?
                .push(t);
            Ok(())
        }
    }

    #[test]
    fn every_pixel_reported_at_its_frame_coordinates() {
        let sink = Collect(Mutex::new(Vec::new()));
        let region = Rect {
            x: 10,
            y: 20,
            width: 50,
            height: 40,
        };
        let stats = run(&Coord, region, 16, &Cancel::new(), &sink).unwrap();
        assert_eq!(stats.rays, 2000);
        let tiles = sink.0.into_inner().unwrap();
        for t in &tiles {
            let mut k = 0;
            for v in t.rect.y..t.rect.y + t.rect.height {
                for u in t.rect.x..t.rect.x + t.rect.width {
                    assert_eq!(t.pixels[k], (u, v));
                    k += 1;
                }
            }
        }
    }

    struct Refuse;
    impl TileSink<(u32, u32)> for Refuse {
        fn tile(&self, _: Tile<(u32, u32)>) -> Result<(), SinkClosed> {
            Err(SinkClosed("gone".into()))
        }
    }

    #[test]
    fn a_refusing_sink_cancels_the_render() {
        let cancel = Cancel::new();
        let r = run(&Coord, Rect::frame(64, 64), 8, &cancel, &Refuse);
        assert!(matches!(r, Err(Stopped::Sink(_))));
        assert!(cancel.is_cancelled());
    }

    #[test]
    fn a_cancelled_render_traces_nothing() {
        let cancel = Cancel::new();
        cancel.cancel();
        let sink = Collect(Mutex::new(Vec::new()));
        assert_eq!(
            run(&Coord, Rect::frame(64, 64), 8, &cancel, &sink),
            Err(Stopped::Cancelled)
        );
        assert!(sink.0.into_inner().unwrap().is_empty());
    }
}
