//! Explaining one pixel (`raytile trace`, `/v1/trace`): its complete ray tree with every
//! intermediate value of the lecture's computation, as JSON ([`Explanation`]) and as text
//! laid out like the lecture's worked example ([`to_text`]).
//!
//! Nothing here repeats the mathematics: the pixel is shaded by the renderer's own
//! [`Shader::trace_probed`](crate::render::shade::Shader::trace_probed), with the
//! explanation's recorder as its shading probe in place of the renderer's `()`, and the
//! shape tests report their quadratics, faces and triangles through
//! [`Probe`](crate::geometry::Probe). So every ray's colour is the tracer's, and the
//! final colour is [`Renderer::pixel_colour`] quantised by [`fn@quantise`]: the 8-bit
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
pub mod screen;
pub mod text;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geometry::ray::PRIMARY_LAMBDA_MIN;
use crate::render::camera::sample_point;
use crate::render::{Lecture, RayCount, Renderer, quantise};
pub use model::{
    Blocker, DirectionTerms, Explanation, FaceCheck, FinalColour, HitInfo, ImageInfo, LightInfo,
    MaterialInfo, ObjectTest, PrimaryRay, Quadratic, Ray4, RayNode, Role, Root, Sample, Secondary,
    Shading, SpentAt, TriangleCheck, Truncation,
};
pub use recorder::part_label;
use recorder::{Explainer, Recorder};
pub use text::to_text;

/// Scenes with at most this many objects are explained against every object by default;
/// larger ones against the BVH's candidates only.
pub const AUTO_ALL_MAX_OBJECTS: usize = 64;

/// Most bytes the ray tree of an explanation takes in its JSON answer (as printed, pretty),
/// counted as it is written: each object test and light by its size, each ray by an
/// estimate of its own fields. Once spent, nothing more is listed but each ray's place,
/// colour and chosen hit; the tracer still shades the pixel, so the colours stay exact.
/// An answer thus stays about this size (a few megabytes, the text form less) however
/// large the scene and whatever the options; what a person reads is far less.
pub const MAX_ANSWER_BYTES: usize = 2 << 20;

/// Most lights listed per hit; the others are shaded all the same.
pub const MAX_LIGHTS_LISTED: usize = 64;

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
    /// Which objects are tested for each ray.
    pub candidates: Candidates,
    /// At most this many object tests are listed per ray (the chosen hit's always is);
    /// the others are counted.
    pub max_tests: usize,
    /// At most this many triangle misses, and as many other hits, are listed per mesh and
    /// ray (the hit that counts always is).
    pub max_triangles: usize,
    /// At most this many rays (primary, reflected, refracted) are expanded; deeper ones
    /// still contribute their exact colour but are not broken down.
    pub max_rays: usize,
}

