//! Whole-image error statistics between a reference and a submitted image of the same
//! size: absolute error, PSNR, SSIM and FLIP.
//!
//! - Absolute error and PSNR are over every channel of every pixel, in 8-bit units:
//!   `PSNR = 10 · log10(255² / MSE)`, absent (infinite) when the images are identical.
//! - SSIM (Wang et al. 2004) is computed on luma `Y = 0.299 R + 0.587 G + 0.114 B` with
//!   an 11 × 11 Gaussian window (σ = 1.5), `C₁ = (0.01 · 255)²`, `C₂ = (0.03 · 255)²`,
//!   averaged over every pixel; near the border the window is cut to the image and its
//!   weights renormalised, so even a 5 × 5 image has a score.
//! - FLIP is NVIDIA's perceptual difference (the reference implementation, through the
//!   `nv-flip` crate), at its default 67 pixels per degree; its per-pixel error map in
//!   `[0, 1]` is summarised by its mean, percentiles and maximum.

use serde::Serialize;

use super::image::RgbImage;

/// Absolute error and PSNR.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Largest absolute difference of any channel (0–255).
    pub max_abs_error: u8,
    /// Mean absolute difference over all channels (0–255).
    pub mean_abs_error: f64,
    /// Peak signal-to-noise ratio in dB; `null` when the images are identical.
    pub psnr_db: Option<f64>,
}

/// FLIP's error map, summarised.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FlipStats {
    /// Mean FLIP error (0 identical, 1 as different as can be).
    pub mean: f64,
    /// Median.
    pub p50: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

/// Absolute error and PSNR of `b` against `a` (same size).
pub fn error_stats(a: &RgbImage, b: &RgbImage) -> ErrorStats {
    let mut max = 0u8;
    let mut sum = 0u64;
    let mut sq = 0u64;
    for (&x, &y) in a.data.iter().zip(&b.data) {
        let d = x.abs_diff(y);
        max = max.max(d);
        sum += d as u64;
        sq += d as u64 * d as u64;
    }
    let n = a.data.len().max(1) as f64;
    let mse = sq as f64 / n;
    ErrorStats {
        max_abs_error: max,
        mean_abs_error: sum as f64 / n,
        psnr_db: (mse > 0.0).then(|| 10.0 * (255.0 * 255.0 / mse).log10()),
    }
}

/// Luma of every pixel (Rec. 601 weights).
fn luma(img: &RgbImage) -> Vec<f64> {
    img.data
        .chunks_exact(3)
        .map(|p| 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64)
        .collect()
}

/// The 11-tap Gaussian of σ = 1.5.
fn gaussian() -> [f64; 11] {
    let mut w = [0.0; 11];
    for (k, x) in w.iter_mut().enumerate() {
        let d = k as f64 - 5.0;
        *x = (-d * d / (2.0 * 1.5 * 1.5)).exp();
    }
    w
}

/// Separable blur with the window cut at the border and renormalised.
fn blur(src: &[f64], w: usize, h: usize, g: &[f64; 11]) -> Vec<f64> {
    let mut tmp = vec![0.0; src.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut ws) = (0.0, 0.0);
            for (k, &gk) in g.iter().enumerate() {
                let xx = x as isize + k as isize - 5;
                if xx >= 0 && (xx as usize) < w {
                    s += gk * src[y * w + xx as usize];
                    ws += gk;
                }
            }
            tmp[y * w + x] = s / ws;
        }
    }
    let mut out = vec![0.0; src.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut ws) = (0.0, 0.0);
            for (k, &gk) in g.iter().enumerate() {
                let yy = y as isize + k as isize - 5;
                if yy >= 0 && (yy as usize) < h {
                    s += gk * tmp[yy as usize * w + x];
                    ws += gk;
                }
            }
            out[y * w + x] = s / ws;
        }
    }
    out
}

