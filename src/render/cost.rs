//! What a render costs in rays, known before it starts and counted while it runs.
//!
//! A bound from the scene alone (pixels × samples² × the branching its materials allow
//! at each depth × the lights) is far too pessimistic for most Whitted scenes: a mirror
//! that fills a corner of the frame would count as if it filled all of it. So the
//! estimate is measured instead, by a *pilot*: the region's pixels on a regular grid of
//! at most [`PILOT_PIXELS`], each traced with all its samples at full depth by the
//! tracer itself
//! ([`Shader::trace_probed`](crate::render::shade::Shader::trace_probed)), in an order
//! that spreads any prefix over the frame. The rays they cost, scaled to the region's
//! pixel count, are the estimate.
//!
//! The pilot is bounded too. It stops as soon as the rays it counted, scaled the same
//! way, already exceed the limit it was asked about: that lower bound is enough to
//! refuse, and it is reached after at most `limit × grid / pixels` rays, a thousandth
//! of the limit or less for frames of a million pixels. It also never traces more than
//! [`PILOT_MAX_RAYS`] (small frames with costly pixels); then the pixels it finished
//! give the estimate. It runs on the calling thread, in a fixed order, so the same scene
//! and limit always give the same estimate.
//!
//! While the render runs, the tile loop charges every row's rays to a [`RayBudget`]
//! carried by its [`Cancel`] token; past the budget the token goes up and the render
//! stops within a row. The estimate is a sample, so a render is given
//! [`overrun_limit`] (half as much again as the limit) before it is stopped.

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::DVec3;

use super::shade::{Branch, RayCount, ShadingProbe};
use super::{Cancel, Rect, Renderer};
use crate::geometry::{Hit, Surface, ray::PRIMARY_LAMBDA_MIN};
use crate::scene::document::MaterialRefDoc;
use crate::scene::problem::Pointer;
use crate::scene::{Material, Problem, Scene};

/// The most rays a render may be estimated to trace: about two minutes of tracing for
/// each of two renders sharing a 2-core replica (measured: 8 M rays/s for the whole
/// replica on `scenes/showcase.json`), so even a render stopped only at half as much
/// again ([`overrun_limit`]) ends well within the default deadline.
/// The showcase at 2048² with 4 × 4 samples traces 345 M.
pub const DEFAULT_MAX_RAYS: u64 = 500_000_000;

/// Most pixels the pilot traces: a 32 × 32 grid on a square frame.
pub const PILOT_PIXELS: u64 = 1024;

/// Most rays the pilot traces, whatever the limit: about half a second of one core in
/// an optimised build, the worst case of a small frame whose pixels are all costly.
pub const PILOT_MAX_RAYS: u64 = 1 << 21;

/// The rays a render may trace before it is stopped, for a limit of `max_rays` on its
/// estimate: half as much again. The estimate samples a thousand pixels; what lies
/// between them (a small mirror the grid missed) can make the real count larger, and
/// a render refused near its end would waste all it traced.
pub fn overrun_limit(max_rays: u64) -> u64 {
    max_rays.saturating_add(max_rays / 2)
}

/// What a render's pixels report, which decides what they cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Work {
    /// A colour: every sample's Whitted tree (primary, shadow and secondary rays).
    Colour,
    /// The first hit: one primary ray per pixel, known without a pilot.
    Hits,
}

/// How many rays a render of a region is expected to trace.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Estimate {
    /// Rays estimated for the region; a lower bound when the pilot was cut short.
    pub rays: u64,
    /// Whether the pilot traced every pixel of its grid (or none were needed).
    pub complete: bool,
    /// Pixels in the pilot's grid (0 when no pilot was needed).
    pub pilot_pixels: u64,
    /// Rays the pilot traced.
    pub pilot_rays: u64,
    /// Materials (indices into [`Scene::materials`]) whose mirror or transmission sent
    /// secondary rays during the pilot, ascending.
    pub branching: Vec<u32>,
}

/// A render whose estimate exceeds the limit.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the scene would trace {}, more than the limit of {limit} rays", about(.estimate))]
pub struct TooCostly {
    /// The estimate.
    pub estimate: Estimate,
    /// The limit it exceeds.
    pub limit: u64,
    /// What the render computes.
    pub work: Work,
}

