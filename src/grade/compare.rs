//! Pixel by pixel: which submitted pixels are within tolerance of the reference, how far
//! off the others are, the worst of them side by side, and the difference image.
//!
//! A colour pixel passes when every channel is within `colour_abs` of the reference. A
//! hit-data pixel passes when it agrees on hit or miss and, for a hit, on the object
//! (when the submission names one), on `λ` within `lambda_rel` relative error, and on
//! the normal within `normal_degrees`. In edge-forgiving mode a pixel that fails also
//! passes when it would pass against any reference pixel of its 3 × 3 neighbourhood
//! (anti-aliased or rounding-sensitive silhouettes differ by a pixel).
//!
//! A float image (PFM, OpenEXR) is compared in linear radiance, before gamma and
//! quantisation: a pixel passes when every channel is within
//! `linear_abs + linear_rel · |reference|` of the reference's linear value; a NaN or an
//! infinity fails.

use glam::DVec3;
use serde::Serialize;

use super::Tolerances;
use super::image::RgbImage;
use super::submission::SubmittedHit;
use crate::format::LinearImage;
use crate::geometry::Surface;

/// The colour failing pixels are painted in the difference image.
pub const FAIL_RGB: [u8; 3] = [255, 0, 255];

/// How much of the reference shows through under the marks (so failures stand out).
const DIM: f64 = 0.35;

/// What one failing check is called in reports.
pub mod check {
    /// A colour channel out of tolerance.
    pub const COLOUR: &str = "colour";
    /// A linear channel out of tolerance.
    pub const LINEAR: &str = "linear";
    /// Hit where the reference misses, or the reverse.
    pub const HIT_MISS: &str = "hit_miss";
    /// A different object.
    pub const OBJECT: &str = "object";
    /// `λ` out of tolerance.
    pub const LAMBDA: &str = "lambda";
    /// Normal out of tolerance.
    pub const NORMAL: &str = "normal";
}

/// A pixel's value, reference or submitted, as the report shows it.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum PixelValue {
    /// An 8-bit colour.
    Colour {
        /// `[r, g, b]`.
        rgb: [u8; 3],
    },
    /// A linear colour, before gamma and quantisation.
    Linear {
        /// `[r, g, b]` (`null` for a NaN or an infinity).
        linear: [Option<f32>; 3],
    },
    /// Hit data.
    Hit {
        /// Whether something was hit.
        hit: bool,
        /// The object.
        object: Option<u32>,
        /// The ray parameter.
        lambda: Option<f64>,
        /// The world point.
        point: Option<[f64; 3]>,
        /// The normal.
        normal: Option<[f64; 3]>,
    },
}

/// One of the worst pixels.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WorstPixel {
    /// Column.
    pub u: u32,
    /// Row.
    pub v: u32,
    /// Whether the pixel passes anyway (within tolerance, or forgiven at an edge).
    pub pass: bool,
    /// The checks it fails against the reference at the same pixel.
    pub failures: Vec<&'static str>,
    /// Largest channel difference (images).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colour_error: Option<u8>,
    /// Largest channel difference in linear radiance (float images; NaN for a value
    /// that is not finite, then written as `null`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub linear_error: Option<f64>,
    /// `|λ − λref| / λref` (hit data, both hit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lambda_rel_error: Option<f64>,
    /// Angle between the normals in degrees (hit data, both hit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_angle_degrees: Option<f64>,
    /// The reference's value.
    pub reference: PixelValue,
    /// The submitted value.
    pub submitted: PixelValue,
}

/// Failing pixels per check (a pixel may fail several).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct HitCounts {
    /// Hit where the reference misses, or the reverse.
    pub hit_miss: u64,
    /// A different object (only when the submission names objects).
    pub wrong_object: u64,
    /// `λ` out of tolerance.
    pub lambda: u64,
    /// Normal out of tolerance.
    pub normal: u64,
    /// Largest `λ` relative error where both hit (`null` for NaN or when none).
    pub max_lambda_rel_error: Option<f64>,
    /// Mean `λ` relative error where both hit.
    pub mean_lambda_rel_error: Option<f64>,
    /// Largest normal angle in degrees where both hit.
    pub max_normal_angle_degrees: Option<f64>,
    /// Pixels where both hit.
    pub both_hit: u64,
}

