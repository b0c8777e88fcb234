//! Linear images: a frame's radiance before gamma and quantisation, 32-bit floats, as
//! float image files (PFM, OpenEXR) carry it and as the renderer computes it
//! ([`crate::render::LinearKernel`]).

use glam::DVec3;

use super::png::RgbImage;
use crate::render::quantise;

/// A linear RGB image, rows top to bottom, 3 floats per pixel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LinearImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height × 3` values.
    pub data: Vec<f32>,
}

impl LinearImage {
    /// An image from its pixels, row-major.
    pub fn from_pixels(width: u32, height: u32, pixels: &[[f32; 3]]) -> LinearImage {
        LinearImage {
            width,
            height,
            data: pixels.iter().flatten().copied().collect(),
        }
    }

    /// Pixel `(u, v)`.
    #[inline]
    pub fn get(&self, u: u32, v: u32) -> [f32; 3] {
        let k = 3 * (v as usize * self.width as usize + u as usize);
        [self.data[k], self.data[k + 1], self.data[k + 2]]
    }

    /// The 8-bit image the renderer would write for these values: `gamma`, then
    /// [`fn@quantise`]'s rounding and clamping.
    pub fn quantise(&self, gamma: Option<f64>) -> RgbImage {
        let mut data = Vec::with_capacity(self.data.len());
        for p in self.data.chunks_exact(3) {
            let c = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            data.extend_from_slice(&quantise(c, gamma));
        }
        RgbImage {
            width: self.width,
            height: self.height,
            data,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantising_applies_gamma_and_clamps() {
        let img = LinearImage::from_pixels(2, 1, &[[0.25, 2.0, -1.0], [0.5, 0.0, 1.0]]);
        assert_eq!(img.get(1, 0), [0.5, 0.0, 1.0]);
        let q = img.quantise(Some(2.0));
        assert_eq!(q.data, vec![128, 255, 0, 180, 0, 255]);
        assert_eq!(img.quantise(None).get(1, 0), [128, 0, 255]);
    }
}