/// Why [`check`] gave no estimate.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CostError {
    /// The estimate exceeds the limit.
    #[error(transparent)]
    TooCostly(#[from] TooCostly),
    /// The token was cancelled while the pilot ran.
    #[error("the cost estimate was cancelled")]
    Cancelled,
}

/// `about N rays`, or `at least N rays` for a pilot cut short.
fn about(e: &Estimate) -> String {
    let how = if e.complete { "about" } else { "at least" };
    format!("{how} {} rays", e.rays)
}

/// Estimates the rays of rendering `region` of `r`'s frame as `work`, and refuses when
/// they exceed `max_rays`. The one check of every caller (server and command line).
pub fn check(
    r: &Renderer,
    region: Rect,
    work: Work,
    max_rays: u64,
    cancel: &Cancel,
) -> Result<Estimate, CostError> {
    let estimate = estimate(r, region, work, max_rays, cancel)?;
    if estimate.rays > max_rays {
        return Err(TooCostly {
            estimate,
            limit: max_rays,
            work,
        }
        .into());
    }
    Ok(estimate)
}

/// Estimates the rays of rendering `region` as `work`. The pilot stops once its count
/// proves the estimate is above `stop_above` (then the estimate is a lower bound above
/// it), or at [`PILOT_MAX_RAYS`]; between samples it stops when `cancel` goes up.
pub fn estimate(
    r: &Renderer,
    region: Rect,
    work: Work,
    stop_above: u64,
    cancel: &Cancel,
) -> Result<Estimate, CostError> {
    let pixels = region.pixels();
    if work == Work::Hits || pixels == 0 {
        return Ok(Estimate {
            rays: if work == Work::Hits { pixels } else { 0 },
            complete: true,
            pilot_pixels: 0,
            pilot_rays: 0,
            branching: Vec::new(),
        });
    }
    let (nx, ny) = grid(region, PILOT_PIXELS);
    let n = nx as u64 * ny as u64;
    // Past this count, `rays × pixels / n` exceeds `stop_above`: enough to refuse.
    let proof = (stop_above as u128 * n as u128 / pixels as u128 + 1).min(u64::MAX as u128) as u64;
    let budget = proof.min(PILOT_MAX_RAYS);

    let scene = &*r.scene;
    let shader = r.shader();
    let seen = vec![Cell::new(false); scene.materials.len()];
    let mut probe = Branching {
        scene,
        seen: &seen,
        at: None,
    };
    let mut rays = RayCount(0);
    let (mut done_pixels, mut done_rays) = (0u64, 0u64);
    let stride = coprime_stride(n);
    let s = scene.samples;
    'pixels: for k in 0..n {
        let cell = (k as u128 * stride as u128 % n as u128) as u64;
        let (gx, gy) = ((cell % nx as u64) as u32, (cell / nx as u64) as u32);
        let u = region.x + centre(gx, nx, region.width);
        let v = region.y + centre(gy, ny, region.height);
        for j in 0..s {
            for i in 0..s {
                if cancel.is_cancelled() {
                    return Err(CostError::Cancelled);
                }
                if rays.0 > budget {
                    break 'pixels;
                }
                let ray = r.sample_ray(u, v, i, j);
                shader.trace_probed(&ray, 0, PRIMARY_LAMBDA_MIN, &mut rays, &mut probe);
            }
        }
        done_pixels += 1;
        done_rays = rays.0;
    }
    let complete = done_pixels == n;
    // What the whole grid traced so far, as if the rest of it were free: a lower bound.
    let mut estimate = scale(rays.0, pixels, n);
    if !complete && done_pixels > 0 {
        estimate = estimate.max(scale(done_rays, pixels, done_pixels));
    }
    Ok(Estimate {
        rays: estimate,
        complete,
        pilot_pixels: n,
        pilot_rays: rays.0,
        branching: (0..seen.len() as u32)
            .filter(|&m| seen[m as usize].get())
            .collect(),
    })
}

