//! Where the rays of an explanation land on the image, for drawing them over it: each
//! ray of the tree (primary, reflected, refracted) and each shadow ray, cut to its part
//! in front of the camera and projected by the camera's own mapping
//! ([`PrimaryRays::segment_on_image`]), so that no client needs a second copy of it.

use glam::DVec3;
use serde::Serialize;

use super::model::{Ray4, RayNode, Role};
use crate::render::camera::PrimaryRays;

/// One ray as a line on the image, in pixel units (`(u + ½, v + ½)` at a pixel's centre;
/// either end may lie outside the image).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScreenRay {
    /// `primary`, `reflected`, `refracted`, `total_internal_reflection` or `shadow`.
    pub role: &'static str,
    /// The depth of the ray in the tree (of the ray whose hit casts it, for a shadow ray).
    pub depth: u32,
    /// Where it starts, or where it comes out in front of the camera.
    pub from: [f64; 2],
    /// Where it ends (its hit, the light, the blocker), or its vanishing point when it
    /// goes on for ever.
    pub to: [f64; 2],
    /// How it ends: `hit` or `miss` for a ray of the tree; `light` or `blocked` for a
    /// shadow ray.
    pub ends: &'static str,
}

fn xyz(v: [f64; 4]) -> DVec3 {
    DVec3::new(v[0], v[1], v[2])
}

/// The rays of `tree` on the image of `camera`, in the order they are traced; a ray with
/// no part in front of the camera is left out.
pub fn screen_rays(tree: &RayNode, camera: &PrimaryRays) -> Vec<ScreenRay> {
    let mut out = Vec::new();
    walk(tree, camera, &mut out);
    out
}

fn push(
    out: &mut Vec<ScreenRay>,
    camera: &PrimaryRays,
    (role, depth, ends): (&'static str, u32, &'static str),
    ray: &Ray4,
    end: f64,
) {
    if let Some([a, b]) = camera.segment_on_image(xyz(ray.origin), xyz(ray.direction), end) {
        out.push(ScreenRay {
            role,
            depth,
            from: a.to_array(),
            to: b.to_array(),
            ends,
        });
    }
}

fn walk(node: &RayNode, camera: &PrimaryRays, out: &mut Vec<ScreenRay>) {
    let role = match node.role {
        Role::Primary => "primary",
        Role::Reflected => "reflected",
        Role::Refracted => "refracted",
        Role::TotalInternalReflection => "total_internal_reflection",
    };
    let (end, ends) = match &node.hit {
        Some(h) => (h.lambda, "hit"),
        None => (f64::INFINITY, "miss"),
    };
    push(out, camera, (role, node.depth, ends), &node.ray, end);
    let Some(shading) = &node.shading else { return };
    for light in &shading.lights {
        let (end, ends) = match &light.blocker {
            Some(b) => (b.lambda, "blocked"),
            None => (light.lambda_max.unwrap_or(f64::INFINITY), "light"),
        };
        push(
            out,
            camera,
            ("shadow", node.depth, ends),
            &light.shadow_ray,
            end,
        );
    }
    for child in [&shading.reflection, &shading.refraction]
        .into_iter()
        .flatten()
    {
        walk(&child.ray, camera, out);
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::renderer;
    use super::super::{ExplainOptions, explain};

    #[test]
    fn the_lecture_pixel_s_rays_on_its_image() {
        let r = renderer("lecture.json");
        let e = explain(&r, 2, 2, &ExplainOptions::default());
        let [primary, shadow] = &e.screen[..] else {
            panic!("{:?}", e.screen)
        };
        // The primary ray is seen end on: it starts and ends at the pixel's centre.
        assert_eq!((primary.role, primary.ends), ("primary", "hit"));
        assert_eq!(primary.from, [2.5, 2.5]);
        assert_eq!(primary.to, [2.5, 2.5]);
        // The shadow ray toward the light at (0, −4, 0) grazes the ball it leaves: blocked
        // at once, it ends a hair above where it starts.
        assert_eq!(
            (shadow.role, shadow.ends, shadow.depth),
            ("shadow", "blocked", 0)
        );
        assert!((shadow.from[0] - 2.5).abs() < 1e-6 && (shadow.from[1] - 2.5).abs() < 1e-6);
        assert!(
            shadow.to[1] < 2.5 && shadow.to[1] > 2.499,
            "{:?}",
            shadow.to
        );
        // From (3, 2) it reaches the light, which is behind the eye's plane: the line is
        // cut where it crosses that plane, far above the image, straight up.
        let e = explain(&r, 3, 2, &ExplainOptions::default());
        let shadow = &e.screen[1];
        assert_eq!((shadow.role, shadow.ends), ("shadow", "light"));
        assert!(
            (shadow.to[0] - 3.5).abs() < 1e-6 && shadow.to[1] < -1e3,
            "{:?}",
            shadow.to
        );
    }

    #[test]
    fn a_mirror_s_reflected_ray_is_listed_after_its_parent() {
        let r = renderer("showcase.json");
        let (w, h) = (r.scene.width, r.scene.height);
        let found = (0..h)
            .step_by(16)
            .flat_map(|v| (0..w).step_by(16).map(move |u| (u, v)))
            .find_map(|(u, v)| {
                let e = explain(&r, u, v, &ExplainOptions::default());
                e.screen.iter().any(|s| s.role == "reflected").then_some(e)
            });
        let e = found.expect("a pixel of the showcase sees a mirror");
        let at = e.screen.iter().position(|s| s.role == "reflected").unwrap();
        assert_eq!(e.screen[0].role, "primary");
        // A reflected ray starts where its parent ray hit.
        let parent = e.screen[..at]
            .iter()
            .rev()
            .find(|s| s.role != "shadow")
            .unwrap();
        let d = ((e.screen[at].from[0] - parent.to[0]).powi(2)
            + (e.screen[at].from[1] - parent.to[1]).powi(2))
        .sqrt();
        assert!(d < 1e-6, "{d}");
    }
}
