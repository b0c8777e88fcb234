//! References rendered once: the reference of a scene (its 8-bit image, its linear
//! image, its hit data) kept by a hash of the scene's normalised document, so that
//! every later submission for the same scene is compared without rendering it again.
//!
//! - **The key** ([`SceneKey`]) is the SHA-256 of the validated document written back
//!   as JSON: members in their declaration order, named materials sorted, `color`
//!   spelled `colour`, `5.0` and `5` the same number. Two documents that differ only in
//!   how they are written (key order, spacing, aliases) share a reference; any change
//!   that can change a pixel is a different key.
//! - **Bounded in bytes**: each entry is counted at what its pixels take; past the
//!   capacity, the least recently used entries go first. Each entry also takes its
//!   bytes from a [`Ledger`] (the server's memory budget) while it is held, and gives
//!   them back whenever the ledger asks ([`ReferenceCache::release`]): the cache makes
//!   room rather than make a request wait or fail. An entry that finds no room is not
//!   kept; the grade that rendered it is answered all the same.
//! - **One render for concurrent misses**: a caller that is about to grade takes its
//!   [`Turn`] first ([`ReferenceCache::turn`], asynchronous, so waiting holds no
//!   thread). The first caller for a missing reference leads; the others wait until
//!   the leader's turn ends, and then find the reference (or, if the leader was
//!   cancelled or failed, the next of them leads). The wait is not done on the trace
//!   threads themselves: a trace thread waiting inside a job can be running on top of
//!   the very render it waits for (rayon runs queued jobs while it waits for a tile),
//!   which would never finish.
//! - **Only finished renders are kept**: a render that is cancelled or fails leaves no
//!   entry behind, so the next caller renders again.
//!
//! `hits`, `misses`, `bytes` and `entries` are counted in [`CacheMetrics`]
//! (`raytile_reference_cache_*` on the server's `/metrics`).

use std::any::Any;
use std::collections::HashMap;
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use prometheus::{IntCounter, IntGauge};
use sha2::{Digest, Sha256};
use tokio::sync::Notify;

use super::{GradeError, RgbImage, Submission};
use crate::format::{LinearImage, Raster};
use crate::geometry::Surface;
use crate::scene::Scene;

/// What an entry costs beyond its pixels (the entry, its key, the map's slot).
const ENTRY_OVERHEAD_BYTES: u64 = 256;

/// The hash of a scene's normalised document.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SceneKey([u8; 32]);

impl fmt::Debug for SceneKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "SceneKey({})", hex::encode(self.0))
    }
}

/// Feeds what is written into the hash, so that the document is never held as text.
struct HashWriter(Sha256);

impl std::io::Write for HashWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.update(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl SceneKey {
    /// The key of `scene`: the SHA-256 of its document as serde writes it back. The
    /// document's types write every member in one order and their maps sorted, so the
    /// text is the same however the document was written. None if it cannot be
    /// written (it always can for a validated scene; then nothing is cached).
    pub fn of(scene: &Scene) -> Option<SceneKey> {
        let mut h = HashWriter(Sha256::new());
        serde_json::to_writer(&mut h, &scene.document).ok()?;
        Some(SceneKey(h.0.finalize().into()))
    }

    /// The key in hexadecimal, for logs.
    pub fn hex(&self) -> String {
        hex::encode(self.0)
    }
}

/// Which reference of a scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    /// The 8-bit image, as `raytile render` writes it.
    Image,
    /// The linear colours, for float submissions (PFM, OpenEXR).
    Linear,
    /// The hit data, as `raytile hits` writes it.
    Hits,
}

impl Kind {
    /// The reference `submission` is compared with.
    pub fn of(submission: &Submission) -> Kind {
        match submission {
            Submission::Image(img) => match img.pixels {
                Raster::Rgb8(_) => Kind::Image,
                Raster::Linear(_) => Kind::Linear,
            },
            Submission::Hits(_) => Kind::Hits,
        }
    }
}