/// Statistics of a linear comparison (float images).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct LinearCounts {
    /// Largest channel difference where both values are finite.
    pub max_abs_error: f64,
    /// Mean channel difference where both values are finite.
    pub mean_abs_error: f64,
    /// Submitted channels that are NaN or infinite (each fails its pixel).
    pub non_finite: u64,
}

/// The outcome of a comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// Pixels that fail (after edge forgiveness).
    pub failing: u64,
    /// Pixels forgiven by the edge-forgiving mode.
    pub forgiven: u64,
    /// The worst pixels, worst first.
    pub worst: Vec<WorstPixel>,
    /// Per-check counts, for hit data.
    pub hits: Option<HitCounts>,
    /// Error statistics, for float images compared in linear radiance.
    pub linear: Option<LinearCounts>,
    /// Failing pixels in [`FAIL_RGB`] over the dimmed reference.
    pub diff: RgbImage,
}

fn dim(c: [u8; 3]) -> [u8; 3] {
    c.map(|x| (x as f64 * DIM).round() as u8)
}

/// The 3 × 3 neighbourhood of `(u, v)` within a `w × h` frame, the pixel itself first.
fn neighbours(u: u32, v: u32, w: u32, h: u32) -> impl Iterator<Item = (u32, u32)> {
    let us = u.saturating_sub(1)..=(u + 1).min(w - 1);
    let vs = v.saturating_sub(1)..=(v + 1).min(h - 1);
    std::iter::once((u, v)).chain(
        vs.flat_map(move |y| us.clone().map(move |x| (x, y)))
            .filter(move |&p| p != (u, v)),
    )
}

/// How bad a pixel is: compared element by element (larger is worse), then the earlier
/// pixel (row, then column) first, so the list is the same on every run.
#[derive(Debug, Clone, Copy)]
struct Rank {
    key: [f64; 3],
    u: u32,
    v: u32,
}

impl Rank {
    fn cmp(&self, other: &Rank) -> std::cmp::Ordering {
        self.key
            .iter()
            .zip(&other.key)
            .map(|(a, b)| a.total_cmp(b))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
            .then((other.v, other.u).cmp(&(self.v, self.u)))
    }
}

struct Ranked(Rank, WorstPixel);

impl PartialEq for Ranked {
    fn eq(&self, other: &Self) -> bool {
        self.0.cmp(&other.0).is_eq()
    }
}
impl Eq for Ranked {}
impl PartialOrd for Ranked {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Ranked {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.cmp(&other.0)
    }
}

/// The `n` worst pixels seen, kept in a bounded heap: memory stays `O(n)` however many
/// pixels differ, and a pixel's record is built only when it makes the list.
struct Worst {
    n: usize,
    heap: std::collections::BinaryHeap<std::cmp::Reverse<Ranked>>,
}

impl Worst {
    fn new(n: usize) -> Worst {
        Worst {
            n,
            heap: std::collections::BinaryHeap::with_capacity(n.min(1 << 16) + 1),
        }
    }

    fn offer(&mut self, rank: Rank, make: impl FnOnce() -> WorstPixel) {
        if self.n == 0 {
            return;
        }
        if self.heap.len() == self.n {
            match self.heap.peek() {
                Some(least) if rank.cmp(&least.0.0).is_gt() => {
                    self.heap.pop();
                }
                _ => return,
            }
        }
        self.heap.push(std::cmp::Reverse(Ranked(rank, make())));
    }

    /// Worst first.
    fn into_vec(self) -> Vec<WorstPixel> {
        // Ascending order of `Reverse` is descending order of rank.
        self.heap
            .into_sorted_vec()
            .into_iter()
            .map(|r| r.0.1)
            .collect()
    }
}