/// Mean SSIM of the lumas of two images of the same size (1 when identical).
pub fn ssim(a: &RgbImage, b: &RgbImage) -> f64 {
    let (w, h) = (a.width as usize, a.height as usize);
    if w == 0 || h == 0 {
        return 1.0;
    }
    let g = gaussian();
    let x = luma(a);
    let y = luma(b);
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
    let (mx, my) = (blur(&x, w, h, &g), blur(&y, w, h, &g));
    let (sxx, syy, sxy) = (
        blur(&xx, w, h, &g),
        blur(&yy, w, h, &g),
        blur(&xy, w, h, &g),
    );
    const C1: f64 = (0.01 * 255.0) * (0.01 * 255.0);
    const C2: f64 = (0.03 * 255.0) * (0.03 * 255.0);
    let mut total = 0.0;
    for i in 0..w * h {
        let (mu_x, mu_y) = (mx[i], my[i]);
        let var_x = (sxx[i] - mu_x * mu_x).max(0.0);
        let var_y = (syy[i] - mu_y * mu_y).max(0.0);
        let cov = sxy[i] - mu_x * mu_y;
        total += ((2.0 * mu_x * mu_y + C1) * (2.0 * cov + C2))
            / ((mu_x * mu_x + mu_y * mu_y + C1) * (var_x + var_y + C2));
    }
    total / (w * h) as f64
}

/// FLIP between a reference and a test image of the same size.
pub fn flip(reference: &RgbImage, test: &RgbImage) -> FlipStats {
    let (w, h) = (reference.width, reference.height);
    let r = nv_flip::FlipImageRgb8::with_data(w, h, &reference.data);
    let t = nv_flip::FlipImageRgb8::with_data(w, h, &test.data);
    let map = nv_flip::flip(r, t, nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    let mut values: Vec<f64> = map
        .to_vec()
        .into_iter()
        .map(|v| if v.is_finite() { v as f64 } else { 1.0 })
        .collect();
    values.sort_by(f64::total_cmp);
    let n = values.len();
    let pct = |p: f64| {
        if n == 0 {
            0.0
        } else {
            // Nearest rank: the smallest value with at least p of the values at or below it.
            let rank = ((p * n as f64).ceil() as usize).clamp(1, n);
            values[rank - 1]
        }
    };
    FlipStats {
        mean: if n == 0 {
            0.0
        } else {
            values.iter().sum::<f64>() / n as f64
        },
        p50: pct(0.50),
        p90: pct(0.90),
        p95: pct(0.95),
        p99: pct(0.99),
        max: values.last().copied().unwrap_or(0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(w: u32, h: u32) -> RgbImage {
        let mut data = Vec::new();
        for v in 0..h {
            for u in 0..w {
                data.extend_from_slice(&[(u * 7 % 256) as u8, (v * 5 % 256) as u8, 90]);
            }
        }
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn identical_images() {
        let a = gradient(40, 30);
        let e = error_stats(&a, &a);
        assert_eq!(e.max_abs_error, 0);
        assert_eq!(e.psnr_db, None);
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-12);
        let f = flip(&a, &a);
        assert_eq!(f.max, 0.0);
    }

    #[test]
    fn a_changed_pixel_lowers_every_score() {
        let a = gradient(40, 30);
        let mut b = a.clone();
        b.set(10, 10, [255, 255, 255]);
        let e = error_stats(&a, &b);
        assert!(e.max_abs_error > 100);
        assert!(e.psnr_db.is_some_and(|p| p > 20.0 && p < 60.0));
        assert!(ssim(&a, &b) < 1.0);
        let f = flip(&a, &b);
        assert!(f.max > 0.1 && f.mean > 0.0 && f.p50 < f.max);
    }

    #[test]
    fn tiny_images_work() {
        for (w, h) in [(1, 1), (5, 5), (2, 13)] {
            let a = gradient(w, h);
            let mut b = a.clone();
            b.set(0, 0, [0, 0, 0]);
            assert!(ssim(&a, &b).is_finite());
            assert!(flip(&a, &b).mean.is_finite());
        }
    }

    #[test]
    fn psnr_of_a_known_error() {
        // Every channel off by 1: MSE = 1, PSNR = 20 log10(255).
        let a = RgbImage {
            width: 2,
            height: 2,
            data: vec![10; 12],
        };
        let b = RgbImage {
            data: vec![11; 12],
            ..a.clone()
        };
        let p = error_stats(&a, &b).psnr_db.unwrap();
        assert!((p - 20.0 * 255f64.log10()).abs() < 1e-12);
    }
}