impl Kind {
    /// The reference a graded part names (`"image"`, `"hits"`), for an 8-bit image.
    pub fn of_part(part: &str) -> Option<Kind> {
        match part {
            "image" => Some(Kind::Image),
            "hits" => Some(Kind::Hits),
            _ => None,
        }
    }
}

/// What grading `scenes` (each with the parts it grades, as [`Kind::of_part`] reads
/// them) wants of the cache, for [`ReferenceCache::turn`]. Hashes every document: call
/// it off the async threads.
pub fn wants(scenes: &[(Arc<Scene>, &[&str])]) -> Vec<(SceneKey, Kind)> {
    scenes
        .iter()
        .filter_map(|(scene, parts)| Some((SceneKey::of(scene)?, *parts)))
        .flat_map(|(key, parts)| {
            parts
                .iter()
                .filter_map(move |p| Some((key, Kind::of_part(p)?)))
        })
        .collect()
}

/// A reference the cache can keep: which kind it is and what it takes in memory.
pub trait Cached: Any + Send + Sync {
    /// Its kind.
    const KIND: Kind;
    /// Bytes its pixels take.
    fn bytes(&self) -> u64;
}

impl Cached for RgbImage {
    const KIND: Kind = Kind::Image;
    fn bytes(&self) -> u64 {
        self.data.capacity() as u64
    }
}

impl Cached for LinearImage {
    const KIND: Kind = Kind::Linear;
    fn bytes(&self) -> u64 {
        (self.data.capacity() * std::mem::size_of::<f32>()) as u64
    }
}

impl Cached for Vec<Option<Surface>> {
    const KIND: Kind = Kind::Hits;
    fn bytes(&self) -> u64 {
        (self.capacity() * std::mem::size_of::<Option<Surface>>()) as u64
    }
}

/// A reference, from the cache or just rendered.
#[derive(Debug)]
pub struct Rendered<T> {
    /// The reference.
    pub value: Arc<T>,
    /// How long rendering it took (when it was rendered, for a cached one): diagnosis
    /// sizes its time budget by it, so a cached reference is diagnosed as the first.
    pub render_time: Duration,
    /// Whether it came from the cache.
    pub hit: bool,
}

/// Renders a reference without a cache, timing it.
pub fn render_uncached<T>(
    render: impl FnOnce() -> Result<T, GradeError>,
) -> Result<Rendered<T>, GradeError> {
    let started = Instant::now();
    let value = Arc::new(render()?);
    Ok(Rendered {
        value,
        render_time: started.elapsed(),
        hit: false,
    })
}

/// Bytes held in a ledger for an entry; dropping it gives them back.
pub type Lease = Box<dyn Any + Send + Sync>;

/// Where the cache's bytes are counted besides its own capacity (the server's memory
/// budget). It must never call back into the cache.
pub trait Ledger: Send + Sync + fmt::Debug {
    /// `bytes` taken now, or None when they do not fit now (nothing is waited for).
    fn try_take(&self, bytes: u64) -> Option<Lease>;
}

/// The cache's counters and gauges, `raytile_reference_cache_*`.
#[derive(Debug, Clone)]
pub struct CacheMetrics {
    /// References found in the cache.
    pub hits: IntCounter,
    /// References rendered because they were not.
    pub misses: IntCounter,
    /// Bytes held now.
    pub bytes: IntGauge,
    /// Entries held now.
    pub entries: IntGauge,
}

impl CacheMetrics {
    /// The four metrics, registered nowhere yet.
    pub fn new() -> prometheus::Result<CacheMetrics> {
        Ok(CacheMetrics {
            hits: IntCounter::new(
                "raytile_reference_cache_hits_total",
                "Grades whose reference was found in the reference cache.",
            )?,
            misses: IntCounter::new(
                "raytile_reference_cache_misses_total",
                "Grades whose reference was rendered because the cache did not hold it.",
            )?,
            bytes: IntGauge::new(
                "raytile_reference_cache_bytes",
                "Bytes the reference cache holds (also reserved in the memory budget).",
            )?,
            entries: IntGauge::new(
                "raytile_reference_cache_entries",
                "References the reference cache holds.",
            )?,
        })
    }