/// Compares two images of the same size.
pub fn images(
    reference: &RgbImage,
    submitted: &RgbImage,
    tol: &Tolerances,
    worst: usize,
) -> Comparison {
    let (w, h) = (reference.width, reference.height);
    let within = |a: [u8; 3], b: [u8; 3]| (0..3).all(|k| a[k].abs_diff(b[k]) <= tol.colour_abs);
    let mut failing = 0;
    let mut forgiven = 0;
    let mut diff = RgbImage {
        width: w,
        height: h,
        data: Vec::with_capacity(reference.data.len()),
    };
    let mut top = Worst::new(worst);
    for v in 0..h {
        for u in 0..w {
            let (r, s) = (reference.get(u, v), submitted.get(u, v));
            let err = (0..3).map(|k| r[k].abs_diff(s[k])).max().unwrap_or(0);
            let direct = err <= tol.colour_abs;
            let pass = direct
                || (tol.edge_forgiving
                    && neighbours(u, v, w, h).any(|(x, y)| within(reference.get(x, y), s)));
            if !pass {
                failing += 1;
            } else if !direct {
                forgiven += 1;
            }
            diff.data
                .extend_from_slice(&if pass { dim(r) } else { FAIL_RGB });
            if err > 0 {
                let sum: u32 = (0..3).map(|k| r[k].abs_diff(s[k]) as u32).sum();
                let rank = Rank {
                    key: [(!pass) as u8 as f64, err as f64, sum as f64],
                    u,
                    v,
                };
                top.offer(rank, || WorstPixel {
                    u,
                    v,
                    pass,
                    failures: if direct { vec![] } else { vec![check::COLOUR] },
                    colour_error: Some(err),
                    linear_error: None,
                    lambda_rel_error: None,
                    normal_angle_degrees: None,
                    reference: PixelValue::Colour { rgb: r },
                    submitted: PixelValue::Colour { rgb: s },
                });
            }
        }
    }
    Comparison {
        failing,
        forgiven,
        worst: top.into_vec(),
        hits: None,
        linear: None,
        diff,
    }
}