/// `⌈rays × pixels / of⌉`, saturating.
fn scale(rays: u64, pixels: u64, of: u64) -> u64 {
    (rays as u128 * pixels as u128)
        .div_ceil(of.max(1) as u128)
        .min(u64::MAX as u128) as u64
}

/// The pilot's grid on `region`: every pixel when there are at most `target`, otherwise
/// at most `target` cells, shaped like the region (a single row for a single row).
fn grid(region: Rect, target: u64) -> (u32, u32) {
    let (w, h) = (region.width as u64, region.height as u64);
    if w * h <= target {
        return (region.width, region.height);
    }
    let nx = ((target as f64 * w as f64 / h as f64).sqrt().round() as u64).clamp(1, w.min(target));
    let ny = (target / nx).clamp(1, h);
    (nx as u32, ny as u32)
}

/// The pixel at the centre of cell `g` of `cells` along `len` pixels.
fn centre(g: u32, cells: u32, len: u32) -> u32 {
    ((2 * g as u64 + 1) * len as u64 / (2 * cells as u64)) as u32
}

/// A step coprime to `n` near `n / φ`: `k × step mod n` visits every cell once, and
/// any prefix of that order lies spread over the grid rather than in its top rows.
fn coprime_stride(n: u64) -> u64 {
    let mut p = ((n as f64 * 0.618_033_988_75).round() as u64).max(1);
    while gcd(p, n) != 1 {
        p += 1;
    }
    p
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// Records which materials send secondary rays: the probe of the tracer's own
/// recursion, so the pilot is the render's computation, not a model of it.
struct Branching<'a> {
    scene: &'a Scene,
    seen: &'a [Cell<bool>],
    /// The material of the surface this ray hit.
    at: Option<u32>,
}

impl ShadingProbe for Branching<'_> {
    fn surface(&mut self, hit: &Hit, _s: &Surface, _n: DVec3, _m: &Material, _ambient: DVec3) {
        self.at = self
            .scene
            .objects
            .get(hit.object as usize)
            .map(|o| o.material);
    }

    fn secondary(&mut self, _branch: Branch, _total_internal_reflection: bool) -> Self {
        if let Some(seen) = self.at.and_then(|m| self.seen.get(m as usize)) {
            seen.set(true);
        }
        Branching {
            scene: self.scene,
            seen: self.seen,
            at: None,
        }
    }
}

impl TooCostly {
    /// The fields that drive the cost, each with a message that states the estimate
    /// and the limit: the image's size, its samples and the recursion depth for colour,
    /// and every material that sent secondary rays in the pilot.
    pub fn problems(&self, scene: &Scene) -> Vec<Problem> {
        let tail = format!(
            "the scene would trace {}, more than the limit of {} rays",
            about(&self.estimate),
            self.limit
        );
        let root = Pointer::root();
        let image = root.key("image");
        let mut out = vec![
            Problem::new(
                image.key("width").to_string(),
                format!("{} pixels wide: {tail}", scene.width),
            ),
            Problem::new(
                image.key("height").to_string(),
                format!("{} pixels high: {tail}", scene.height),
            ),
        ];
        if self.work == Work::Hits {
            return out;
        }
        let s = scene.samples;
        out.push(Problem::new(
            image.key("samples").to_string(),
            format!("{}: {tail}", crate::scene::sample_grid(s)),
        ));
        if self.estimate.branching.is_empty() {
            return out;
        }
        out.push(Problem::new(
            root.key("max_depth").to_string(),
            format!(
                "secondary rays recurse up to {} deep: {tail}",
                scene.max_depth
            ),
        ));
        for pointer in material_pointers(scene, &self.estimate.branching) {
            out.push(Problem::new(
                pointer,
                format!("its mirror or transmission sends secondary rays: {tail}"),
            ));
        }
        out
    }
}