    /// Each metric, to register.
    pub fn collectors(&self) -> Vec<Box<dyn prometheus::core::Collector>> {
        vec![
            Box::new(self.hits.clone()),
            Box::new(self.misses.clone()),
            Box::new(self.bytes.clone()),
            Box::new(self.entries.clone()),
        ]
    }
}

struct Entry {
    value: Arc<dyn Any + Send + Sync>,
    bytes: u64,
    render_time: Duration,
    /// When it was last used, in the cache's own ticks.
    used: u64,
    _lease: Option<Lease>,
}

#[derive(Default)]
struct State {
    entries: HashMap<(SceneKey, Kind), Entry>,
    bytes: u64,
    tick: u64,
    /// The scenes whose turn is taken, with what wakes the callers waiting for it.
    leads: HashMap<SceneKey, Arc<Notify>>,
}

impl State {
    /// Drops the least recently used entry; its bytes, or None when there is none.
    fn evict_oldest(&mut self) -> Option<u64> {
        let oldest = *self.entries.iter().min_by_key(|(_, e)| e.used)?.0;
        let e = self.entries.remove(&oldest)?;
        self.bytes -= e.bytes;
        Some(e.bytes)
    }
}

/// The references of recently graded scenes, at most `capacity` bytes of them.
pub struct ReferenceCache {
    capacity: u64,
    ledger: Option<Arc<dyn Ledger>>,
    metrics: CacheMetrics,
    state: Mutex<State>,
}

impl fmt::Debug for ReferenceCache {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let st = self.lock();
        f.debug_struct("ReferenceCache")
            .field("capacity", &self.capacity)
            .field("bytes", &st.bytes)
            .field("entries", &st.entries.len())
            .finish()
    }
}

