//! The catalogue: one entry per classic mistake of the course, what a student reads when
//! it is named, the convention it breaks, and, for the mistakes that are rendered, the
//! renderer's [`Conventions`] that make it.

use serde::Serialize;

use crate::render::Conventions;
use crate::scene::Scene;

/// How an entry's "wrong reference" is made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Making {
    /// Pixels of the reference moved (an image or hit data).
    Moved,
    /// The 8-bit reference's channels changed (images).
    Channels,
    /// The reference's linear colours written to 8 bits the wrong way (images).
    Quantised,
    /// Rendered by the tracer with the mistake (images and hit data).
    Rendered,
}

/// A classic mistake.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Mistake {
    /// Rows in the wrong order: `y` up instead of down.
    FlippedVertically,
    /// Columns in the wrong order.
    FlippedHorizontally,
    /// `u` and `v` swapped.
    Transposed,
    /// Blue and red exchanged.
    BgrOrder,
    /// `image.gamma` not applied.
    GammaMissing,
    /// `image.gamma` applied twice.
    GammaTwice,
    /// The sRGB curve applied in place of `image.gamma`.
    SrgbInsteadOfGamma,
    /// A gamma of 2.2 applied where the scene gives none.
    GammaUnasked,
    /// `floor` instead of `round` to 8 bits.
    Truncated,
    /// The primary ray through the pixel's corner.
    PixelCorner,
    /// `λ` along the normalised direction.
    LambdaUnitDirection,
    /// Normals carried by `T` instead of `(T⁻¹)ᵀ`.
    NormalsNotInverseTranspose,
    /// Normals not normalised after they are carried.
    NormalsNotNormalised,
    /// Shadow rays start on the surface: shadow acne.
    ShadowAcne,
    /// No shadow rays.
    ShadowsMissing,
    /// No ambient term.
    AmbientMissing,
    /// No specular term.
    SpecularMissing,
    /// Blinn–Phong's half vector instead of Phong's reflected `l`.
    BlinnPhong,
    /// No mirror rays.
    ReflectionMissing,
    /// No refracted rays.
    RefractionMissing,
    /// `η` inverted.
    RefractionRatioInverted,
    /// One bounce more than `max_depth` allows.
    MaxDepthPlusOne,
    /// One bounce fewer than `max_depth` allows.
    MaxDepthMinusOne,
}

/// Every entry, in the order they are tried (cheapest first).
pub const ALL: [Mistake; 23] = [
    Mistake::FlippedVertically,
    Mistake::FlippedHorizontally,
    Mistake::Transposed,
    Mistake::BgrOrder,
    Mistake::GammaMissing,
    Mistake::GammaTwice,
    Mistake::SrgbInsteadOfGamma,
    Mistake::GammaUnasked,
    Mistake::Truncated,
    Mistake::LambdaUnitDirection,
    Mistake::PixelCorner,
    Mistake::NormalsNotInverseTranspose,
    Mistake::NormalsNotNormalised,
    Mistake::ShadowAcne,
    Mistake::ShadowsMissing,
    Mistake::AmbientMissing,
    Mistake::SpecularMissing,
    Mistake::BlinnPhong,
    Mistake::ReflectionMissing,
    Mistake::RefractionMissing,
    Mistake::RefractionRatioInverted,
    Mistake::MaxDepthPlusOne,
    Mistake::MaxDepthMinusOne,
];

