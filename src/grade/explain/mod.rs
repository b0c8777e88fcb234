//! Explaining one pixel (`raytile trace`, `/v1/trace`): its complete ray tree with every
//! intermediate value of the lecture's computation, as JSON ([`Explanation`]) and as text
//! laid out like the lecture's worked example ([`to_text`]).
//!
//! Nothing here repeats the mathematics: the pixel is shaded by the renderer's own
//! [`Shader::trace_probed`], with the explanation's recorder as its shading probe in place of
//! the renderer's `()`, and the shape tests report their quadratics, faces and triangles
//! through [`Probe`](crate::geometry::Probe). So every ray's colour is the tracer's, and
//! the final colour is [`Renderer::pixel_colour`] quantised by [`quantise`]: the 8-bit
//! colour shown is the rendered PNG's pixel exactly.
//!
//! - [`model`]: the answer's types, as they serialise to JSON;
//! - `recorder`: the shading probe that fills them in while the tracer runs;
//! - [`text`]: the answer laid out as text.
//!
//! For `scenes/lecture.json`, pixel (2, 2):
//!
//! ```text
//! Primary ray (world space):  p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]
//! object 0 "ball" (sphere)
//!   T⁻¹ = [1, 0, 0, -1; 0, 1, 0, 0; 0, 0, 1, -2; 0, 0, 0, 1]
//!   ray in object space: [-1, 0, -2, 1] + λ [0, 0, 1, 0]
//!   a = 1, b = -4, c = 4, discriminant 0: λ = 2 counts
//! ```

pub mod model;
mod recorder;
pub mod text;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geometry::ray::PRIMARY_LAMBDA_MIN;
use crate::render::shade::Shader;
use crate::render::{RayCount, Renderer, quantise};
pub use model::{
    Blocker, Explanation, FaceCheck, FinalColour, HitInfo, ImageInfo, LightInfo, MaterialInfo,
    ObjectTest, PrimaryRay, Quadratic, Ray4, RayNode, Role, Root, Sample, Secondary, Shading,
    TriangleCheck,
};
pub use recorder::part_label;
use recorder::{Explainer, Recorder};
pub use text::to_text;

/// Scenes with at most this many objects are explained against every object by default;
/// larger ones against the BVH's candidates only.
pub const AUTO_ALL_MAX_OBJECTS: usize = 64;

/// Which objects each ray of the explanation is tested against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Candidates {
    /// `all` for scenes of at most [`AUTO_ALL_MAX_OBJECTS`] objects, else `bvh`.
    #[default]
    Auto,
    /// Every object, in scene order: what the lecture does by hand.
    All,
    /// Only the objects whose bounding box the ray enters (and unbounded planes).
    Bvh,
}

/// What to include in an explanation.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExplainOptions {
    /// Which objects are listed for each ray.
    pub candidates: Candidates,
    /// At most this many triangle tests are listed per mesh and ray (hits always are).
    pub max_triangles: usize,
    /// At most this many rays (primary, reflected, refracted) are expanded; deeper ones
    /// still contribute their exact colour but are not broken down.
    pub max_rays: usize,
}

impl Default for ExplainOptions {
    fn default() -> Self {
        ExplainOptions {
            candidates: Candidates::Auto,
            max_triangles: 16,
            max_rays: 64,
        }
    }
}

/// Why a pixel cannot be explained.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ExplainError {
    /// The pixel lies outside the image.
    #[error("pixel ({u}, {v}) is outside the {width} × {height} image")]
    OutsideImage {
        /// Column asked for.
        u: u32,
        /// Row asked for.
        v: u32,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
    },
}