/// How many tolerances off a linear channel is (infinite for NaN or an infinity).
fn linear_excess(r: f32, s: f32, tol: &Tolerances) -> f64 {
    let (r, s) = (r as f64, s as f64);
    let d = (s - r).abs();
    if !d.is_finite() {
        return f64::INFINITY;
    }
    let allowed = tol.linear_abs + tol.linear_rel * r.abs();
    if allowed > 0.0 {
        d / allowed
    } else if d > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// The worst channel of a pixel, in tolerances (≤ 1 passes).
fn linear_pixel_excess(r: [f32; 3], s: [f32; 3], tol: &Tolerances) -> f64 {
    (0..3)
        .map(|k| linear_excess(r[k], s[k], tol))
        .fold(0.0, f64::max)
}

fn finite(c: [f32; 3]) -> [Option<f32>; 3] {
    c.map(|x| x.is_finite().then_some(x))
}

/// Compares two linear images of the same size; `picture` is the reference as 8-bit
/// RGB, the picture under the difference image.
pub fn linear(
    reference: &LinearImage,
    submitted: &LinearImage,
    picture: &RgbImage,
    tol: &Tolerances,
    worst: usize,
) -> Comparison {
    let (w, h) = (reference.width, reference.height);
    let mut failing = 0;
    let mut forgiven = 0;
    let mut counts = LinearCounts::default();
    let (mut sum, mut n) = (0.0, 0u64);
    let mut diff = RgbImage {
        width: w,
        height: h,
        data: Vec::with_capacity(w as usize * h as usize * 3),
    };
    let mut top = Worst::new(worst);
    for v in 0..h {
        for u in 0..w {
            let (r, s) = (reference.get(u, v), submitted.get(u, v));
            let (mut err, mut bad) = (0.0f64, false);
            for k in 0..3 {
                let d = (s[k] as f64 - r[k] as f64).abs();
                if d.is_finite() {
                    err = err.max(d);
                    sum += d;
                    n += 1;
                } else {
                    counts.non_finite += 1;
                    bad = true;
                }
            }
            counts.max_abs_error = counts.max_abs_error.max(err);
            let err = if bad { f64::NAN } else { err };
            let excess = linear_pixel_excess(r, s, tol);
            let direct = excess <= 1.0;
            let pass = direct
                || (tol.edge_forgiving
                    && neighbours(u, v, w, h)
                        .skip(1)
                        .any(|(x, y)| linear_pixel_excess(reference.get(x, y), s, tol) <= 1.0));
            if !pass {
                failing += 1;
            } else if !direct {
                forgiven += 1;
            }
            diff.data.extend_from_slice(&if pass {
                dim(picture.get(u, v))
            } else {
                FAIL_RGB
            });
            if err != 0.0 {
                let rank = Rank {
                    key: [(!pass) as u8 as f64, excess, err],
                    u,
                    v,
                };
                top.offer(rank, || WorstPixel {
                    u,
                    v,
                    pass,
                    failures: if direct { vec![] } else { vec![check::LINEAR] },
                    colour_error: None,
                    linear_error: Some(err),
                    lambda_rel_error: None,
                    normal_angle_degrees: None,
                    reference: PixelValue::Linear { linear: finite(r) },
                    submitted: PixelValue::Linear { linear: finite(s) },
                });
            }
        }
    }
    counts.mean_abs_error = if n > 0 { sum / n as f64 } else { 0.0 };
    Comparison {
        failing,
        forgiven,
        worst: top.into_vec(),
        hits: None,
        linear: Some(counts),
        diff,
    }
}

/// One hit-data pixel checked against one reference pixel.
#[derive(Debug, Clone, Copy, Default)]
struct HitCheck {
    hit_miss: bool,
    object: bool,
    lambda: bool,
    normal: bool,
    lambda_rel: Option<f64>,
    angle: Option<f64>,
}

impl HitCheck {
    fn pass(&self) -> bool {
        !(self.hit_miss || self.object || self.lambda || self.normal)
    }

    fn failures(&self) -> Vec<&'static str> {
        [
            (self.hit_miss, check::HIT_MISS),
            (self.object, check::OBJECT),
            (self.lambda, check::LAMBDA),
            (self.normal, check::NORMAL),
        ]
        .into_iter()
        .filter_map(|(f, name)| f.then_some(name))
        .collect()
    }
}

/// The angle between two vectors in degrees, NaN when either has no direction.
/// `atan2(|a × b|, a · b)` stays accurate for tiny angles, where `acos` does not.
pub fn angle_degrees(a: DVec3, b: DVec3) -> f64 {
    let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
    if a == DVec3::ZERO || b == DVec3::ZERO || !a.is_finite() || !b.is_finite() {
        return f64::NAN;
    }
    a.cross(b).length().atan2(a.dot(b)).to_degrees()
}

/// `x ≤ tol`, false for NaN.
fn within(x: f64, tol: f64) -> bool {
    x.partial_cmp(&tol).is_some_and(|o| o.is_le())
}

fn check_hit(r: &Option<Surface>, s: &SubmittedHit, tol: &Tolerances) -> HitCheck {
    let mut c = HitCheck::default();
    let Some(r) = r else {
        c.hit_miss = s.hit;
        return c;
    };
    if !s.hit {
        c.hit_miss = true;
        return c;
    }
    c.object = s.object.is_some_and(|o| o != r.object);
    let rel = s
        .lambda
        .map_or(f64::NAN, |l| (l - r.lambda).abs() / r.lambda.abs());
    // NaN (no λ, or a NaN submitted) fails.
    c.lambda = !within(rel, tol.lambda_rel);
    c.lambda_rel = Some(rel);
    let angle = s
        .normal
        .map_or(f64::NAN, |n| angle_degrees(DVec3::from_array(n), r.normal));
    c.normal = !within(angle, tol.normal_degrees);
    c.angle = Some(angle);
    c
}