/// Where in the document each of `materials` is written: `/materials/{name}` for a
/// named one, `/objects/{i}/material` for one written in place, in that order.
fn material_pointers(scene: &Scene, materials: &[u32]) -> Vec<String> {
    let root = Pointer::root();
    let mut named = Vec::new();
    let mut inline = Vec::new();
    for (i, (doc, object)) in scene
        .document
        .objects
        .iter()
        .zip(&scene.objects)
        .enumerate()
    {
        if !materials.contains(&object.material) {
            continue;
        }
        match &doc.material {
            Some(MaterialRefDoc::Named(name)) => {
                let p = root.key("materials").key(name).to_string();
                if !named.contains(&p) {
                    named.push(p);
                }
            }
            Some(MaterialRefDoc::Inline(_)) => {
                inline.push(root.key("objects").index(i).key("material").to_string());
            }
            None => {}
        }
    }
    named.sort();
    named.extend(inline);
    named
}

/// A count of rays against a limit, shared by the threads of one render.
#[derive(Debug)]
pub struct RayBudget {
    limit: u64,
    used: AtomicU64,
}

impl RayBudget {
    /// A budget of `limit` rays, none used.
    pub fn new(limit: u64) -> RayBudget {
        RayBudget {
            limit,
            used: AtomicU64::new(0),
        }
    }

    /// Charges `rays`; whether the total now exceeds the limit.
    #[inline]
    pub fn charge(&self, rays: u64) -> bool {
        self.used
            .fetch_add(rays, Ordering::Relaxed)
            .saturating_add(rays)
            > self.limit
    }

    /// The limit.
    pub fn limit(&self) -> u64 {
        self.limit
    }

    /// Rays charged so far.
    pub fn used(&self) -> u64 {
        self.used.load(Ordering::Relaxed)
    }

    /// Whether more than the limit was charged.
    pub fn is_exceeded(&self) -> bool {
        self.used() > self.limit
    }
}

/// Scenes the tests of the cost estimate share (also the server's).
#[cfg(test)]
pub(crate) mod scenes {
    use serde_json::{Value, json};

    /// The camera inside two large spheres of one glass-and-mirror material: every ray
    /// hits a surface that reflects and refracts, to `max_depth` 10, at 1024² and
    /// 8 × 8 samples.
    pub fn branching() -> Value {
        json!({
            "version": 1,
            "image": { "width": 1024, "height": 1024, "samples": 8 },
            "max_depth": 10,
            "materials": { "glass": { "mirror": [0.5, 0.5, 0.5], "transmission": [0.5, 0.5, 0.5], "ior": 1.5 } },
            "objects": [
                { "shape": "sphere", "material": "glass", "transform": [{ "scale": 100 }] },
                { "shape": "sphere", "material": "glass", "transform": [{ "scale": 200 }] }
            ],
            "lights": [{ "type": "point", "position": [0, 50, 0], "colour": [1, 1, 1] }]
        })
    }

