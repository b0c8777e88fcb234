//! `image`: a frame of at least one pixel and at most the limit, a sample count within
//! the limit, and a positive gamma.
//!
//! ```json
//! "image": { "width": 640, "height": 480, "samples": 2, "gamma": 2.2 }
//! ```

use super::Problems;
use crate::scene::Limits;
use crate::scene::document::ImageDoc;
use crate::scene::problem::Pointer;

/// Checks `image` (at `at`) and returns its sample count, default applied.
pub(super) fn check(img: &ImageDoc, at: &Pointer, limits: &Limits, p: &mut Problems) -> u32 {
    if img.width == 0 {
        p.add(&at.key("width"), "must be at least 1");
    }
    if img.height == 0 {
        p.add(&at.key("height"), "must be at least 1");
    }
    let pixels = img.width as u64 * img.height as u64;
    if pixels > limits.max_pixels {
        p.add(
            at,
            format!(
                "{} × {} is {pixels} pixels; the limit is {}",
                img.width, img.height, limits.max_pixels
            ),
        );
    }
    let samples = img.samples.unwrap_or(1);
    if samples == 0 {
        p.add(&at.key("samples"), "must be at least 1");
    } else if samples > limits.max_samples {
        p.add(
            &at.key("samples"),
            format!("{samples} is more than the limit of {}", limits.max_samples),
        );
    }
    // Written so that NaN, which no JSON number gives but a caller's document may hold,
    // is refused too.
    if let Some(g) = img.gamma
        && g.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
    {
        p.add(&at.key("gamma"), "must be greater than 0");
    }
    samples
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(width: u32, height: u32, samples: Option<u32>, gamma: Option<f64>) -> ImageDoc {
        ImageDoc {
            width,
            height,
            samples,
            gamma,
        }
    }

    fn problems(img: &ImageDoc, limits: &Limits) -> (u32, Vec<(String, String)>) {
        let mut p = Problems::default();
        let samples = check(img, &Pointer::root().key("image"), limits, &mut p);
        (samples, p.pairs())
    }

    fn one(pointer: &str, message: &str) -> Vec<(String, String)> {
        vec![(pointer.into(), message.into())]
    }

    #[test]
    fn a_good_image_has_no_problem_and_one_sample_by_default() {
        let limits = Limits::default();
        assert_eq!(problems(&image(640, 480, None, None), &limits), (1, vec![]));
        assert_eq!(
            problems(&image(4096, 4096, Some(8), Some(2.2)), &limits),
            (8, vec![])
        );
    }

    #[test]
    fn a_zero_width_or_height_must_be_at_least_1() {
        let limits = Limits::default();
        assert_eq!(
            problems(&image(0, 4, None, None), &limits).1,
            one("/image/width", "must be at least 1")
        );
        assert_eq!(
            problems(&image(4, 0, None, None), &limits).1,
            one("/image/height", "must be at least 1")
        );
    }

    #[test]
    fn a_frame_beyond_the_pixel_limit_is_a_problem_of_the_image() {
        let limits = Limits {
            max_pixels: 100,
            ..Limits::default()
        };
        assert_eq!(problems(&image(10, 10, None, None), &limits).1, []);
        assert_eq!(
            problems(&image(11, 10, None, None), &limits).1,
            one("/image", "11 × 10 is 110 pixels; the limit is 100")
        );
    }

    #[test]
    fn the_pixel_count_does_not_overflow() {
        let (_, found) = problems(&image(u32::MAX, u32::MAX, None, None), &Limits::default());
        assert_eq!(
            found,
            one(
                "/image",
                "4294967295 × 4294967295 is 18446744065119617025 pixels; the limit is 16777216"
            )
        );
    }

    #[test]
    fn samples_must_be_at_least_1_and_within_the_limit() {
        let limits = Limits::default();
        assert_eq!(
            problems(&image(1, 1, Some(0), None), &limits).1,
            one("/image/samples", "must be at least 1")
        );
        assert_eq!(
            problems(&image(1, 1, Some(9), None), &limits).1,
            one("/image/samples", "9 is more than the limit of 8")
        );
    }

    #[test]
    fn gamma_must_be_greater_than_0() {
        for g in [0.0, -1.0, f64::NAN] {
            assert_eq!(
                problems(&image(1, 1, None, Some(g)), &Limits::default()).1,
                one("/image/gamma", "must be greater than 0"),
                "gamma {g}"
            );
        }
    }

    #[test]
    fn every_problem_of_the_image_is_reported_in_field_order() {
        let limits = Limits {
            max_pixels: 0,
            ..Limits::default()
        };
        let found: Vec<String> = problems(&image(0, 0, Some(0), Some(0.0)), &limits)
            .1
            .into_iter()
            .map(|(at, _)| at)
            .collect();
        assert_eq!(
            found,
            [
                "/image/width",
                "/image/height",
                "/image/samples",
                "/image/gamma"
            ]
        );
    }
}
