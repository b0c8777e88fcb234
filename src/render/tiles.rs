//! The tile loop: the frame (or a region of it) is cut into tiles of the shape its sink
//! asks for ([`TileSink::tile_shape`]), each tile is traced with a [`Kernel`]
//! ([`trace_tile`], the one place that does) and pushed into a [`TileSink`]. What
//! differs between a PNG, hit data and a progress bar is the kernel or the sink.
//!
//! Two drivers hand out the tiles, in row-major order: [`run`] blocks its caller until
//! the last tile (the command line, a grade's reference, the cost pilot), while the
//! server steps a render a tile at a time through the [`Scheduler`] with a
//! [`TileCursor`], so that a render whose client does not read can park without holding
//! a thread, and the tiles of every admitted render interleave on the pool.
//!
//! Every pixel is computed from its own `(u, v)` in full-frame coordinates, so the
//! result does not depend on the tile size or shape, the thread count or the order
//! tiles finish.

use std::collections::{BTreeSet, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use super::Rect;
use super::cost::RayBudget;

/// Default tile edge in pixels.
pub const DEFAULT_TILE_PX: u32 = 32;

/// Neighbouring pixels whose primary rays are traced as one packet: four of each of
/// two rows, or eight of a row where a tile has one row left. A tile's pixels beyond a
/// multiple of the packet's width are traced one at a time, at a greater cost.
pub const PACKET_PIXELS: u32 = 8;

/// Rows a tile's kernel is given at a time ([`Kernel::rows`]): a pair, so that a packet
/// can be a block of two rows ([`PACKET_PIXELS`]).
pub const KERNEL_ROWS: u32 = 2;

/// The most pixels a band (one row of tiles) spans when it is more than one pixel high,
/// for sinks that write rows in order ([`TileShape::rows`]): they must hold a band's
/// tiles until its last one is in.
pub const BAND_PIXELS: u64 = 16 * 1024;

/// The size of the tiles a region is cut into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileShape {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl TileShape {
    /// `tile_px` square.
    pub fn square(tile_px: u32) -> TileShape {
        let t = tile_px.max(1);
        TileShape {
            width: t,
            height: t,
        }
    }

    /// Tiles of about `tile_px²` pixels for a sink that writes the rows of `region` in
    /// order: as high as `tile_px` while a band of them spans at most [`BAND_PIXELS`],
    /// lower (down to one row, wider to keep their area) for wider regions. A band one
    /// row high is released tile by tile ([`crate::output::RowAssembler`]), so what a
    /// sink holds is bounded whatever the region's width. A tile widened so is a
    /// multiple of [`PACKET_PIXELS`] wide (for a 1280-wide frame, 80 instead of 85:
    /// no pixel traced alone).
    pub fn rows(region: Rect, tile_px: u32) -> TileShape {
        let t = tile_px.max(1) as u64;
        let h = (BAND_PIXELS / region.width.max(1) as u64).clamp(1, t);
        let mut w = (t * t / h).min(region.width.max(1) as u64).max(1);
        let packet = u64::from(PACKET_PIXELS);
        if h < t && w > packet && w < u64::from(region.width) {
            w -= w % packet;
        }
        TileShape {
            width: w as u32,
            height: h as u32,
        }
    }

    /// Pixels in one tile.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// The tiles of `region`, row-major.
    pub fn cut(&self, region: Rect) -> Vec<Rect> {
        region.tiles_of(self.width, self.height)
    }
}

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

#[cfg(test)]
impl<T> Tile<T> {
    /// A tile over `rect` whose pixel (u, v) is `f(u, v)`, as the sinks' tests feed them.
    pub(crate) fn filled(rect: Rect, f: impl Fn(u32, u32) -> T) -> Tile<T> {
        let pixels = (rect.y..rect.y + rect.height)
            .flat_map(|v| (rect.x..rect.x + rect.width).map(move |u| (u, v)))
            .map(|(u, v)| f(u, v))
            .collect();
        Tile {
            rect,
            pixels,
            rays: 0,
        }
    }
}