impl ReferenceCache {
    /// A cache of at most `capacity` bytes, taking them from `ledger` too if given.
    pub fn new(
        capacity: u64,
        ledger: Option<Arc<dyn Ledger>>,
        metrics: CacheMetrics,
    ) -> ReferenceCache {
        ReferenceCache {
            capacity,
            ledger,
            metrics,
            state: Mutex::new(State::default()),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // The state is consistent between statements: a panic elsewhere leaves it usable.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The most it holds.
    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Bytes held now.
    pub fn bytes(&self) -> u64 {
        self.lock().bytes
    }

    /// Entries held now.
    pub fn len(&self) -> usize {
        self.lock().entries.len()
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Its metrics.
    pub fn metrics(&self) -> &CacheMetrics {
        &self.metrics
    }

    fn publish(&self, st: &State) {
        self.metrics.bytes.set(st.bytes as i64);
        self.metrics.entries.set(st.entries.len() as i64);
    }

    /// The `T` reference of the scene `key`: from the cache, or rendered by `render`
    /// (on the calling thread) and kept if there is room. A render that fails or is
    /// cancelled returns its error and keeps nothing. Never waits for another caller:
    /// see [`ReferenceCache::turn`] for that.
    pub fn get_or_render<T: Cached>(
        &self,
        key: SceneKey,
        render: impl FnOnce() -> Result<T, GradeError>,
    ) -> Result<Rendered<T>, GradeError> {
        if let Some(hit) = self.get::<T>(key) {
            self.metrics.hits.inc();
            return Ok(hit);
        }
        self.metrics.misses.inc();
        let rendered = render_uncached(render)?;
        self.insert(key, &rendered);
        Ok(rendered)
    }

    fn get<T: Cached>(&self, key: SceneKey) -> Option<Rendered<T>> {
        let mut st = self.lock();
        st.tick += 1;
        let tick = st.tick;
        let e = st.entries.get_mut(&(key, T::KIND))?;
        e.used = tick;
        let value = e.value.clone().downcast::<T>().ok()?;
        Some(Rendered {
            value,
            render_time: e.render_time,
            hit: true,
        })
    }

    fn insert<T: Cached>(&self, key: SceneKey, r: &Rendered<T>) {
        let bytes = r.value.bytes() + ENTRY_OVERHEAD_BYTES;
        if bytes > self.capacity {
            return;
        }
        let mut st = self.lock();
        // Another caller that did not wait for a turn may have rendered it meanwhile.
        if st.entries.contains_key(&(key, T::KIND)) {
            return;
        }
        while st.bytes + bytes > self.capacity && st.evict_oldest().is_some() {}
        let lease = match &self.ledger {
            None => None,
            Some(ledger) => loop {
                if let Some(lease) = ledger.try_take(bytes) {
                    break Some(lease);
                }
                if st.evict_oldest().is_none() {
                    // The budget is taken by requests: grading them matters more.
                    self.publish(&st);
                    return;
                }
            },
        };
        st.tick += 1;
        let used = st.tick;
        st.entries.insert(
            (key, T::KIND),
            Entry {
                value: r.value.clone(),
                bytes,
                render_time: r.render_time,
                used,
                _lease: lease,
            },
        );
        st.bytes += bytes;
        self.publish(&st);
    }

    /// Drops the least recently used entries until at least `bytes` are freed (or none
    /// is left), giving their bytes back to the ledger; the bytes freed. Grades using
    /// an entry keep their copy until they end.
    pub fn release(&self, bytes: u64) -> u64 {
        let mut st = self.lock();
        let mut freed = 0;
        while freed < bytes {
            match st.evict_oldest() {
                Some(b) => freed += b,
                None => break,
            }
        }
        if freed > 0 {
            tracing::debug!(
                freed_bytes = freed,
                "the reference cache gave memory back to the budget"
            );
        }
        self.publish(&st);
        freed
    }

    /// Waits (without holding a thread) until grading the references `wants` renders
    /// none of them that another caller is rendering now. For each scene in `wants`
    /// whose references are not all cached, the caller either leads (nobody else is
    /// grading it: the returned turn holds it until dropped) or waits for whoever does,
    /// and then looks again. Scenes are taken in the order of their keys, so callers
    /// wanting several never wait for each other in a circle. Grade while holding the
    /// turn, and drop it when the grading ends, finished or not.
    pub async fn turn(self: &Arc<Self>, wants: &[(SceneKey, Kind)]) -> Turn {
        let mut keys: Vec<SceneKey> = wants.iter().map(|w| w.0).collect();
        keys.sort();
        keys.dedup();
        let mut turn = Turn {
            cache: self.clone(),
            led: Vec::new(),
        };
        for key in keys {
            loop {
                let leader = {
                    let mut st = self.lock();
                    let cached = wants
                        .iter()
                        .filter(|w| w.0 == key)
                        .all(|w| st.entries.contains_key(w));
                    if cached {
                        break;
                    }
                    match st.leads.get(&key) {
                        Some(n) => n.clone(),
                        None => {
                            st.leads.insert(key, Arc::new(Notify::new()));
                            turn.led.push(key);
                            break;
                        }
                    }
                };
                let ended = leader.notified();
                tokio::pin!(ended);
                ended.as_mut().enable();
                // The turn may have ended between the look and `enable`: look again.
                let still = self
                    .lock()
                    .leads
                    .get(&key)
                    .is_some_and(|n| Arc::ptr_eq(n, &leader));
                if still {
                    ended.await;
                }
            }
        }
        turn
    }
}

/// The scenes a caller leads until it drops this (see [`ReferenceCache::turn`]).
#[derive(Debug)]
pub struct Turn {
    cache: Arc<ReferenceCache>,
    led: Vec<SceneKey>,
}

impl Turn {
    /// How many scenes this turn leads (renders, if they are still missing).
    pub fn leads(&self) -> usize {
        self.led.len()
    }
}

impl Drop for Turn {
    fn drop(&mut self) {
        let woken: Vec<Arc<Notify>> = {
            let mut st = self.cache.lock();
            self.led.iter().filter_map(|k| st.leads.remove(k)).collect()
        };
        for n in woken {
            n.notify_waiters();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    use crate::render::{Cancel, Renderer};
    use crate::scene::{Limits, parse};

    fn scene(text: &str) -> Scene {
        parse(text.as_bytes(), &Limits::default()).unwrap()
    }

    const BALL: &str = r#"{"version": 1, "image": {"width": 8, "height": 6},
        "materials": {"red": {"diffuse": [1, 0, 0]}, "blue": {"diffuse": [0, 0, 1]}},
        "objects": [{"shape": "sphere", "material": "red",
                     "transform": [{"translate": [0, 0, 3]}]}],
        "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]}"#;

    fn key(text: &str) -> SceneKey {
        SceneKey::of(&scene(text)).unwrap()
    }

    fn cache(capacity: u64) -> ReferenceCache {
        ReferenceCache::new(capacity, None, CacheMetrics::new().unwrap())
    }

    fn image(bytes: usize, fill: u8) -> RgbImage {
        RgbImage {
            width: bytes as u32 / 3,
            height: 1,
            data: vec![fill; bytes],
        }
    }

    #[test]
    fn the_same_document_written_otherwise_has_the_same_key() {
        // Keys reordered (at the top, in a material, in an object), other spacing,
        // `color` for `colour`, 3.0 for 3, the materials listed the other way round.
        let reordered = r#"{"lights": [{"color": [1, 1, 1], "position": [0, -4, 0], "type": "point"}],
            "objects": [{"transform": [{"translate": [0.0, 0, 3.0]}], "material": "red",
                         "shape": "sphere"}],
            "materials": {"blue": {"diffuse": [0, 0, 1]}, "red": {"diffuse": [1.0, 0, 0]}},
            "image": {"height": 6, "width": 8}, "version": 1}"#;
        assert_eq!(key(BALL), key(reordered));
    }

    #[test]
    fn a_different_document_has_a_different_key() {
        let moved = BALL.replace("[0, 0, 3]", "[0, 0, 3.5]");
        let wider = BALL.replace(r#""width": 8"#, r#""width": 9"#);
        let recoloured = BALL.replace("[0, 0, 1]", "[0, 1, 1]");
        let keys = [key(BALL), key(&moved), key(&wider), key(&recoloured)];
        for i in 0..keys.len() {
            for j in i + 1..keys.len() {
                assert_ne!(keys[i], keys[j], "{i} and {j}");
            }
        }
    }

    #[test]
    fn a_miss_renders_and_a_hit_does_not() {
        let c = cache(1 << 20);
        let k = key(BALL);
        let renders = AtomicUsize::new(0);
        let render = || {
            renders.fetch_add(1, Ordering::SeqCst);
            Ok(image(300, 7))
        };
        let first = c.get_or_render(k, render).unwrap();
        assert!(!first.hit);
        let second = c.get_or_render(k, render).unwrap();
        assert!(second.hit);
        assert_eq!(renders.load(Ordering::SeqCst), 1);
        assert!(Arc::ptr_eq(&first.value, &second.value));
        assert_eq!(second.render_time, first.render_time);
        assert_eq!((c.metrics.hits.get(), c.metrics.misses.get()), (1, 1));
        assert_eq!(c.len(), 1);
        assert_eq!(c.bytes(), 300 + ENTRY_OVERHEAD_BYTES);
        assert_eq!(c.metrics.bytes.get() as u64, c.bytes());
        assert_eq!(c.metrics.entries.get(), 1);
        // Another kind of the same scene is another reference.
        let hits = c.get_or_render(k, || Ok(vec![None; 4])).unwrap();
        assert!(!hits.hit);
        assert_eq!(c.len(), 2);
    }

    #[test]
    fn the_least_recently_used_go_first_past_the_capacity() {
        let entry = 1000 + ENTRY_OVERHEAD_BYTES;
        let c = cache(3 * entry);
        let keys: Vec<SceneKey> = (0..4)
            .map(|i| key(&BALL.replace("[0, 0, 3]", &format!("[0, 0, {}]", 3 + i))))
            .collect();
        for (i, k) in keys.iter().take(3).enumerate() {
            c.get_or_render(*k, || Ok(image(1000, i as u8))).unwrap();
        }
        assert_eq!(c.bytes(), 3 * entry);
        // The first is used again: the second is now the oldest.
        assert!(c.get_or_render(keys[0], || Ok(image(1000, 9))).unwrap().hit);
        c.get_or_render(keys[3], || Ok(image(1000, 3))).unwrap();
        assert_eq!((c.len(), c.bytes()), (3, 3 * entry));
        // Looked at without using it, which would change the order.
        let cached = |k: SceneKey| c.lock().entries.contains_key(&(k, Kind::Image));
        assert!(cached(keys[0]) && !cached(keys[1]) && cached(keys[2]) && cached(keys[3]));
        // Larger than the whole cache: rendered, not kept, nothing evicted for it.
        let big = c.get_or_render(keys[1], || Ok(image(4000, 1))).unwrap();
        assert_eq!(big.value.data.len(), 4000);
        assert_eq!(c.len(), 3);
        // Released on demand, oldest first.
        assert_eq!(c.release(1), entry);
        assert!(!cached(keys[2]));
        assert_eq!(c.release(u64::MAX), 2 * entry);
        assert!(c.is_empty());
        assert_eq!((c.metrics.bytes.get(), c.metrics.entries.get()), (0, 0));
    }

    /// A ledger of `free` bytes that counts what it lends.
    #[derive(Debug)]
    struct Budget(Arc<Mutex<u64>>);

    struct Loan(Arc<Mutex<u64>>, u64);

    impl Drop for Loan {
        fn drop(&mut self) {
            *self.0.lock().unwrap() += self.1;
        }
    }

    impl Ledger for Budget {
        fn try_take(&self, bytes: u64) -> Option<Lease> {
            let mut free = self.0.lock().unwrap();
            if *free < bytes {
                return None;
            }
            *free -= bytes;
            Some(Box::new(Loan(self.0.clone(), bytes)))
        }
    }

    #[test]
    fn entries_hold_their_bytes_in_the_ledger_and_make_room_when_it_is_full() {
        let entry = 1000 + ENTRY_OVERHEAD_BYTES;
        let free = Arc::new(Mutex::new(2 * entry));
        let c = ReferenceCache::new(
            10 * entry,
            Some(Arc::new(Budget(free.clone()))),
            CacheMetrics::new().unwrap(),
        );
        let k = |i: u32| key(&BALL.replace("[0, 0, 3]", &format!("[0, 0, {}]", 3 + i)));
        c.get_or_render(k(0), || Ok(image(1000, 0))).unwrap();
        c.get_or_render(k(1), || Ok(image(1000, 1))).unwrap();
        assert_eq!(*free.lock().unwrap(), 0);
        // The ledger is full: the oldest entry gives its bytes to the new one.
        c.get_or_render(k(2), || Ok(image(1000, 2))).unwrap();
        assert_eq!(c.len(), 2);
        assert!(c.get::<RgbImage>(k(0)).is_none());
        // Someone else takes what the ledger has: an entry that finds no room is not kept.
        c.release(u64::MAX);
        let someone = Budget(free.clone()).try_take(2 * entry).unwrap();
        let r = c.get_or_render(k(3), || Ok(image(1000, 3))).unwrap();
        assert!(!r.hit);
        assert!(c.is_empty());
        drop(someone);
        assert_eq!(*free.lock().unwrap(), 2 * entry);
    }

    #[test]
    fn a_cancelled_or_failed_render_leaves_no_entry() {
        let c = cache(1 << 20);
        let s = Arc::new(scene(BALL));
        let k = SceneKey::of(&s).unwrap();
        let r = Renderer::new(s);
        let cancel = Cancel::new();
        cancel.cancel();
        let e = c
            .get_or_render(k, || super::super::reference_image(&r, &cancel))
            .unwrap_err();
        assert_eq!(e, GradeError::Cancelled);
        let e = c
            .get_or_render::<RgbImage>(k, || Err(GradeError::Reference("no".into())))
            .unwrap_err();
        assert!(matches!(e, GradeError::Reference(_)));
        assert!(c.is_empty());
        // The next caller renders it, and it is kept.
        let fresh = Cancel::new();
        let img = c
            .get_or_render(k, || super::super::reference_image(&r, &fresh))
            .unwrap();
        assert!(!img.hit);
        assert_eq!(c.len(), 1);
        assert_eq!(c.metrics.misses.get(), 3);
    }

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_time()
            .build()
            .unwrap()
    }

    #[test]
    fn concurrent_misses_render_once() {
        runtime().block_on(async {
            let c = Arc::new(cache(1 << 20));
            let k = key(BALL);
            let renders = Arc::new(AtomicUsize::new(0));
            let mut tasks = Vec::new();
            for _ in 0..8 {
                let (c, renders) = (c.clone(), renders.clone());
                tasks.push(tokio::spawn(async move {
                    let turn = c.turn(&[(k, Kind::Image)]).await;
                    // Graded off the runtime's threads, as the server does.
                    tokio::task::spawn_blocking(move || {
                        let r = c.get_or_render(k, || {
                            renders.fetch_add(1, Ordering::SeqCst);
                            std::thread::sleep(Duration::from_millis(50));
                            Ok(image(300, 1))
                        });
                        drop(turn);
                        r.map(|r| r.hit)
                    })
                    .await
                    .unwrap()
                }));
            }
            let mut hits = 0;
            for t in tasks {
                hits += t.await.unwrap().unwrap() as usize;
            }
            assert_eq!(renders.load(Ordering::SeqCst), 1);
            assert_eq!(hits, 7);
            assert_eq!((c.metrics.hits.get(), c.metrics.misses.get()), (7, 1));
        });
    }

    #[test]
    fn a_cancelled_leader_hands_the_turn_on() {
        runtime().block_on(async {
            let c = Arc::new(cache(1 << 20));
            let k = key(BALL);
            let first = c.turn(&[(k, Kind::Image)]).await;
            assert_eq!(first.leads(), 1);
            let (c2, waiter) = (c.clone(), tokio::sync::oneshot::channel::<usize>());
            let (tx, rx) = waiter;
            let second = tokio::spawn(async move {
                let t = c2.turn(&[(k, Kind::Image)]).await;
                let _ = tx.send(t.leads());
                t
            });
            tokio::time::sleep(Duration::from_millis(20)).await;
            // The leader's render is cancelled: nothing kept, and the waiter leads next.
            let e = c.get_or_render::<RgbImage>(k, || Err(GradeError::Cancelled));
            assert_eq!(e.unwrap_err(), GradeError::Cancelled);
            drop(first);
            assert_eq!(rx.await.unwrap(), 1);
            let second = second.await.unwrap();
            c.get_or_render(k, || Ok(image(300, 1))).unwrap();
            drop(second);
            // Cached now: a turn for it leads nothing and does not wait.
            assert_eq!(c.turn(&[(k, Kind::Image)]).await.leads(), 0);
            // A turn dropped while waiting leaves nothing taken.
            let hold = c.turn(&[(k, Kind::Hits)]).await;
            let c3 = c.clone();
            let gone = tokio::spawn(async move { c3.turn(&[(k, Kind::Hits)]).await.leads() });
            tokio::time::sleep(Duration::from_millis(20)).await;
            gone.abort();
            drop(hold);
            assert_eq!(c.turn(&[(k, Kind::Hits)]).await.leads(), 1);
        });
    }
}