impl Default for ExplainOptions {
    fn default() -> Self {
        ExplainOptions {
            candidates: Candidates::Auto,
            max_tests: AUTO_ALL_MAX_OBJECTS,
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
    let shader = r.shader();
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
    let left_out = ex.left_out();

    let mut notes = Vec::new();
    let s = scene.samples;
    let mut samples = Vec::new();
    if s > 1 {
        notes.push(format!(
            "The image takes {}: the ray tree is the pixel-centre \
             ray's (as hit data uses); the final colour is the mean of the {} samples, as rendered.",
            crate::scene::sample_grid(s),
            s * s
        ));
        // The same points, in the same order, as `Renderer::pixel_colour` averages them.
        for j in 0..s {
            for i in 0..s {
                let [px, py] = sample_point::<Lecture>(u, v, i, j, s);
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
    if let Some(at) = &left_out.spent_at {
        notes.push(format!(
            "The answer's size budget ({MAX_ANSWER_BYTES} bytes) ran out at ray {} ({}): \
             nothing more is listed, and the rays traced after it are not broken down; \
             their colours are the tracer's, exactly.",
            at.ray, at.pointer
        ));
    }
    if left_out.tests_unlisted > 0 {
        notes.push(format!(
            "{} object tests are not listed: at most {} per ray are (and the chosen hit's).",
            left_out.tests_unlisted, opts.max_tests
        ));
    }
    if left_out.lights_unlisted > 0 {
        notes.push(format!(
            "{} lights at hits are not listed: at most {MAX_LIGHTS_LISTED} per hit are; \
             their terms are in the colours all the same.",
            left_out.lights_unlisted
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
            direction_terms: DirectionTerms::new(x, y, scene.width, scene.height),
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
        screen: screen::screen_rays(&tree, &r.camera),
        tree,
        truncated: left_out.spent_at.is_some()
            || left_out.rays_not_broken_down > 0
            || left_out.tests_unlisted > 0
            || left_out.triangles_unlisted > 0
            || left_out.lights_unlisted > 0,
        truncation: Truncation {
            max_rays: opts.max_rays.max(1),
            max_tests: opts.max_tests,
            max_triangles: opts.max_triangles,
            max_lights: MAX_LIGHTS_LISTED,
            max_bytes: MAX_ANSWER_BYTES,
            bytes: left_out.bytes,
            rays_not_broken_down: left_out.rays_not_broken_down,
            tests_unlisted: left_out.tests_unlisted,
            triangles_unlisted: left_out.triangles_unlisted,
            lights_unlisted: left_out.lights_unlisted,
            budget_spent_at: left_out.spent_at,
        },
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
        let shader = r.shader();
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
            let shader = r.shader();
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

    /// `n` identical unit spheres around the camera, of one mirror-and-glass material, and
    /// `lights` point lights: every ray of the tree is a candidate ray of every sphere.
    pub(super) fn coincident_spheres(n: usize, lights: usize, max_depth: u32) -> Renderer {
        let objects: Vec<_> = (0..n)
            .map(|_| serde_json::json!({"shape": "sphere", "material": "glass"}))
            .collect();
        let lights: Vec<_> = (0..lights)
            .map(|i| {
                serde_json::json!({
                    "type": "point",
                    "position": [0.01 * i as f64, -4, 0],
                    "colour": [0.01, 0.01, 0.01]
                })
            })
            .collect();
        let scene = serde_json::json!({
            "version": 1,
            "image": {"width": 5, "height": 5},
            "camera": {"focal_length": 1},
            "max_depth": max_depth,
            "materials": {"glass": {
                "diffuse": [0.1, 0.1, 0.1],
                "mirror": [0.5, 0.5, 0.5],
                "transmission": [0.5, 0.5, 0.5],
                "ior": 1.5
            }},
            "objects": objects,
            "lights": lights
        });
        let bytes = serde_json::to_vec(&scene).unwrap();
        Renderer::new(Arc::new(parse(&bytes, &Limits::NONE).unwrap()))
    }

    /// Every node of a tree, depth first.
    pub(super) fn nodes(n: &RayNode) -> Vec<&RayNode> {
        let mut out = vec![n];
        if let Some(s) = &n.shading {
            for sec in [&s.reflection, &s.refraction].into_iter().flatten() {
                out.extend(nodes(&sec.ray));
            }
        }
        out
    }

    /// The largest options a request may ask for, in every candidates mode.
    fn largest(candidates: Candidates) -> ExplainOptions {
        ExplainOptions {
            candidates,
            max_tests: 1024,
            max_triangles: 1024,
            max_rays: 1024,
        }
    }

    /// The answer stays within its size budget whatever the number of objects and the
    /// candidates mode, and keeps the tracer's colour.
    #[test]
    fn the_answer_is_bounded_whatever_the_scene() {
        for n in [2_000, 20_000] {
            let r = coincident_spheres(n, 1, 10);
            for mode in [Candidates::Auto, Candidates::All, Candidates::Bvh] {
                let e = explain(&r, 2, 2, &largest(mode));
                let json = serde_json::to_vec_pretty(&e).unwrap();
                assert!(
                    json.len() < MAX_ANSWER_BYTES + MAX_ANSWER_BYTES / 8,
                    "{n} spheres, {mode:?}: {} bytes",
                    json.len()
                );
                assert!(e.truncated, "{n} {mode:?}");
                let t = &e.truncation;
                assert!(t.bytes >= MAX_ANSWER_BYTES, "{n} {mode:?}");
                let at = t.budget_spent_at.as_ref().unwrap();
                assert!(at.pointer.starts_with("/tree"), "{}", at.pointer);
                assert!(t.tests_unlisted > 0 && t.rays_not_broken_down > 0);
                let shader = r.shader();
                let centre = shader.trace(
                    &r.camera.pixel_centre(2, 2),
                    0,
                    PRIMARY_LAMBDA_MIN,
                    &mut RayCount(0),
                );
                assert_eq!(bits(e.tree.colour), bits(centre.to_array()));
                let all = nodes(&e.tree);
                let listed: usize = all.iter().map(|n| n.tests.len()).sum();
                let unlisted: usize = all.iter().map(|n| n.tests_unlisted).sum();
                assert_eq!(unlisted, t.tests_unlisted);
                for node in all.iter().filter(|n| !n.truncated) {
                    assert_eq!(node.tested, n, "{mode:?}: every sphere is a candidate");
                    assert_eq!(node.tests.len() + node.tests_unlisted, node.tested);
                }
                assert!(listed <= 1024 * 8, "{listed} tests listed");
            }
        }
    }

    /// By default each ray lists at most `max_tests` objects and the chosen one; the
    /// others are counted, in the ray and in the whole.
    #[test]
    fn each_ray_lists_at_most_max_tests_and_the_chosen_hit() {
        let r = coincident_spheres(20_000, 1, 3);
        let opts = ExplainOptions {
            candidates: Candidates::Bvh,
            ..Default::default()
        };
        let e = explain(&r, 2, 2, &opts);
        assert!(e.truncation.budget_spent_at.is_none());
        let all = nodes(&e.tree);
        assert!(all.len() > 3, "a tree of depth 3");
        for node in &all {
            assert!(node.tests.len() <= opts.max_tests + 1);
            if let Some(h) = &node.hit {
                assert!(node.tests.iter().any(|t| t.chosen && t.object == h.object));
                assert_eq!(node.tested, 20_000);
            }
            assert_eq!(node.tests_unlisted, node.tested - node.tests.len());
            assert!(node.tests.windows(2).all(|w| w[0].object < w[1].object));
        }
        assert_eq!(
            e.truncation.tests_unlisted,
            all.iter().map(|n| n.tests_unlisted).sum::<usize>()
        );
        assert!(
            e.notes
                .iter()
                .any(|n| n.contains("object tests are not listed"))
        );
        let text = to_text(&e);
        assert!(
            text.contains("more objects tested, not listed: at most 64 are listed per ray"),
            "{text}"
        );
        assert!(text.contains("Shortened to stay readable"), "{text}");
    }

    /// At most [`MAX_LIGHTS_LISTED`] lights are listed per hit; the rest are counted and
    /// still shade the colour.
    #[test]
    fn lights_past_the_cap_are_counted() {
        let r = coincident_spheres(1, MAX_LIGHTS_LISTED + 36, 0);
        let e = explain(&r, 2, 2, &ExplainOptions::default());
        let s = e.tree.shading.as_ref().unwrap();
        assert_eq!(s.lights.len(), MAX_LIGHTS_LISTED);
        assert_eq!(s.lights_unlisted, 36);
        assert_eq!(e.truncation.lights_unlisted, 36);
        assert!(e.truncated);
        assert!(to_text(&e).contains("… 36 more lights, not listed"));
        let rendered = ColourKernel(&r).pixel(2, 2, &mut 0);
        assert_eq!(e.colour.rgb8, rendered);
    }

    /// Nothing is left out of the lecture's example, and the answer says so.
    #[test]
    fn a_small_scene_is_not_truncated() {
        let r = renderer("lecture.json");
        let e = explain(&r, 2, 2, &ExplainOptions::default());
        assert!(!e.truncated);
        let t = &e.truncation;
        assert_eq!(
            (
                t.tests_unlisted,
                t.rays_not_broken_down,
                t.budget_spent_at.as_ref()
            ),
            (0, 0, None)
        );
        assert!(t.bytes > 0 && t.bytes < MAX_ANSWER_BYTES);
        assert_eq!(e.tree.tests_unlisted, 0);
        assert!(!to_text(&e).contains("Shortened"));
    }
}