fn hit_value(r: &Option<Surface>) -> PixelValue {
    match r {
        None => PixelValue::Hit {
            hit: false,
            object: None,
            lambda: None,
            point: None,
            normal: None,
        },
        Some(s) => PixelValue::Hit {
            hit: true,
            object: Some(s.object),
            lambda: Some(s.lambda),
            point: Some(s.point.to_array()),
            normal: Some(s.normal.to_array()),
        },
    }
}

fn submitted_value(s: &SubmittedHit) -> PixelValue {
    PixelValue::Hit {
        hit: s.hit,
        object: s.object,
        lambda: s.lambda,
        point: s.point,
        normal: s.normal,
    }
}

/// How many tolerances `x` is, for ranking (NaN ranks as infinitely bad).
fn ratio(x: Option<f64>, tol: f64) -> f64 {
    match x {
        None => 0.0,
        Some(x) if x.is_nan() => f64::INFINITY,
        Some(x) if tol > 0.0 => x / tol,
        Some(x) if x > 0.0 => f64::INFINITY,
        Some(_) => 0.0,
    }
}

/// The normal map of the reference hits, the picture under a hit-data difference image.
fn normal_picture(r: &Option<Surface>) -> [u8; 3] {
    match r {
        None => [0, 0, 0],
        Some(s) => s
            .normal
            .to_array()
            .map(|x| (255.0 * (0.5 + 0.5 * x)).round().clamp(0.0, 255.0) as u8),
    }
}

