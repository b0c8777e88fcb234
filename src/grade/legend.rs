//! The colours of the hit-data difference image: each kind of disagreement its own, so a
//! student sees at once whether a pixel hits the wrong thing or hits it slightly wrong.
//! The legend, with words, is `diagnose::HIT_DIFF_LEGEND`.

/// A pixel that hits another object.
pub const OBJECT_RGB: [u8; 3] = [255, 200, 0];
/// A pixel whose `λ` is out of tolerance (and that hits the right object).
pub const LAMBDA_RGB: [u8; 3] = [255, 64, 0];
/// A pixel whose normal alone is out of tolerance.
pub const NORMAL_RGB: [u8; 3] = [0, 200, 255];

/// A hit-data pixel's colour in the difference image: `passing` (the dimmed reference)
/// when it passes, `hit_miss_rgb` when it hits where the reference misses or the reverse,
/// else the colour of the first check it fails: object, `λ`, normal.
pub fn hit_diff_colour(
    pass: bool,
    hit_miss: bool,
    object: bool,
    lambda: bool,
    passing: [u8; 3],
    hit_miss_rgb: [u8; 3],
) -> [u8; 3] {
    if pass {
        passing
    } else if hit_miss {
        hit_miss_rgb
    } else if object {
        OBJECT_RGB
    } else if lambda {
        LAMBDA_RGB
    } else {
        NORMAL_RGB
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hit_colours_follow_precedence() {
        let (base, fail) = ([1, 2, 3], [255, 0, 255]);
        assert_eq!(hit_diff_colour(true, true, true, true, base, fail), base);
        assert_eq!(hit_diff_colour(false, true, true, true, base, fail), fail);
        assert_eq!(
            hit_diff_colour(false, false, true, true, base, fail),
            OBJECT_RGB
        );
        assert_eq!(
            hit_diff_colour(false, false, false, true, base, fail),
            LAMBDA_RGB
        );
        assert_eq!(
            hit_diff_colour(false, false, false, false, base, fail),
            NORMAL_RGB
        );
    }
}
