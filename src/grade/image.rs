//! Images as grading sees them: [`RgbImage`] (8-bit RGB, read and written by
//! [`crate::format::png`]) and the one thing only grading does to one, shrinking a
//! difference image so that failing pixels stay visible.

pub use crate::format::png::RgbImage;

impl RgbImage {
    /// Halves the size (rounding up); a block with any `keep` pixel becomes `keep`, so
    /// failures marked in that colour survive every halving; other blocks are averaged.
    pub fn halve(&self, keep: [u8; 3]) -> RgbImage {
        let (w, h) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut out = RgbImage {
            width: w,
            height: h,
            data: vec![0; w as usize * h as usize * 3],
        };
        for v in 0..h {
            for u in 0..w {
                let mut sum = [0u32; 3];
                let mut n = 0;
                let mut marked = false;
                for (du, dv) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (x, y) = (2 * u + du, 2 * v + dv);
                    if x < self.width && y < self.height {
                        let c = self.get(x, y);
                        marked |= c == keep;
                        for k in 0..3 {
                            sum[k] += c[k] as u32;
                        }
                        n += 1;
                    }
                }
                let c = if marked {
                    keep
                } else {
                    [0, 1, 2].map(|k| ((sum[k] + n / 2) / n.max(1)) as u8)
                };
                out.set(u, v, c);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halving_keeps_marked_pixels() {
        let mut img = RgbImage {
            width: 3,
            height: 3,
            data: vec![100; 27],
        };
        img.set(2, 2, [255, 0, 255]);
        let h = img.halve([255, 0, 255]);
        assert_eq!((h.width, h.height), (2, 2));
        assert_eq!(h.get(1, 1), [255, 0, 255]);
        assert_eq!(h.get(0, 0), [100, 100, 100]);
    }
}
