//! From linear colour to the 8-bit levels of a PNG: optional gamma, then
//! `round(255 · clamp(c, 0, 1))` for each channel.
//!
//! Every pixel of a render goes through this, so it is written for speed: two channels
//! at a time in lanes (SSE2 on x86-64, part of the architecture), exact, with no
//! conversion to an integer and back.

use bytemuck::cast;
use glam::DVec3;
use wide::{f64x2, i64x2};

/// Linear colour to 8 bits: optional gamma, then `round(255 · clamp(c, 0, 1))`.
#[inline]
pub fn quantise(c: DVec3, gamma: Option<f64>) -> [u8; 3] {
    let c = gamma_encoded(c, gamma);
    let [r, g] = levels2(c.x, c.y);
    let [b, _] = levels2(c.z, c.z);
    [r, g, b]
}

/// [`quantise`] of a packet's eight colours, byte for byte: the red and green of a
/// pixel in one pair of lanes, the blues of two pixels in another.
///
/// Quantising one channel at a time, each a chain of conversions from and back to
/// floating point, was 4 % of `mesh-100k`'s render (whole process, one thread).
#[inline]
pub fn quantise8(c: &[DVec3; 8], gamma: Option<f64>) -> [[u8; 3]; 8] {
    let mut q = [[0; 3]; 8];
    for k in (0..8).step_by(2) {
        let (a, b) = (gamma_encoded(c[k], gamma), gamma_encoded(c[k + 1], gamma));
        let ([ra, ga], [rb, gb]) = (levels2(a.x, a.y), levels2(b.x, b.y));
        let [ba, bb] = levels2(a.z, b.z);
        (q[k], q[k + 1]) = ([ra, ga, ba], [rb, gb, bb]);
    }
    q
}

/// `c` with each channel raised to `1 / gamma`, if there is a gamma.
#[inline(always)]
fn gamma_encoded(c: DVec3, gamma: Option<f64>) -> DVec3 {
    match gamma {
        Some(g) => DVec3::new(c.x.powf(1.0 / g), c.y.powf(1.0 / g), c.z.powf(1.0 / g)),
        None => c,
    }
}

/// The 8-bit levels `round(255 · clamp(x, 0, 1))` of two channels `a` and `b`, in
/// two lanes, rounding half up as `f64::round` does there; NaN gives 0.
///
/// Exact, with no conversion to an integer on the way: for `0 ≤ y < 2⁵²`, `y + 2⁵²`
/// lies where floating point numbers are one apart, so it is rounded to the nearest
/// integer, ties to even, and that integer is its low mantissa bits. Half up differs
/// from ties to even only where `y` was half way and went down, where `y − rounded`
/// (exact) is ½: one is added there. `max` against 0 takes the 0 where `x` is NaN
/// (the second operand of `maxpd`) and turns −0 into +0.
#[inline(always)]
fn levels2(a: f64, b: f64) -> [u8; 2] {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    let x = f64x2::new([a, b])
        .fast_max(f64x2::ZERO)
        .fast_min(f64x2::ONE);
    let y = f64x2::splat(255.0) * x;
    let shifted = y + f64x2::splat(TWO_52);
    let went_down = (y - (shifted - f64x2::splat(TWO_52))).simd_eq(f64x2::splat(0.5));
    // All ones (−1) where it went down half way, so subtracting adds one.
    let levels = cast::<f64x2, i64x2>(shifted) - cast::<f64x2, i64x2>(went_down);
    levels.to_array().map(|l| l as u8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Every value quantising can meet at and around each level's edges (`k / 255`
    /// and `(k + ½) / 255`, a few steps of one unit in the last place either way),
    /// outside `[0, 1]`, and the odd ones (±0, ±∞, NaN, the smallest numbers).
    fn channels() -> Vec<f64> {
        let mut xs = vec![
            0.0,
            -0.0,
            1.0,
            f64::NAN,
            -f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            5e-324,
            -5e-324,
            1.0f64.next_up(),
            1.5,
            -0.25,
            1e300,
            -1e300,
        ];
        for k in 0..=255 {
            for x in [k as f64 / 255.0, (k as f64 + 0.5) / 255.0] {
                let (mut lo, mut hi) = (x, x);
                for _ in 0..4 {
                    xs.extend([lo, hi]);
                    (lo, hi) = (lo.next_down(), hi.next_up());
                }
            }
        }
        xs.extend((0..10_000).map(|i| i as f64 / 9_999.0));
        xs
    }

    /// `round(255 · clamp(x, 0, 1))` with `f64::round`: the rule.
    fn level(x: f64) -> u8 {
        (255.0 * x.clamp(0.0, 1.0)).round() as u8
    }

    /// The lanes give each channel the rule's level, whatever its lane and whatever its
    /// neighbour, on every edge value, the exact half-way points among them.
    #[test]
    fn the_lanes_give_the_rules_levels() {
        let xs = channels();
        let half_way = xs.iter().filter(|&&x| (255.0 * x).fract() == 0.5).count();
        assert!(half_way > 200, "only {half_way} channels fall half way");
        for (i, &a) in xs.iter().enumerate() {
            let b = xs[(i * 7919 + 13) % xs.len()];
            assert_eq!(levels2(a, b), [level(a), level(b)], "{a:e}, {b:e}");
            assert_eq!(levels2(b, a), [level(b), level(a)], "{b:e}, {a:e}");
        }
        let one = |x: f64| levels2(x, 0.0)[0];
        assert_eq!([one(-0.0), one(f64::NAN), one(-1.0)], [0, 0, 0]);
        assert_eq!([one(f64::INFINITY), one(2.0), one(1.0)], [255; 3]);
        // 127.5 rounds up (ties to even would give 128 too), 2.5 up to 3 (not 2).
        assert_eq!(
            [one(0.5), one(2.5 / 255.0), one(0.5f64.next_down())],
            [128, 3, 127]
        );
    }

    #[test]
    fn quantise_rounds_and_clamps() {
        assert_eq!(quantise(DVec3::new(0.5, 2.0, -1.0), None), [128, 255, 0]);
        assert_eq!(quantise(DVec3::splat(0.25), Some(2.0)), [128, 128, 128]);
    }

    proptest! {
        /// A packet's eight colours quantise as each does alone, with or without gamma.
        #[test]
        fn a_packet_quantises_as_its_pixels_do(
            c in prop::array::uniform8(prop::array::uniform3(-0.5f64..1.5)),
            edge in prop::array::uniform8(0usize..4096),
            gamma in prop::option::of(prop::sample::select(vec![1.0, 1.8, 2.2, 2.4])),
        ) {
            // Some channels from the edge values, so that each lane meets them.
            let xs = channels();
            let c: [DVec3; 8] = std::array::from_fn(|k| {
                let mut v = c[k];
                if edge[k] % 2 == 0 {
                    v[edge[k] % 3] = xs[edge[k] * 31 % xs.len()];
                }
                DVec3::from_array(v)
            });
            let alone: [[u8; 3]; 8] = c.map(|c| quantise(c, gamma));
            prop_assert_eq!(quantise8(&c, gamma), alone);
            for (c, q) in c.iter().zip(alone) {
                prop_assert_eq!(q, levels_of(*c, gamma));
            }
        }
    }

    /// [`level`] of each channel after gamma.
    fn levels_of(c: DVec3, gamma: Option<f64>) -> [u8; 3] {
        gamma_encoded(c, gamma).to_array().map(level)
    }
}