/// Checks that `(u, v)` is a pixel of the renderer's image (callers that take the pixel
/// from a user check this before [`explain`], which would otherwise extrapolate).
pub fn check_pixel(r: &Renderer, u: u32, v: u32) -> Result<(), ExplainError> {
    if u < r.scene.width && v < r.scene.height {
        Ok(())
    } else {
        Err(ExplainError::OutsideImage {
            u,
            v,
            width: r.scene.width,
            height: r.scene.height,
        })
    }
}
/// Explains pixel `(u, v)` (see the module documentation). A pixel outside the image is
/// extrapolated along the same formula; [`check_pixel`] refuses it first.
pub fn explain(r: &Renderer, u: u32, v: u32, opts: &ExplainOptions) -> Explanation {
    let scene = &r.scene;
    let mode = match opts.candidates {
        Candidates::Auto if scene.objects.len() <= AUTO_ALL_MAX_OBJECTS => Candidates::All,
        Candidates::Auto => Candidates::Bvh,
        c => c,
    };
    let (x, y) = (u as f64 + 0.5, v as f64 + 0.5);
    let camera_ray = r.camera.camera_ray(x, y);
    let world_ray = r.camera.pixel_centre(u, v);
    let shader = Shader {
        scene,
        world: &r.world,
    };
    let ex = Explainer::new(r, opts, mode);
    let mut recorder = Recorder::primary(&ex);
    let centre = shader.trace_probed(
        &world_ray,
        0,
        PRIMARY_LAMBDA_MIN,
        &mut RayCount(0),
        &mut recorder,
    );
    let tree = recorder.finish(centre);

    let mut notes = Vec::new();
    let s = scene.samples;
    let mut samples = Vec::new();
    if s > 1 {
        notes.push(format!(
            "The image takes {s} × {s} samples per pixel: the ray tree is the pixel-centre \
             ray's (as hit data uses); the final colour is the mean of the {} samples, as rendered.",
            s * s
        ));
        // The same points, in the same order, as `Renderer::pixel_colour` averages them.
        let sf = s as f64;
        for j in 0..s {
            for i in 0..s {
                let px = u as f64 + (i as f64 + 0.5) / sf;
                let py = v as f64 + (j as f64 + 0.5) / sf;
                let c = shader.trace(
                    &r.camera.through(px, py),
                    0,
                    PRIMARY_LAMBDA_MIN,
                    &mut RayCount(0),
                );
                samples.push(Sample {
                    image_point: [px, py],
                    linear: c.to_array(),
                });
            }
        }
    }
    if ex.truncated() {
        notes.push(format!(
            "Only the first {} rays are broken down; the colours of the others are the \
             tracer's, exactly.",
            opts.max_rays.max(1)
        ));
    }
    if mode == Candidates::Bvh {
        notes.push(
            "Each ray lists only the BVH's candidates: objects whose bounding box it enters, \
             and unbounded planes."
                .into(),
        );
    }

    let linear = r.pixel_colour(u, v, &mut RayCount(0));
    let encoded = match scene.gamma {
        Some(g) => DVec3::new(
            linear.x.powf(1.0 / g),
            linear.y.powf(1.0 / g),
            linear.z.powf(1.0 / g),
        ),
        None => linear,
    };
    let rgb8 = quantise(linear, scene.gamma);
    Explanation {
        u,
        v,
        image: ImageInfo {
            width: scene.width,
            height: scene.height,
            samples: s,
            gamma: scene.gamma,
            focal_length: scene.camera.focal_length,
            max_depth: scene.max_depth,
            objects: scene.objects.len(),
            lights: scene.lights.len(),
        },
        primary: PrimaryRay {
            image_point: [x, y],
            camera: (&camera_ray).into(),
            world_from_camera: scene.camera.world_from_camera.forward_rows(),
            world: (&world_ray).into(),
        },
        candidates: mode,
        colour: FinalColour {
            centre_linear: tree.colour,
            samples,
            linear: linear.to_array(),
            gamma: scene.gamma,
            encoded: encoded.to_array(),
            rgb8,
            hex: format!("#{:02x}{:02x}{:02x}", rgb8[0], rgb8[1], rgb8[2]),
        },
        tree,
        notes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{ColourKernel, Kernel};
    use crate::scene::{Limits, parse};
    use std::sync::Arc;

    /// The example scene of each shape.
    pub(super) const SHAPE_SCENES: [&str; 7] = [
        "sphere.json",
        "cube.json",
        "plane.json",
        "disk.json",
        "cylinder.json",
        "cone.json",
        "mesh.json",
    ];

    /// A colour's exact bits: `==` on floats would let `-0.0` pass for `0.0`.
    pub(super) fn bits(c: [f64; 3]) -> [u64; 3] {
        c.map(f64::to_bits)
    }

    pub(super) fn renderer(name: &str) -> Renderer {
        let path = format!("{}/scenes/{name}", env!("CARGO_MANIFEST_DIR"));
        let bytes = std::fs::read(path).unwrap();
        Renderer::new(Arc::new(parse(&bytes, &Limits::NONE).unwrap()))
    }

    #[test]
    fn lecture_pixel_2_2_value_by_value() {
        let r = renderer("lecture.json");
        let e = explain(&r, 2, 2, &ExplainOptions::default());
        assert_eq!(e.primary.camera.origin, [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(e.primary.camera.direction, [0.0, 0.0, 1.0, 0.0]);
        assert_eq!(e.primary.world, e.primary.camera);
        assert_eq!(e.candidates, Candidates::All);
        let t = &e.tree.tests[0];
        assert_eq!(
            t.inverse_transform,
            [
                [1.0, 0.0, 0.0, -1.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, -2.0],
                [0.0, 0.0, 0.0, 1.0]
            ]
        );
        assert_eq!(t.object_ray.origin, [-1.0, 0.0, -2.0, 1.0]);
        assert_eq!(t.object_ray.direction, [0.0, 0.0, 1.0, 0.0]);
        let q = &t.quadratics[0];
        assert_eq!((q.a, q.b, q.c, q.discriminant), (1.0, -4.0, 4.0, 0.0));
        assert_eq!(q.roots.len(), 1);
        assert_eq!(q.roots[0].lambda, 2.0);
        assert!(q.roots[0].counts);
        assert!(t.chosen);
        let h = e.tree.hit.as_ref().unwrap();
        assert_eq!(h.lambda, 2.0);
        assert_eq!(h.object_point, [-1.0, 0.0, 0.0, 1.0]);
        assert_eq!(h.point, [0.0, 0.0, 2.0, 1.0]);
        assert_eq!(h.normal, [-1.0, 0.0, 0.0, 0.0]);
        assert_eq!(h.name.as_deref(), Some("ball"));
    }

    /// The tree's colour is the tracer's, and the final 8-bit colour is the PNG's.
    #[test]
    fn showcase_colours_match_the_renderer() {
        let r = renderer("showcase.json");
        let shader = Shader {
            scene: &r.scene,
            world: &r.world,
        };
        // Floor, mirror ball, glass ball, small ball, cube, column, cone, backdrop, gem, slab,
        // sky and corners.
        for (u, v) in [
            (512, 700),
            (380, 380),
            (640, 470),
            (470, 500),
            (800, 380),
            (560, 300),
            (200, 400),
            (170, 260),
            (270, 409),
            (743, 477),
            (512, 20),
            (0, 0),
            (1023, 767),
        ] {
            let e = explain(&r, u, v, &ExplainOptions::default());
            let centre = shader.trace(
                &r.camera.pixel_centre(u, v),
                0,
                PRIMARY_LAMBDA_MIN,
                &mut RayCount(0),
            );
            assert_eq!(e.tree.colour, centre.to_array(), "pixel ({u}, {v})");
            let rendered = ColourKernel(&r).pixel(u, v, &mut 0);
            assert_eq!(e.colour.rgb8, rendered, "pixel ({u}, {v})");
            assert_eq!(e.colour.samples.len(), 4);
        }
    }

    /// Every tenth pixel of the scene of each shape: the explained colour is the rendered
    /// pixel's, bit for bit, and the tree's chosen hit is the one its tests say is first.
    #[test]
    fn every_shape_explains_the_rendered_pixel() {
        for name in SHAPE_SCENES {
            let r = renderer(name);
            let shader = Shader {
                scene: &r.scene,
                world: &r.world,
            };
            for v in (0..r.scene.height).step_by(7) {
                for u in (0..r.scene.width).step_by(7) {
                    let e = explain(&r, u, v, &ExplainOptions::default());
                    let centre = shader.trace(
                        &r.camera.pixel_centre(u, v),
                        0,
                        PRIMARY_LAMBDA_MIN,
                        &mut RayCount(0),
                    );
                    let linear = r.pixel_colour(u, v, &mut RayCount(0));
                    assert_eq!(
                        bits(e.tree.colour),
                        bits(centre.to_array()),
                        "{name} ({u}, {v})"
                    );
                    assert_eq!(
                        bits(e.colour.linear),
                        bits(linear.to_array()),
                        "{name} ({u}, {v})"
                    );
                    let rendered = ColourKernel(&r).pixel(u, v, &mut 0);
                    assert_eq!(e.colour.rgb8, rendered, "{name} ({u}, {v})");
                    let chosen = e.tree.tests.iter().filter(|t| t.chosen).count();
                    assert_eq!(chosen, e.tree.hit.is_some() as usize, "{name} ({u}, {v})");
                    if let Some(h) = &e.tree.hit {
                        let t = e.tree.tests.iter().find(|t| t.chosen).unwrap();
                        assert_eq!(t.lambda, Some(h.lambda), "{name} ({u}, {v})");
                    }
                }
            }
        }
    }

    #[test]
    fn bvh_candidates_keep_the_chosen_hit() {
        let r = renderer("showcase.json");
        let opts = ExplainOptions {
            candidates: Candidates::Bvh,
            ..Default::default()
        };
        let e = explain(&r, 380, 380, &opts);
        assert_eq!(e.candidates, Candidates::Bvh);
        assert!(e.tree.tested < e.tree.objects);
        assert!(e.tree.tests.iter().any(|t| t.chosen));
    }

    #[test]
    fn ray_budget_truncates_but_keeps_the_colour() {
        let r = renderer("showcase.json");
        let full = explain(&r, 640, 470, &ExplainOptions::default());
        let cut = explain(
            &r,
            640,
            470,
            &ExplainOptions {
                max_rays: 1,
                ..Default::default()
            },
        );
        assert_eq!(full.tree.colour, cut.tree.colour);
        assert!(cut.notes.iter().any(|n| n.contains("first 1 rays")));
    }

    #[test]
    fn outside_pixels_are_refused_by_check() {
        let r = renderer("lecture.json");
        assert!(check_pixel(&r, 4, 4).is_ok());
        assert!(check_pixel(&r, 5, 0).is_err());
    }
}
