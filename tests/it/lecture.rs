//! The lecture's worked example (`scenes/lecture.json`): a unit sphere translated by
//! (1, 0, 2), a 5 × 5 image, f = 1.

use raytile::format::PixelHit;
use raytile::geometry::Ray;
use raytile::render::Renderer;
use raytile::scene::{Limits, parse};
use std::sync::Arc;

use crate::support::*;

fn lecture() -> Renderer {
    let bytes = std::fs::read(scene("lecture.json")).unwrap();
    Renderer::new(Arc::new(parse(&bytes, &Limits::default()).unwrap()))
}

#[test]
fn centre_pixel_ray_is_the_lectures() {
    let r = lecture();
    let ray = r.camera.pixel_centre(2, 2);
    assert_eq!(
        ray,
        Ray::new([0.0, 0.0, 0.0].into(), [0.0, 0.0, 1.0].into())
    );
}

#[test]
fn centre_pixel_grazes_the_sphere_at_lambda_two() {
    let s = lecture().pixel_hit(2, 2).expect("pixel (2, 2) hits");
    assert_eq!(s.object, 0);
    assert_eq!(s.lambda, 2.0);
    assert_eq!(s.point.to_array(), [0.0, 0.0, 2.0]);
    assert_eq!(s.object_point.to_array(), [-1.0, 0.0, 0.0]);
    assert_eq!(s.normal.to_array(), [-1.0, 0.0, 0.0]);
}

/// Every pixel hits exactly when `b² − 4ac ≥ 0` for the lecture's quadratic, computed
/// here independently: ray `λ d` from the origin, sphere centre `c = (1, 0, 2)`.
#[test]
fn every_pixel_hits_or_misses_as_the_formula_says() {
    let out = tempfile::tempdir().unwrap();
    let path = out.path().join("hits.json");
    let res = run(&[
        "hits",
        scene("lecture.json").to_str().unwrap(),
        "-o",
        path.to_str().unwrap(),
    ]);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let pixels: Vec<PixelHit> = serde_json::from_value(doc["pixels"].clone()).unwrap();
    assert_eq!(pixels.len(), 25);
    let c = [1.0, 0.0, 2.0];
    let mut hits = 0;
    for (k, p) in pixels.iter().enumerate() {
        let (u, v) = (k as u32 % 5, k as u32 / 5);
        assert_eq!((p.u, p.v), (u, v), "row-major order");
        let d = [
            -1.0 + (u as f64 + 0.5) * 2.0 / 5.0,
            -1.0 + (v as f64 + 0.5) * 2.0 / 5.0,
            1.0,
        ];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        // Object space origin o = −c: a = d·d, b = 2 o·d, c' = o·o − 1.
        let (a, b, cc) = (dot(d, d), -2.0 * dot(c, d), dot(c, c) - 1.0);
        let disc = b * b - 4.0 * a * cc;
        assert_eq!(p.hit, disc >= 0.0, "pixel ({u}, {v}): discriminant {disc}");
        if p.hit {
            hits += 1;
            let lambda = if disc == 0.0 {
                -b / (2.0 * a)
            } else {
                (-b - disc.sqrt()) / (2.0 * a)
            };
            assert_eq!(p.lambda, Some(lambda), "pixel ({u}, {v})");
            assert_eq!(p.name.as_deref(), Some("ball"));
        }
    }
    assert_eq!(hits, 7);
}