impl Mistake {
    /// The entry's name in the report's JSON (`"flipped_vertically"`).
    pub fn id(self) -> &'static str {
        use Mistake::*;
        match self {
            FlippedVertically => "flipped_vertically",
            FlippedHorizontally => "flipped_horizontally",
            Transposed => "transposed",
            BgrOrder => "bgr_order",
            GammaMissing => "gamma_missing",
            GammaTwice => "gamma_twice",
            SrgbInsteadOfGamma => "srgb_instead_of_gamma",
            GammaUnasked => "gamma_unasked",
            Truncated => "truncated",
            PixelCorner => "pixel_corner",
            LambdaUnitDirection => "lambda_unit_direction",
            NormalsNotInverseTranspose => "normals_not_inverse_transpose",
            NormalsNotNormalised => "normals_not_normalised",
            ShadowAcne => "shadow_acne",
            ShadowsMissing => "shadows_missing",
            AmbientMissing => "ambient_missing",
            SpecularMissing => "specular_missing",
            BlinnPhong => "blinn_phong",
            ReflectionMissing => "reflection_missing",
            RefractionMissing => "refraction_missing",
            RefractionRatioInverted => "refraction_ratio_inverted",
            MaxDepthPlusOne => "max_depth_plus_one",
            MaxDepthMinusOne => "max_depth_minus_one",
        }
    }

    /// The mistake in a few words, as a heading.
    pub fn title(self) -> &'static str {
        use Mistake::*;
        match self {
            FlippedVertically => "upside down (y up instead of down)",
            FlippedHorizontally => "mirrored left to right",
            Transposed => "u and v swapped",
            BgrOrder => "channels in BGR order",
            GammaMissing => "gamma missing",
            GammaTwice => "gamma applied twice",
            SrgbInsteadOfGamma => "the sRGB curve instead of image.gamma",
            GammaUnasked => "a gamma the scene does not ask for",
            Truncated => "truncated instead of rounded to 8 bits",
            PixelCorner => "rays through the pixel's corner (no + ½)",
            LambdaUnitDirection => "λ measured along the normalised direction",
            NormalsNotInverseTranspose => "normals not carried by the inverse transpose",
            NormalsNotNormalised => "normals not normalised",
            ShadowAcne => "shadow acne (shadow rays not moved off the surface)",
            ShadowsMissing => "shadows missing",
            AmbientMissing => "ambient term missing",
            SpecularMissing => "specular term missing",
            BlinnPhong => "Blinn–Phong instead of Phong",
            ReflectionMissing => "reflection missing",
            RefractionMissing => "refraction missing",
            RefractionRatioInverted => "refraction ratio inverted",
            MaxDepthPlusOne => "max_depth off by one (one bounce too many)",
            MaxDepthMinusOne => "max_depth off by one (one bounce too few)",
        }
    }

    /// What went wrong, in one or two sentences a student understands.
    pub fn explanation(self) -> &'static str {
        use Mistake::*;
        match self {
            FlippedVertically => {
                "Your image is the reference upside down. Row v = 0 is the top of the image and camera y points down; a tracer with y up (or one that writes the rows bottom first) gives this picture."
            }
            FlippedHorizontally => {
                "Your image is the reference mirrored left to right. Column u = 0 is the left edge and camera x points right: check the sign of x in the primary direction and the order you write the columns in."
            }
            Transposed => {
                "Your image is the reference with rows and columns exchanged: somewhere u and v (or x and y) are swapped, in the primary ray or in how the pixels are stored."
            }
            BgrOrder => {
                "Red and blue are exchanged: the channels are written in BGR order (OpenCV's), where the PNG wants R, G, B."
            }
            GammaMissing => {
                "Your image is the reference without gamma correction: the scene gives image.gamma, so each channel c must become c^(1/gamma) before it is written to 8 bits."
            }
            GammaTwice => {
                "Gamma correction is applied twice: each channel must become c^(1/gamma) once, just before it is written to 8 bits, not also at an earlier step."
            }
            SrgbInsteadOfGamma => {
                "The colours follow the sRGB transfer curve; the course applies the plain power c^(1/gamma) with the scene's image.gamma (they differ most in dark colours)."
            }
            GammaUnasked => {
                "The colours are gamma corrected (c^(1/2.2)) although the scene gives no image.gamma: then the linear colour is written as it is."
            }
            Truncated => {
                "The 8-bit values are truncated: the course writes round(255 · clamp(c, 0, 1)), and your values are one lower wherever the fraction is ½ or more (e.g. int(255 * c) in Python)."
            }
            PixelCorner => {
                "Your primary rays go through the pixels' top-left corners: the ray of pixel (u, v) goes through its centre, x = u + ½ and y = v + ½."
            }
            LambdaUnitDirection => {
                "Your λ is the distance along the normalised direction: the course's λ is measured along the primary direction d as written, not normalised, so it equals your λ divided by |d|."
            }
            NormalsNotInverseTranspose => {
                "The normals of non-uniformly scaled objects are wrong: a normal is carried to world space by the inverse transpose of the object's transform, (T⁻¹)ᵀ n, not by T itself."
            }
            NormalsNotNormalised => {
                "The shading uses normals that are not unit length: after (T⁻¹)ᵀ n the normal must be normalised again, or scaled objects shade too bright or too dark."
            }
            ShadowAcne => {
                "Lit surfaces are speckled with dark pixels (shadow acne): a shadow ray that starts exactly on the surface hits that surface again. Move its origin off the surface by ε along the normal."
            }
            ShadowsMissing => {
                "There are no shadows: a light adds its diffuse and specular terms only when the shadow ray toward it is not blocked."
            }
            AmbientMissing => {
                "The ambient term is missing: every hit starts from ambient ⊙ m.ambient before the lights are added."
            }
            SpecularMissing => {
                "The highlights are missing: each light adds m.specular · max(0, r·v)^shininess as well as the diffuse term."
            }
            BlinnPhong => {
                "The highlights follow Blinn–Phong, (n·h)^shininess with the half vector h; the course uses Phong's (r·v)^shininess, r the mirror image of l about n."
            }
            ReflectionMissing => {
                "Mirror reflections are missing: a material with a non-black mirror adds mirror ⊙ the colour of the reflected ray."
            }
            RefractionMissing => {
                "Refraction is missing: a material with a non-black transmission adds transmission ⊙ the colour of the refracted ray."
            }
            RefractionRatioInverted => {
                "The refracted rays bend the wrong way: entering a material from air η = 1/ior, and leaving it η = ior; yours has the two exchanged."
            }
            MaxDepthPlusOne => {
                "Your recursion goes one bounce deeper than max_depth allows: secondary rays are traced only while depth < max_depth, the primary ray having depth 0."
            }
            MaxDepthMinusOne => {
                "Your recursion stops one bounce early: secondary rays are traced while depth < max_depth, the primary ray having depth 0, so the deepest rays have depth max_depth."
            }
        }
    }

    /// The place in the course's conventions the mistake breaks: a page and its section.
    pub fn convention(self) -> &'static str {
        use Mistake::*;
        match self {
            FlippedVertically | FlippedHorizontally | Transposed => {
                "docs/spec/camera.md, \"Pixels\" and \"The primary ray\""
            }
            BgrOrder | GammaMissing | GammaTwice | SrgbInsteadOfGamma | GammaUnasked
            | Truncated => "docs/spec/shading.md, \"Output\"",
            PixelCorner | LambdaUnitDirection => "docs/spec/camera.md, \"The primary ray\"",
            NormalsNotInverseTranspose | NormalsNotNormalised => "docs/spec/shapes.md, \"Normals\"",
            ShadowAcne => "docs/spec/shading.md, \"Secondary rays\"",
            ShadowsMissing => "docs/spec/shading.md, \"Shadows\"",
            AmbientMissing | SpecularMissing | BlinnPhong => {
                "docs/spec/shading.md, \"The colour of a hit\""
            }
            ReflectionMissing | RefractionMissing | RefractionRatioInverted => {
                "docs/spec/shading.md, \"Reflection and refraction\""
            }
            MaxDepthPlusOne | MaxDepthMinusOne => "docs/spec/shading.md, \"The colour of a hit\"",
        }
    }

    /// How its wrong reference is made.
    pub fn making(self) -> Making {
        use Mistake::*;
        match self {
            FlippedVertically | FlippedHorizontally | Transposed => Making::Moved,
            BgrOrder => Making::Channels,
            GammaMissing | GammaTwice | SrgbInsteadOfGamma | GammaUnasked | Truncated => {
                Making::Quantised
            }
            _ => Making::Rendered,
        }
    }

    /// Whether the entry can explain a submission of this kind (an image, or hit data)
    /// of `scene`: whether the mistake changes anything there.
    pub fn applies(self, scene: &Scene, image: bool) -> bool {
        use Mistake::*;
        let any = |f: &dyn Fn(&crate::scene::Material) -> bool| scene.materials.iter().any(f);
        let black = glam::DVec3::ZERO;
        let mirrors = any(&|m| m.mirror != black);
        let glass = any(&|m| m.transmission != black);
        match self {
            FlippedVertically | FlippedHorizontally | PixelCorner => true,
            Transposed => scene.width == scene.height,
            NormalsNotInverseTranspose => !scene.objects.is_empty(),
            LambdaUnitDirection => !image,
            // Hit data is graded on the normals' directions alone.
            NormalsNotNormalised => image,
            BgrOrder | Truncated => image,
            GammaMissing | GammaTwice | SrgbInsteadOfGamma => image && scene.gamma.is_some(),
            GammaUnasked => image && scene.gamma.is_none(),
            ShadowAcne | ShadowsMissing => image && !scene.lights.is_empty(),
            AmbientMissing => image && scene.ambient != black,
            SpecularMissing | BlinnPhong => {
                image && !scene.lights.is_empty() && any(&|m| m.specular != black)
            }
            ReflectionMissing => image && mirrors && scene.max_depth > 0,
            RefractionMissing | RefractionRatioInverted => image && glass && scene.max_depth > 0,
            MaxDepthPlusOne => image && (mirrors || glass),
            MaxDepthMinusOne => image && (mirrors || glass) && scene.max_depth > 0,
        }
    }
}

