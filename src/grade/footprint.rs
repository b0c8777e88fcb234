//! What grading costs in memory beyond the scene and the submission, from the frame
//! alone, decided before the reference is rendered (the server charges it to its
//! memory budget first, `server::memory`): the reference (an image, or a hit record a
//! pixel), the submission placed in the frame, the comparison, and for images the
//! metrics (SSIM, and FLIP, which keeps several floating-point images of the frame),
//! the report and the difference image.
//!
//! The bytes a pixel are measured (the tests run a grade under a counting allocator and
//! check the estimate against its peak) and rounded up.

/// Bytes a pixel grading an image takes at most: 94 measured (the SSIM's
/// floating-point images are the peak, FLIP's come after them and are no larger).
const IMAGE_PIXEL: u64 = 128;
/// Bytes a pixel grading hit data takes at most: 398 measured (the reference's hit
/// records, the submission placed in the frame, and the comparison's).
const HITS_PIXEL: u64 = 512;
/// What grading holds whatever the frame (the report, the worst pixels).
const FIXED: u64 = 1 << 20;

/// What diagnosing a failing submission adds a pixel (`grade::diagnose`): its entries
/// run one after another, each holding one wrong reference and its comparison beside
/// the grade's own (an image: the wrong image, the linear frame the gamma entries
/// share, the comparison; hit data: a wrong copy of the reference's records).
const DIAGNOSIS_IMAGE_PIXEL: u64 = 48;
const DIAGNOSIS_HITS_PIXEL: u64 = 192;

/// The peak of grading a `width × height` frame: an image or hit data, `diagnosed` if
/// a failing submission of that frame would be diagnosed.
pub fn grading(width: u32, height: u32, image: bool, diagnosed: bool) -> u64 {
    let per_pixel = match (image, diagnosed) {
        (true, false) => IMAGE_PIXEL,
        (true, true) => IMAGE_PIXEL + DIAGNOSIS_IMAGE_PIXEL,
        (false, false) => HITS_PIXEL,
        (false, true) => HITS_PIXEL + DIAGNOSIS_HITS_PIXEL,
    };
    width as u64 * height as u64 * per_pixel + FIXED
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    use crate::grade::{
        GradeOptions, Submission, Tolerances, grade, reference_hits, reference_image,
    };
    use crate::measure;
    use crate::render::{Cancel, Renderer};

    fn renderer(w: u32, h: u32) -> Renderer {
        let text = format!(
            r#"{{"version": 1, "image": {{"width": {w}, "height": {h}}},
                "camera": {{"focal_length": 1}},
                "objects": [{{"shape": "sphere", "transform": [{{"translate": [0, 0, 3]}}]}}],
                "lights": [{{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}}]}}"#
        );
        let scene = crate::scene::parse(text.as_bytes(), &crate::scene::Limits::default()).unwrap();
        Renderer::new(Arc::new(scene))
    }

    fn check(image: bool, flip: bool) {
        let (w, h) = (320, 240);
        let r = renderer(w, h);
        let cancel = Cancel::default();
        let submission = if image {
            Submission::Image(reference_image(&r, &cancel).unwrap().into())
        } else {
            let hits = reference_hits(&r, &cancel).unwrap();
            let pixels: Vec<crate::format::PixelHit> = hits
                .iter()
                .enumerate()
                .map(|(k, s)| crate::format::PixelHit::new(&r.scene, k as u32 % w, k as u32 / w, s))
                .collect();
            let mut doc = Vec::new();
            crate::format::json::write_start(&mut doc, w, h, r.frame()).unwrap();
            let mut first = true;
            for p in &pixels {
                crate::format::json::push_pixel(&mut doc, &mut first, p).unwrap();
            }
            doc.extend_from_slice(crate::format::json::END);
            Submission::parse(&doc, crate::grade::Hint::Json).unwrap()
        };
        let opts = GradeOptions {
            flip,
            ..GradeOptions::default()
        };
        let (report, peak) =
            measure::peak(|| grade(&r, submission, &Tolerances::default(), &opts).unwrap());
        assert!(report.pass);
        let estimate = grading(w, h, image, false);
        eprintln!(
            "image {image} flip {flip}: peak {peak} = {} a pixel; estimate {estimate}",
            peak / (w as u64 * h as u64)
        );
        assert!(estimate >= peak, "estimate {estimate} < peak {peak}");
    }

    #[test]
    fn grading_an_image_stays_within_its_estimate() {
        crate::measure::alone_or_return!(grading_an_image_stays_within_its_estimate);
        check(true, true);
        check(true, false);
    }

    #[test]
    fn grading_hit_data_stays_within_its_estimate() {
        crate::measure::alone_or_return!(grading_hit_data_stays_within_its_estimate);
        check(false, false);
    }
}