/// What a pixel reports.
pub trait Kernel: Sync {
    /// A pixel's value.
    type Pixel: Send;
    /// Computes pixel `(u, v)` of the full frame, adding the rays it traced to `rays`.
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> Self::Pixel;

    /// Appends row `v` of pixels `u` to `u + width − 1`, each what [`Kernel::pixel`]
    /// gives, to `out[0]`, and row `v + 1` to `out[1]` when `rows` is 2: a kernel may
    /// trace neighbours together. The tile loop asks for [`KERNEL_ROWS`] rows at a
    /// time (one where a tile has one left), and appends the second row's pixels after
    /// the first's.
    #[inline]
    fn rows(
        &self,
        (u, v, width, rows): (u32, u32, u32, u32),
        rays: &mut u64,
        out: [&mut Vec<Self::Pixel>; KERNEL_ROWS as usize],
    ) {
        for (v, out) in (v..v + rows).zip(out) {
            for u in u..u + width {
                out.push(self.pixel(u, v, rays));
            }
        }
    }
}

/// Where finished tiles go. Called from the worker threads, in the order tiles finish.
pub trait TileSink<T>: Sync {
    /// Takes a finished tile. An error stops the render (e.g. the client left).
    fn tile(&self, tile: Tile<T>) -> Result<(), SinkClosed>;

