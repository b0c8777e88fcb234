//! Making the wrong references: the reference moved, recoloured or re-quantised, or
//! rendered again by the tracer with a mistake.

use glam::DVec3;

use super::catalogue::{self, Mistake};
use crate::geometry::Surface;
use crate::grade::{GradeError, RgbImage, render_frame};
use crate::render::{Cancel, Conventions, Kernel, Lecture, RayCount, Renderer, quantise};

/// The reference's pixels moved: pixel `(u, v)` of the result is `at(u, v)` of a
/// `w × h` frame stored row-major.
pub fn moved<T: Clone>(mistake: Mistake, px: &[T], w: u32, h: u32) -> Option<Vec<T>> {
    let src = |u: u32, v: u32| -> (u32, u32) {
        match mistake {
            Mistake::FlippedVertically => (u, h - 1 - v),
            Mistake::FlippedHorizontally => (w - 1 - u, v),
            _ => (v, u),
        }
    };
    if !matches!(
        mistake,
        Mistake::FlippedVertically | Mistake::FlippedHorizontally | Mistake::Transposed
    ) || (mistake == Mistake::Transposed && w != h)
    {
        return None;
    }
    let mut out = Vec::with_capacity(px.len());
    for v in 0..h {
        for u in 0..w {
            let (x, y) = src(u, v);
            out.push(px[y as usize * w as usize + x as usize].clone());
        }
    }
    Some(out)
}

/// An image's pixels moved as [`moved`] does.
pub fn moved_image(mistake: Mistake, img: &RgbImage) -> Option<RgbImage> {
    let px = moved(mistake, &img.pixels(), img.width, img.height)?;
    Some(RgbImage::from_pixels(img.width, img.height, &px))
}

/// Red and blue exchanged.
pub fn bgr(img: &RgbImage) -> RgbImage {
    let px: Vec<[u8; 3]> = img.pixels().iter().map(|&[r, g, b]| [b, g, r]).collect();
    RgbImage::from_pixels(img.width, img.height, &px)
}

/// The sRGB transfer curve (IEC 61966-2-1) of a linear value.
fn srgb(c: f64) -> f64 {
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// The linear frame written to 8 bits as `mistake` does, with the scene's `gamma`.
pub fn quantised(
    mistake: Mistake,
    linear: &[DVec3],
    w: u32,
    h: u32,
    gamma: Option<f64>,
) -> Option<RgbImage> {
    let g = gamma.unwrap_or(1.0);
    let q = |x: f64| (255.0 * x.clamp(0.0, 1.0)).round() as u8;
    let px: Vec<[u8; 3]> = match mistake {
        Mistake::GammaMissing => linear.iter().map(|&c| quantise(c, None)).collect(),
        Mistake::GammaTwice => linear.iter().map(|&c| quantise(c, Some(g * g))).collect(),
        Mistake::GammaUnasked => linear.iter().map(|&c| quantise(c, Some(2.2))).collect(),
        Mistake::SrgbInsteadOfGamma => linear
            .iter()
            .map(|c| c.to_array().map(|x| q(srgb(x.clamp(0.0, 1.0)))))
            .collect(),
        Mistake::Truncated => linear
            .iter()
            .map(|c| {
                let c = match gamma {
                    Some(g) => c.powf(1.0 / g),
                    None => *c,
                };
                c.to_array()
                    .map(|x| (255.0 * x.clamp(0.0, 1.0)).floor() as u8)
            })
            .collect(),
        _ => return None,
    };
    Some(RgbImage::from_pixels(w, h, &px))
}

/// Reports each pixel's linear colour under conventions `C`, before gamma and 8 bits.
struct LinearKernel<'a, C>(&'a Renderer, std::marker::PhantomData<C>);

impl<C: Conventions> Kernel for LinearKernel<'_, C> {
    type Pixel = DVec3;
    #[inline]
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> DVec3 {
        let mut n = RayCount(0);
        let c = self.0.pixel_colour_as::<C>(u, v, &mut n);
        *rays += n.0;
        c
    }
}

/// Reports each pixel's first hit under conventions `C`.
struct HitKernelAs<'a, C>(&'a Renderer, std::marker::PhantomData<C>);

impl<C: Conventions> Kernel for HitKernelAs<'_, C> {
    type Pixel = Option<Surface>;
    #[inline]
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> Option<Surface> {
        *rays += 1;
        self.0.pixel_hit_as::<C>(u, v)
    }
}

fn linear_as<C: Conventions>(r: &Renderer, cancel: &Cancel) -> Result<Vec<DVec3>, GradeError> {
    let k = LinearKernel::<C>(r, std::marker::PhantomData);
    render_frame(&k, r.scene.width, r.scene.height, cancel)
}

fn hits_as<C: Conventions>(
    r: &Renderer,
    cancel: &Cancel,
) -> Result<Vec<Option<Surface>>, GradeError> {
    let k = HitKernelAs::<C>(r, std::marker::PhantomData);
    render_frame(&k, r.scene.width, r.scene.height, cancel)
}

/// The reference's linear colours, before gamma and quantisation: the one place diagnosis
/// reaches the renderer's radiance.
pub fn linear_frame(r: &Renderer, cancel: &Cancel) -> Result<Vec<DVec3>, GradeError> {
    linear_as::<Lecture>(r, cancel)
}