macro_rules! conventions {
    ($($(#[$doc:meta])* $name:ident { $($k:ident: $t:ty = $v:expr),* })*) => {$(
        $(#[$doc])*
        pub struct $name;
        impl Conventions for $name {
            $(const $k: $t = $v;)*
        }
    )*};
}

conventions! {
    /// Rays through the pixel's (or sample cell's) corner.
    Corner { PIXEL_OFFSET: f64 = 0.0 }
    /// `λ` along `d/|d|`.
    UnitLambda { UNIT_DIRECTION_LAMBDA: bool = true }
    /// Normals carried by `T`.
    ForwardNormals { INVERSE_TRANSPOSE: bool = false }
    /// Normals left unnormalised.
    RawNormals { NORMALISED: bool = false }
    /// Every light blocked where it would add something, at every depth.
    Acne { SELF_SHADOWED_DEPTHS: u32 = u32::MAX }
    /// … at the primary ray's hit only.
    AcnePrimary { SELF_SHADOWED_DEPTHS: u32 = 1 }
    /// … at the secondary rays' hits only.
    AcneSecondary { SELF_SHADOWED_DEPTHS: u32 = u32::MAX << 1 }
    /// Nothing blocks a light.
    NoShadows { SHADOWS: bool = false }
    /// No ambient term.
    NoAmbient { AMBIENT: bool = false }
    /// No specular term.
    NoSpecular { SPECULAR: bool = false }
    /// Blinn–Phong highlights.
    Blinn { BLINN_PHONG: bool = true }
    /// No mirror rays.
    NoReflection { REFLECTION: bool = false }
    /// No refracted rays.
    NoRefraction { REFRACTION: bool = false }
    /// `η` inverted.
    InvertedEta { INVERTED_ETA: bool = true }
    /// One bounce more.
    DeeperByOne { EXTRA_DEPTH: i64 = 1 }
    /// One bounce fewer.
    ShallowerByOne { EXTRA_DEPTH: i64 = -1 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Face, Ray, Surface, Transform};
    use crate::render::shade::{Lecture, conventional_hit, hit_as_found};
    use glam::DVec3;

    /// The packets' hit data is left as the world wrote it where `hit_as_found`: so it
    /// must hold for the lecture's conventions, and for none that changes a record.
    #[test]
    fn only_the_lectures_hit_data_is_taken_as_found() {
        // Scaled unevenly and turned, so that carrying the normal by `T` or leaving it
        // unnormalised changes it; a ray of length 2.5, so that `λ` along `d/|d|` does.
        let t = Transform::scale(DVec3::new(1.0, 2.0, 3.0))
            .then(&Transform::rotate(DVec3::new(1.0, 1.0, 0.0), 30.0));
        let ray = Ray::new(DVec3::ZERO, DVec3::new(1.5, 0.0, 2.0));
        let s = Surface {
            lambda: 2.0,
            object: 3,
            point: DVec3::new(3.0, 0.0, 4.0),
            object_point: DVec3::new(0.5, 0.5, 0.0),
            normal: DVec3::new(0.0, 0.6, -0.8),
            front: true,
            face: Some(Face::PosY),
        };
        assert!(hit_as_found::<Lecture>());
        assert_eq!(conventional_hit::<Lecture>(&t, &ray, s), s);
        fn not_as_found<C: Conventions>(name: &str, t: &Transform, ray: &Ray, s: Surface) {
            assert!(!hit_as_found::<C>(), "{name} is not the lecture's hit data");
            assert!(
                conventional_hit::<C>(t, ray, s) != s,
                "{name} changes this record"
            );
        }
        not_as_found::<UnitLambda>("UnitLambda", &t, &ray, s);
        not_as_found::<ForwardNormals>("ForwardNormals", &t, &ray, s);
        not_as_found::<RawNormals>("RawNormals", &t, &ray, s);
    }
}