    /// The tiles it wants for `region` when asked for `tile_px`: square unless it says
    /// otherwise (a sink writing rows in order wants [`TileShape::rows`]).
    fn tile_shape(&self, region: Rect, tile_px: u32) -> TileShape {
        let _ = region;
        TileShape::square(tile_px)
    }
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

/// Traces the pixels of `r` with `kernel`, row by row, charging `cancel`'s ray budget
/// and stopping between rows once it is cancelled.
pub fn trace_tile<K: Kernel>(
    kernel: &K,
    r: Rect,
    cancel: &Cancel,
) -> Result<Tile<K::Pixel>, Stopped> {
    let mut pixels = Vec::with_capacity(r.pixels() as usize);
    // A pair's second row, gathered apart and then appended in one bulk copy: each
    // pixel made in its place in the tile would be copied through the stack twice.
    let mut second = Vec::with_capacity(r.width as usize);
    let mut n = 0u64;
    for v in (r.y..r.y + r.height).step_by(KERNEL_ROWS as usize) {
        let rows = KERNEL_ROWS.min(r.y + r.height - v);
        let before = n;
        kernel.rows((r.x, v, r.width, rows), &mut n, [&mut pixels, &mut second]);
        pixels.append(&mut second);
        // Charged by the rows, not the pixel: one atomic add per pair of rows costs
        // nothing next to them, and a costly render still stops within two rows.
        cancel.charge(n - before);
        if cancel.is_cancelled() {
            return Err(Stopped::Cancelled);
        }
    }
    Ok(Tile {
        rect: r,
        pixels,
        rays: n,
    })
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
    let rects = sink.tile_shape(region, tile_px).cut(region);
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
            let tile = trace_tile(kernel, r, cancel)?;
            rays.fetch_add(tile.rays, Ordering::Relaxed);
            nanos.fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
            sink.tile(tile).map_err(|e| {
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

/// The tiles of a render stepped one at a time, handed out in row-major order but never
/// more than `window` ahead of the oldest tile still being traced: so a sink that puts
/// tiles in order holds at most that many out of order, however slow one tile is.
#[derive(Debug)]
pub struct TileCursor {
    rects: Vec<Rect>,
    window: usize,
    state: Mutex<CursorState>,
}

#[derive(Debug, Default)]
struct CursorState {
    next: usize,
    running: BTreeSet<usize>,
    done: usize,
}

impl TileCursor {
    /// For the tiles `rects`, at most `window` (at least 1) ahead of the oldest running.
    pub fn new(rects: Vec<Rect>, window: usize) -> TileCursor {
        TileCursor {
            rects,
            window: window.max(1),
            state: Mutex::default(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, CursorState> {
        // The state is a few counters, consistent after every statement.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn may_take(&self, s: &CursorState) -> bool {
        let oldest = s.running.first().copied().unwrap_or(s.next);
        s.next < self.rects.len() && s.next < oldest + self.window
    }

    /// The next tile and its index, unless all are handed out or the window is full.
    pub fn take(&self) -> Option<(usize, Rect)> {
        let mut s = self.lock();
        if !self.may_take(&s) {
            return None;
        }
        let i = s.next;
        s.next += 1;
        s.running.insert(i);
        Some((i, self.rects[i]))
    }

    /// Whether [`TileCursor::take`] would hand out a tile now.
    pub fn can_take(&self) -> bool {
        self.may_take(&self.lock())
    }

    /// Marks tile `i` as finished (or abandoned).
    pub fn finished(&self, i: usize) {
        let mut s = self.lock();
        if s.running.remove(&i) {
            s.done += 1;
        }
    }

    /// Whether every tile has been handed out and finished.
    pub fn is_done(&self) -> bool {
        self.lock().done == self.rects.len()
    }

    /// The number of tiles.
    pub fn len(&self) -> usize {
        self.rects.len()
    }

    /// Whether there are no tiles at all.
    pub fn is_empty(&self) -> bool {
        self.rects.is_empty()
    }
}

/// A piece of CPU work the [`Scheduler`] runs one step at a time.
pub trait Step: Send + Sync + 'static {
    /// Does one step (e.g. traces one tile). To go on, it schedules itself again.
    fn step(self: Arc<Self>, scheduler: &Arc<Scheduler>);
}

/// One entry of the queue.
enum Entry {
    Once(Box<dyn FnOnce() + Send>),
    Step(Arc<dyn Step>),
}

/// A rayon pool with one first-come, first-served queue in front of it: every entry is a
/// step of a render (one tile) or a job run once, and each rayon task takes the entry at
/// the front of the queue, whichever thread it lands on. A render steps itself back to
/// the end of the queue after each tile, so the tiles of every admitted render
/// interleave and a small render waits behind a few tiles of a large one, not behind
/// all of them (rayon alone would run a worker's own tasks, last in first out, before
/// anything new).
pub struct Scheduler {
    pool: rayon::ThreadPool,
    queue: Mutex<VecDeque<Entry>>,
}

impl std::fmt::Debug for Scheduler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scheduler")
            .field("threads", &self.pool.current_num_threads())
            .field("queued", &self.queued())
            .finish()
    }
}

impl Scheduler {
    /// Queues work for `pool`.
    pub fn new(pool: rayon::ThreadPool) -> Arc<Scheduler> {
        Arc::new(Scheduler {
            pool,
            queue: Mutex::new(VecDeque::new()),
        })
    }

    /// The pool's threads.
    pub fn current_num_threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// Entries waiting now.
    pub fn queued(&self) -> usize {
        self.queue.lock().map_or(0, |q| q.len())
    }

    /// Runs `f` once, in its turn.
    pub fn spawn(self: &Arc<Self>, f: impl FnOnce() + Send + 'static) {
        self.push(Entry::Once(Box::new(f)));
    }

    /// Runs one step of `step`, in its turn.
    pub fn schedule(self: &Arc<Self>, step: Arc<dyn Step>) {
        self.push(Entry::Step(step));
    }

    fn push(self: &Arc<Self>, e: Entry) {
        self.queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push_back(e);
        // One rayon task per entry: it runs whichever entry is at the front then.
        let me = self.clone();
        self.pool.spawn(move || me.run_one());
    }

    fn run_one(self: &Arc<Self>) {
        let e = self
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop_front();
        match e {
            Some(Entry::Once(f)) => f(),
            Some(Entry::Step(s)) => s.step(self),
            None => {}
        }
    }
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
    fn row_tiles_keep_bands_small_or_one_row_high() {
        for (w, h) in [
            (1, 1),
            (64, 64),
            (512, 512),
            (4096, 4096),
            (16_383, 3),
            (843_137, 5),
            (4_000_000, 1),
        ] {
            let region = Rect::frame(w, h);
            let s = TileShape::rows(region, DEFAULT_TILE_PX);
            assert!(
                s.height >= 1 && s.height <= DEFAULT_TILE_PX,
                "{w}×{h}: {s:?}"
            );
            assert!(
                s.height == 1 || w as u64 * s.height as u64 <= BAND_PIXELS,
                "{w}×{h}: a band of {s:?} spans more than {BAND_PIXELS} pixels"
            );
            assert!(s.pixels() <= (DEFAULT_TILE_PX * DEFAULT_TILE_PX) as u64);
            let tiles = s.cut(region);
            assert_eq!(tiles.iter().map(Rect::pixels).sum::<u64>(), region.pixels());
        }
        // Widened tiles hold whole packets.
        for (w, h) in [(1280, 720), (1920, 1080), (3000, 100), (16_383, 3)] {
            let s = TileShape::rows(Rect::frame(w, h), DEFAULT_TILE_PX);
            assert_eq!(s.width % PACKET_PIXELS, 0, "{w}×{h}: {s:?}");
        }
        assert_eq!(
            TileShape::rows(Rect::frame(1280, 720), 32),
            TileShape {
                width: 80,
                height: 12
            }
        );
        // Narrow frames keep the square tiles.
        assert_eq!(
            TileShape::rows(Rect::frame(300, 200), 32),
            TileShape::square(32)
        );
    }

    #[test]
    fn the_cursor_stays_within_its_window_of_the_oldest_running_tile() {
        let c = TileCursor::new(Rect::frame(100, 1).tiles(1), 3);
        let (a, _) = c.take().unwrap();
        let (b, _) = c.take().unwrap();
        let (d, _) = c.take().unwrap();
        assert_eq!((a, b, d), (0, 1, 2));
        assert!(c.take().is_none(), "three ahead of tile 0");
        c.finished(2);
        c.finished(1);
        assert!(!c.can_take(), "tile 0 still runs");
        c.finished(0);
        assert_eq!(c.take().map(|t| t.0), Some(3));
        c.finished(3);
        while let Some((i, _)) = c.take() {
            c.finished(i);
        }
        assert!(c.is_done());
    }

    struct Counted {
        name: u32,
        left: Mutex<u32>,
        log: Arc<Mutex<Vec<u32>>>,
    }
    impl Step for Counted {
        fn step(self: Arc<Self>, s: &Arc<Scheduler>) {
            self.log.lock().unwrap().push(self.name);
            let mut left = self.left.lock().unwrap();
            *left -= 1;
            if *left > 0 {
                drop(left);
                s.schedule(self);
            }
        }
    }

    #[test]
    fn the_scheduler_interleaves_the_steps_of_its_renders() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let s = Scheduler::new(pool);
        let log = Arc::new(Mutex::new(Vec::new()));
        let (tx, rx) = std::sync::mpsc::channel();
        // Hold the only thread while a large and then a small render are queued.
        s.spawn(move || {
            let _ = rx.recv();
        });
        let large = Arc::new(Counted {
            name: 1,
            left: Mutex::new(100),
            log: log.clone(),
        });
        let small = Arc::new(Counted {
            name: 2,
            left: Mutex::new(2),
            log: log.clone(),
        });
        s.schedule(large);
        s.schedule(small);
        tx.send(()).unwrap();
        while log.lock().unwrap().len() < 102 {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let log = log.lock().unwrap();
        let last_small = log.iter().rposition(|&n| n == 2).unwrap();
        assert!(last_small <= 3, "the small render waited: {:?}", &log[..10]);
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