    /// A 1600² frame whose costly pixels all lie between the pilot's samples: a lattice
    /// of small balls centred on the corners of its 50-pixel grid cells, lit by 64
    /// lights, so each of their pixels traces 65 rays and every sample 1.
    pub fn hidden_cost() -> Value {
        let mut objects = Vec::new();
        for i in 1..32 {
            for j in 1..32 {
                let x = -1.0 + 2.0 * (50.0 * i as f64) / 1600.0;
                let y = -1.0 + 2.0 * (50.0 * j as f64) / 1600.0;
                objects.push(json!({
                    "shape": "sphere",
                    "transform": [{ "scale": 0.18 }, { "translate": [10.0 * x, 10.0 * y, 10.0] }]
                }));
            }
        }
        let lights: Vec<Value> = (0..64)
            .map(|k| json!({ "type": "point", "position": [0.01 * k as f64, 0, 0], "colour": [0.01, 0.01, 0.01] }))
            .collect();
        json!({
            "version": 1,
            "image": { "width": 1600, "height": 1600 },
            "objects": objects,
            "lights": lights
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{ColourKernel, SinkClosed, Tile, TileSink};
    use crate::scene::{Limits, parse_value};
    use std::sync::Arc;

    fn renderer(v: serde_json::Value) -> Renderer {
        Renderer::new(Arc::new(parse_value(v, &Limits::default()).unwrap()))
    }

    fn shipped(name: &str) -> serde_json::Value {
        let path = format!("{}/scenes/{name}", env!("CARGO_MANIFEST_DIR"));
        serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
    }

    struct Drop;
    impl<T> TileSink<T> for Drop {
        fn tile(&self, _: Tile<T>) -> Result<(), SinkClosed> {
            Ok(())
        }
    }

    /// The rays a full render of `r` traces.
    fn traced(r: &Renderer) -> u64 {
        crate::render::run(&ColourKernel(r), r.frame(), 32, &Cancel::new(), &Drop)
            .unwrap()
            .rays
    }

    #[test]
    fn the_grid_lies_in_the_region_and_never_exceeds_its_size() {
        for (w, h) in [
            (1, 1),
            (20, 30),
            (32, 32),
            (33, 32),
            (2048, 2048),
            (16_777_216, 1),
            (1, 100_000),
            (4000, 3),
        ] {
            let region = Rect {
                x: 7,
                y: 9,
                width: w,
                height: h,
            };
            let (nx, ny) = grid(region, PILOT_PIXELS);
            let n = nx as u64 * ny as u64;
            assert!(n <= PILOT_PIXELS.max(1) && n >= 1, "{w}×{h}: {nx}×{ny}");
            assert!(nx <= w && ny <= h, "{w}×{h}: {nx}×{ny}");
            if region.pixels() >= PILOT_PIXELS {
                assert!(n * 2 > PILOT_PIXELS, "{w}×{h}: only {nx}×{ny}");
            }
            assert!(centre(nx - 1, nx, w) < w && centre(ny - 1, ny, h) < h);
            let stride = coprime_stride(n);
            let mut cells: Vec<u64> = (0..n).map(|k| k * stride % n).collect();
            cells.sort();
            cells.dedup();
            assert_eq!(cells.len() as u64, n, "the order visits every cell once");
        }
    }

    #[test]
    fn a_frame_within_the_grid_is_estimated_exactly_and_alike_every_time() {
        let r = renderer(resized(shipped("showcase.json"), 32, 24));
        let e = estimate(&r, r.frame(), Work::Colour, u64::MAX, &Cancel::new()).unwrap();
        assert!(e.complete);
        assert_eq!(e.rays, traced(&r));
        assert_eq!(e.pilot_rays, e.rays);
        assert_eq!(
            estimate(&r, r.frame(), Work::Colour, u64::MAX, &Cancel::new()).unwrap(),
            e
        );
        // The showcase's mirror, glass and floor materials branch; the rest do not.
        let names: Vec<&str> = r
            .scene
            .document
            .materials
            .keys()
            .map(String::as_str)
            .collect();
        let branching: Vec<&str> = e.branching.iter().map(|&m| names[m as usize]).collect();
        assert_eq!(branching, ["floor", "glass", "mirror"]);
    }

    pub(super) fn resized(mut v: serde_json::Value, w: u32, h: u32) -> serde_json::Value {
        v["image"]["width"] = w.into();
        v["image"]["height"] = h.into();
        v
    }

    #[test]
    fn a_sparse_pilot_estimates_an_ordinary_scene_closely() {
        let r = renderer(resized(shipped("showcase.json"), 256, 192));
        let e = estimate(&r, r.frame(), Work::Colour, u64::MAX, &Cancel::new()).unwrap();
        let actual = traced(&r);
        assert!(e.complete && e.pilot_pixels > 900 && e.pilot_pixels <= 1024);
        let error = (e.rays as f64 - actual as f64).abs() / actual as f64;
        assert!(error < 0.05, "estimated {} rays, traced {actual}", e.rays);
    }

    #[test]
    fn hit_data_costs_one_ray_a_pixel_without_a_pilot() {
        let r = renderer(scenes::branching());
        let e = check(&r, r.frame(), Work::Hits, 1 << 20, &Cancel::new()).unwrap();
        assert_eq!((e.rays, e.pilot_rays), (1 << 20, 0));
        let Err(CostError::TooCostly(t)) = check(&r, r.frame(), Work::Hits, 1000, &Cancel::new())
        else {
            panic!("a million hit rays are more than a thousand");
        };
        let pointers: Vec<String> = t
            .problems(&r.scene)
            .into_iter()
            .map(|p| p.pointer)
            .collect();
        assert_eq!(pointers, ["/image/width", "/image/height"]);
    }

    #[test]
    fn a_branching_scene_is_refused_by_a_short_pilot() {
        let r = renderer(scenes::branching());
        let limit = 500_000_000;
        let started = std::time::Instant::now();
        let Err(CostError::TooCostly(t)) =
            check(&r, r.frame(), Work::Colour, limit, &Cancel::new())
        else {
            panic!("the branching scene passed");
        };
        eprintln!(
            "refused in {:?}: {t} ({} pilot rays)",
            started.elapsed(),
            t.estimate.pilot_rays
        );
        assert!(!t.estimate.complete);
        assert!(t.estimate.rays > limit);
        // It stopped as soon as its count proved the point: the proof plus one sample.
        let proof = limit as u128 * 1024 / (1024 * 1024) + 1;
        assert!((t.estimate.pilot_rays as u128) < proof + 4 * 2048);
        let problems = t.problems(&r.scene);
        let pointers: Vec<&str> = problems.iter().map(|p| p.pointer.as_str()).collect();
        assert_eq!(
            pointers,
            [
                "/image/width",
                "/image/height",
                "/image/samples",
                "/max_depth",
                "/materials/glass"
            ]
        );
        assert!(
            problems.iter().all(|p| p
                .message
                .contains(&format!("at least {} rays", t.estimate.rays))
                && p.message.contains("limit of 500000000 rays")),
            "{problems:?}"
        );
        // The same scene gives the same answer.
        assert_eq!(
            check(&r, r.frame(), Work::Colour, limit, &Cancel::new()),
            Err(CostError::TooCostly(t))
        );
    }

    #[test]
    fn the_showcase_at_2048_with_4x4_samples_is_within_the_default_limit() {
        let mut v = shipped("showcase.json");
        v["image"] =
            serde_json::json!({ "width": 2048, "height": 2048, "samples": 4, "gamma": 2.2 });
        let r = renderer(v);
        let started = std::time::Instant::now();
        let e = check(
            &r,
            r.frame(),
            Work::Colour,
            DEFAULT_MAX_RAYS,
            &Cancel::new(),
        )
        .unwrap();
        eprintln!(
            "pilot: {:?}, {} rays, estimate {}",
            started.elapsed(),
            e.pilot_rays,
            e.rays
        );
        assert!(e.complete);
        // 344 688 026 rays when rendered whole.
        assert!((300_000_000..400_000_000).contains(&e.rays), "{}", e.rays);
    }

    #[test]
    fn the_pilot_stops_when_cancelled() {
        let r = renderer(scenes::branching());
        let cancel = Cancel::new();
        cancel.cancel();
        assert_eq!(
            check(&r, r.frame(), Work::Colour, 1 << 40, &cancel),
            Err(CostError::Cancelled)
        );
    }

    #[test]
    fn costly_pixels_between_the_samples_are_stopped_by_the_budget() {
        let r = renderer(scenes::hidden_cost());
        let e = check(&r, r.frame(), Work::Colour, 4_000_000, &Cancel::new()).unwrap();
        assert_eq!(e.rays, 1600 * 1600, "the pilot sees only the background");
        let cancel = Cancel::with_ray_limit(overrun_limit(4_000_000));
        let stopped = crate::render::run(&ColourKernel(&r), r.frame(), 32, &cancel, &Drop);
        assert_eq!(stopped, Err(crate::render::Stopped::Cancelled));
        assert!(cancel.is_over_budget());
        let used = cancel.budget().unwrap().used();
        // Stopped within a row of a tile on each thread: 32 pixels of 65 rays.
        assert!(
            used > 6_000_000 && used < 6_000_000 + 64 * 32 * 65,
            "{used}"
        );
    }

    #[test]
    fn a_budget_counts_what_is_charged() {
        let b = RayBudget::new(10);
        assert!(!b.charge(10));
        assert!(!b.is_exceeded());
        assert!(b.charge(1));
        assert_eq!((b.used(), b.limit()), (11, 10));
        assert!(b.is_exceeded());
    }
}