/// Compares hit data placed in the frame (row-major, `w × h`) with the reference.
pub fn hits(
    reference: &[Option<Surface>],
    submitted: &[SubmittedHit],
    w: u32,
    h: u32,
    tol: &Tolerances,
    worst: usize,
) -> Comparison {
    let at = |u: u32, v: u32| v as usize * w as usize + u as usize;
    let mut counts = HitCounts::default();
    let mut failing = 0;
    let mut forgiven = 0;
    let mut rel_sum = 0.0;
    let mut diff = RgbImage {
        width: w,
        height: h,
        data: Vec::with_capacity(w as usize * h as usize * 3),
    };
    let mut top = Worst::new(worst);
    let worse = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(x), Some(y)) if x.is_nan() || y.is_nan() => Some(f64::NAN),
        (Some(x), Some(y)) => Some(x.max(y)),
        (x, None) => x,
        (None, y) => y,
    };
    for v in 0..h {
        for u in 0..w {
            let r = &reference[at(u, v)];
            let s = &submitted[at(u, v)];
            let c = check_hit(r, s, tol);
            let direct = c.pass();
            let pass = direct
                || (tol.edge_forgiving
                    && neighbours(u, v, w, h)
                        .skip(1)
                        .any(|(x, y)| check_hit(&reference[at(x, y)], s, tol).pass()));
            if let (Some(rel), Some(angle)) = (c.lambda_rel, c.angle) {
                counts.both_hit += 1;
                rel_sum += rel;
                counts.max_lambda_rel_error = worse(counts.max_lambda_rel_error, Some(rel));
                counts.max_normal_angle_degrees =
                    worse(counts.max_normal_angle_degrees, Some(angle));
            }
            if !pass {
                failing += 1;
                counts.hit_miss += c.hit_miss as u64;
                counts.wrong_object += c.object as u64;
                counts.lambda += c.lambda as u64;
                counts.normal += c.normal as u64;
            } else if !direct {
                forgiven += 1;
            }
            diff.data.extend_from_slice(&super::legend::hit_diff_colour(
                pass,
                c.hit_miss,
                c.object,
                c.lambda,
                dim(normal_picture(r)),
                FAIL_RGB,
            ));
            let differs = c.hit_miss
                || c.object
                || c.lambda_rel.is_some_and(|x| x != 0.0)
                || c.angle.is_some_and(|x| x != 0.0);
            if differs {
                let class = if c.hit_miss {
                    3
                } else if c.object {
                    2
                } else {
                    (!direct) as u8
                };
                let magnitude =
                    ratio(c.lambda_rel, tol.lambda_rel).max(ratio(c.angle, tol.normal_degrees));
                let rank = Rank {
                    key: [(!pass) as u8 as f64, class as f64, magnitude],
                    u,
                    v,
                };
                top.offer(rank, || WorstPixel {
                    u,
                    v,
                    pass,
                    failures: c.failures(),
                    colour_error: None,
                    linear_error: None,
                    lambda_rel_error: c.lambda_rel,
                    normal_angle_degrees: c.angle,
                    reference: hit_value(r),
                    submitted: submitted_value(s),
                });
            }
        }
    }
    // NaN is not JSON: a NaN maximum is reported as absent, and the pixel is in `worst`.
    counts.max_lambda_rel_error = counts.max_lambda_rel_error.filter(|x| x.is_finite());
    counts.max_normal_angle_degrees = counts.max_normal_angle_degrees.filter(|x| x.is_finite());
    counts.mean_lambda_rel_error = (counts.both_hit > 0)
        .then(|| rel_sum / counts.both_hit as f64)
        .filter(|x| x.is_finite());
    Comparison {
        failing,
        forgiven,
        worst: top.into_vec(),
        hits: Some(counts),
        linear: None,
        diff,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: u32, h: u32, c: u8) -> RgbImage {
        RgbImage {
            width: w,
            height: h,
            data: vec![c; (w * h * 3) as usize],
        }
    }

    #[test]
    fn within_tolerance_passes_beyond_fails() {
        let a = flat(4, 3, 100);
        let mut b = a.clone();
        b.set(1, 2, [102, 100, 100]);
        b.set(3, 0, [100, 97, 100]);
        let c = images(&a, &b, &Tolerances::default(), 10);
        assert_eq!(c.failing, 1);
        assert_eq!((c.worst[0].u, c.worst[0].v), (3, 0));
        assert!(!c.worst[0].pass);
        assert_eq!(c.worst[1].colour_error, Some(2));
        assert!(c.worst[1].pass);
        assert_eq!(c.diff.get(3, 0), FAIL_RGB);
        assert_eq!(c.diff.get(0, 0), [35, 35, 35]);
    }

    #[test]
    fn worst_list_is_bounded_and_ordered() {
        let a = flat(20, 10, 100);
        let mut b = flat(20, 10, 110);
        b.set(7, 9, [200, 100, 100]);
        b.set(3, 2, [100, 190, 100]);
        let c = images(&a, &b, &Tolerances::default(), 4);
        assert_eq!(c.failing, 200);
        let at: Vec<(u32, u32)> = c.worst.iter().map(|w| (w.u, w.v)).collect();
        // The two largest errors, then equal ones in row-major order.
        assert_eq!(at, vec![(7, 9), (3, 2), (0, 0), (1, 0)]);
        assert!(images(&a, &b, &Tolerances::default(), 0).worst.is_empty());
    }

    #[test]
    fn edge_forgiving_accepts_a_neighbours_value() {
        let mut a = flat(3, 3, 0);
        a.set(2, 1, [200, 200, 200]);
        let mut b = flat(3, 3, 0);
        b.set(1, 1, [200, 200, 200]);
        assert_eq!(images(&a, &b, &Tolerances::default(), 5).failing, 2);
        let t = Tolerances {
            edge_forgiving: true,
            ..Default::default()
        };
        let c = images(&a, &b, &t, 5);
        assert_eq!(c.failing, 0);
        assert_eq!(c.forgiven, 2);
    }

    #[test]
    fn linear_images_compare_with_a_relative_and_an_absolute_tolerance() {
        let t = Tolerances {
            linear_rel: 0.01,
            linear_abs: 0.001,
            ..Default::default()
        };
        let reference = LinearImage::from_pixels(4, 1, &[[0.0; 3], [10.0; 3], [0.5; 3], [1.0; 3]]);
        let within = LinearImage::from_pixels(
            4,
            1,
            &[[0.0009, 0.0, 0.0], [10.09, 9.91, 10.0], [0.5; 3], [1.0; 3]],
        );
        let picture = flat(4, 1, 100);
        let c = linear(&reference, &within, &picture, &t, 10);
        assert_eq!(c.failing, 0);
        assert!((c.linear.unwrap().max_abs_error - 0.09).abs() < 1e-5);
        let beyond = LinearImage::from_pixels(
            4,
            1,
            &[
                [0.0011, 0.0, 0.0],
                [10.2, 10.0, 10.0],
                [f32::NAN, 0.5, 0.5],
                [1.0; 3],
            ],
        );
        let c = linear(&reference, &beyond, &picture, &t, 10);
        assert_eq!(c.failing, 3);
        assert_eq!(c.linear.unwrap().non_finite, 1);
        // The NaN pixel is worst (infinitely many tolerances off), then λ-like ranking.
        assert_eq!(
            (c.worst[0].u, c.worst[0].failures.clone()),
            (2, vec![check::LINEAR])
        );
        assert_eq!(
            serde_json::to_value(&c.worst[0].submitted).unwrap(),
            serde_json::json!({"linear": [null, 0.5, 0.5]})
        );
        assert_eq!(c.diff.get(3, 0), [35, 35, 35]);
        assert_eq!(c.diff.get(0, 0), FAIL_RGB);
    }

    #[test]
    fn neighbourhood_stays_in_frame() {
        let n: Vec<_> = neighbours(0, 0, 1, 1).collect();
        assert_eq!(n, vec![(0, 0)]);
        assert_eq!(neighbours(1, 1, 3, 3).count(), 9);
        assert_eq!(neighbours(2, 0, 3, 3).count(), 4);
    }

    #[test]
    fn angles() {
        assert_eq!(angle_degrees(DVec3::X, DVec3::X), 0.0);
        assert!((angle_degrees(DVec3::X, -DVec3::X) - 180.0).abs() < 1e-12);
        assert!((angle_degrees(DVec3::X, DVec3::new(1.0, 1.0, 0.0)) - 45.0).abs() < 1e-12);
        assert!(angle_degrees(DVec3::ZERO, DVec3::X).is_nan());
    }

    #[test]
    fn hit_checks_are_separate() {
        let r = Some(Surface {
            lambda: 2.0,
            object: 1,
            point: DVec3::new(0.0, 0.0, 2.0),
            object_point: DVec3::ZERO,
            normal: DVec3::NEG_Z,
            front: true,
            face: None,
        });
        let good = SubmittedHit {
            hit: true,
            object: Some(1),
            lambda: Some(2.0),
            normal: Some([0.0, 0.0, -1.0]),
            ..Default::default()
        };
        let t = Tolerances::default();
        assert!(check_hit(&r, &good, &t).pass());
        let far = SubmittedHit {
            lambda: Some(2.02),
            ..good
        };
        assert_eq!(check_hit(&r, &far, &t).failures(), vec![check::LAMBDA]);
        let flipped = SubmittedHit {
            normal: Some([0.0, 0.0, 1.0]),
            ..good
        };
        assert_eq!(check_hit(&r, &flipped, &t).failures(), vec![check::NORMAL]);
        let other = SubmittedHit {
            object: Some(0),
            ..good
        };
        assert_eq!(check_hit(&r, &other, &t).failures(), vec![check::OBJECT]);
        let unnamed = SubmittedHit {
            object: None,
            ..good
        };
        assert!(check_hit(&r, &unnamed, &t).pass());
        let miss = SubmittedHit::default();
        assert_eq!(check_hit(&r, &miss, &t).failures(), vec![check::HIT_MISS]);
        assert_eq!(
            check_hit(&None, &good, &t).failures(),
            vec![check::HIT_MISS]
        );
        let nan = SubmittedHit {
            lambda: Some(f64::NAN),
            ..good
        };
        assert_eq!(check_hit(&r, &nan, &t).failures(), vec![check::LAMBDA]);
    }
}