/// The linear frame the tracer renders with `mistake`; `None` for an entry not rendered.
pub fn rendered_linear(
    mistake: Mistake,
    r: &Renderer,
    cancel: &Cancel,
) -> Option<Result<Vec<DVec3>, GradeError>> {
    use catalogue::*;
    Some(match mistake {
        Mistake::PixelCorner => linear_as::<Corner>(r, cancel),
        Mistake::NormalsNotInverseTranspose => linear_as::<ForwardNormals>(r, cancel),
        Mistake::NormalsNotNormalised => linear_as::<RawNormals>(r, cancel),
        Mistake::ShadowsMissing => linear_as::<NoShadows>(r, cancel),
        Mistake::AmbientMissing => linear_as::<NoAmbient>(r, cancel),
        Mistake::SpecularMissing => linear_as::<NoSpecular>(r, cancel),
        Mistake::BlinnPhong => linear_as::<Blinn>(r, cancel),
        Mistake::ReflectionMissing => linear_as::<NoReflection>(r, cancel),
        Mistake::RefractionMissing => linear_as::<NoRefraction>(r, cancel),
        Mistake::RefractionRatioInverted => linear_as::<InvertedEta>(r, cancel),
        Mistake::MaxDepthPlusOne => linear_as::<DeeperByOne>(r, cancel),
        Mistake::MaxDepthMinusOne => linear_as::<ShallowerByOne>(r, cancel),
        _ => return None,
    })
}

/// The hit data the tracer finds with `mistake`; `None` for an entry not rendered.
pub fn rendered_hits(
    mistake: Mistake,
    r: &Renderer,
    cancel: &Cancel,
) -> Option<Result<Vec<Option<Surface>>, GradeError>> {
    use catalogue::*;
    Some(match mistake {
        Mistake::PixelCorner => hits_as::<Corner>(r, cancel),
        Mistake::LambdaUnitDirection => hits_as::<UnitLambda>(r, cancel),
        Mistake::NormalsNotInverseTranspose => hits_as::<ForwardNormals>(r, cancel),
        _ => return None,
    })
}

/// The pictures of shadow acne besides the reference's: every light blocked where it would
/// add something at the primary hit, at the secondary hits, and at both. Acne blocks a
/// light at a part of the points chosen by rounding, so a pixel of an acned image is one
/// of these (or the reference) wherever a pixel's rays meet acne at one point per depth.
pub fn acne_linear(r: &Renderer, cancel: &Cancel) -> Result<[Vec<DVec3>; 3], GradeError> {
    use catalogue::*;
    Ok([
        linear_as::<Acne>(r, cancel)?,
        linear_as::<AcnePrimary>(r, cancel)?,
        linear_as::<AcneSecondary>(r, cancel)?,
    ])
}

/// A linear frame written to 8 bits as the specification says.
pub fn to_image(linear: &[DVec3], w: u32, h: u32, gamma: Option<f64>) -> RgbImage {
    let px: Vec<[u8; 3]> = linear.iter().map(|&c| quantise(c, gamma)).collect();
    RgbImage::from_pixels(w, h, &px)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_pixels() {
        let px = [1, 2, 3, 4, 5, 6];
        assert_eq!(
            moved(Mistake::FlippedVertically, &px, 3, 2),
            Some(vec![4, 5, 6, 1, 2, 3])
        );
        assert_eq!(
            moved(Mistake::FlippedHorizontally, &px, 3, 2),
            Some(vec![3, 2, 1, 6, 5, 4])
        );
        assert_eq!(moved(Mistake::Transposed, &px, 3, 2), None);
        assert_eq!(
            moved(Mistake::Transposed, &[1, 2, 3, 4], 2, 2),
            Some(vec![1, 3, 2, 4])
        );
        assert_eq!(moved(Mistake::BgrOrder, &px, 3, 2), None);
    }

    #[test]
    fn writing_to_eight_bits_the_wrong_ways() {
        let lin = [DVec3::new(0.5, 0.002, 1.0 / 255.0 * 0.6)];
        let q = |m| quantised(m, &lin, 1, 1, Some(2.0)).unwrap().get(0, 0);
        assert_eq!(q(Mistake::GammaMissing), [128, 1, 1]);
        // 0.5^(1/4) = 0.8409 → 214.
        assert_eq!(q(Mistake::GammaTwice)[0], 214);
        // sRGB: 12.92 · 0.002 = 0.0258 → 7.
        assert_eq!(q(Mistake::SrgbInsteadOfGamma)[1], 7);
        // 0.5^(1/2) · 255 = 180.3 → 180 either way; 0.002^(1/2) · 255 = 11.4 → 11.
        assert_eq!(q(Mistake::Truncated)[..2], [180, 11]);
        let half = [DVec3::splat(0.5)];
        assert_eq!(
            quantised(Mistake::Truncated, &half, 1, 1, None)
                .unwrap()
                .get(0, 0),
            [127; 3]
        );
        assert_eq!(to_image(&half, 1, 1, None).get(0, 0), [128; 3]);
    }
}
