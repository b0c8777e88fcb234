//! Primary rays exactly as `docs/spec/camera.md` writes them:
//! `p(λ) = [0,0,0,1] + λ [−1 + x·2/w, −h/w + y·2/w, f, 0]` with `x = u + ½`, `y = v + ½`
//! at a pixel's centre, then carried into world space by `world_from_camera`.

use glam::{DAffine3, DVec2, DVec3};

use super::shade::{Conventions, Lecture};
use crate::geometry::Ray;
use crate::scene::Scene;

/// How far in front of the eye, in focal lengths, a path on its way behind the camera is
/// cut when it is drawn on the image.
const NEAR: f64 = 1e-6;

/// How far along a path that runs parallel to the image plane for ever it is drawn, in
/// lengths of its direction: far enough to leave any image it crosses.
const FAR: f64 = 1e6;

/// Makes the primary rays of a scene's camera.
#[derive(Debug, Clone, Copy)]
pub struct PrimaryRays {
    world_from_camera: DAffine3,
    origin: DVec3,
    width: f64,
    height: f64,
    focal_length: f64,
    identity: bool,
}

impl PrimaryRays {
    /// The camera of `scene`.
    pub fn new(scene: &Scene) -> Self {
        let m = scene.camera.world_from_camera.forward;
        PrimaryRays {
            world_from_camera: m,
            origin: m.transform_point3(DVec3::ZERO),
            width: scene.width as f64,
            height: scene.height as f64,
            focal_length: scene.camera.focal_length,
            identity: m == DAffine3::IDENTITY,
        }
    }

    /// The camera-space direction through image point `(x, y)` in pixel units.
    #[inline]
    pub fn camera_dir(&self, x: f64, y: f64) -> DVec3 {
        let (w, h) = (self.width, self.height);
        DVec3::new(-1.0 + x * 2.0 / w, -h / w + y * 2.0 / w, self.focal_length)
    }

    /// The camera-space ray through `(x, y)`.
    #[inline]
    pub fn camera_ray(&self, x: f64, y: f64) -> Ray {
        Ray::new(DVec3::ZERO, self.camera_dir(x, y))
    }

    /// The world-space ray through image point `(x, y)`.
    #[inline]
    pub fn through(&self, x: f64, y: f64) -> Ray {
        let d = self.camera_dir(x, y);
        if self.identity {
            // Skipping the identity keeps the lecture's rays bit-exact (no `+ 0·x` terms).
            Ray::new(DVec3::ZERO, d)
        } else {
            Ray::new(self.origin, self.world_from_camera.transform_vector3(d))
        }
    }

    /// The world-space ray through the centre of pixel `(u, v)`.
    #[inline]
    pub fn pixel_centre(&self, u: u32, v: u32) -> Ray {
        self.pixel_ray::<Lecture>(u, v)
    }

    /// The world-space ray of pixel `(u, v)` under conventions `C`: through its centre,
    /// or through its corner for a tracer that forgets the `+ ½`.
    #[inline]
    pub fn pixel_ray<C: Conventions>(&self, u: u32, v: u32) -> Ray {
        self.through(u as f64 + C::PIXEL_OFFSET, v as f64 + C::PIXEL_OFFSET)
    }

    /// The world-space ray of sample `(i, j)` of pixel `(u, v)`, the pixel cut into
    /// `s × s` cells, under conventions `C`: through the cell's centre in the lecture's.
    #[inline]
    pub fn sample_ray<C: Conventions>(&self, u: u32, v: u32, i: u32, j: u32, s: u32) -> Ray {
        let sf = s as f64;
        let x = u as f64 + (i as f64 + C::PIXEL_OFFSET) / sf;
        let y = v as f64 + (j as f64 + C::PIXEL_OFFSET) / sf;
        self.through(x, y)
    }

    /// The world-space origin every primary ray shares.
    pub fn origin(&self) -> DVec3 {
        self.origin
    }
    /// Where world point `p` lands on the image, in pixel units (`(u + ½, v + ½)` at a
    /// pixel's centre): the primary rays' mapping run backwards. `None` for a point that
    /// is not in front of the camera (camera-space `z ≤ 0`).
    pub fn image_point(&self, p: DVec3) -> Option<DVec2> {
        self.project(self.world_from_camera.inverse().transform_point3(p))
    }

    /// The image point of camera-space `q`: the `(x, y)` whose direction
    /// `[−1 + x·2/w, −h/w + y·2/w, f]` is `q` scaled by `f / q.z`.
    fn project(&self, q: DVec3) -> Option<DVec2> {
        if q.z.is_nan() || q.z <= 0.0 {
            return None;
        }
        let (w, h, f) = (self.width, self.height, self.focal_length);
        let p = DVec2::new(
            (1.0 + q.x * f / q.z) * w / 2.0,
            (h / w + q.y * f / q.z) * w / 2.0,
        );
        p.is_finite().then_some(p)
    }

    /// The world-space path `origin + t·dir`, `t` in `[0, end]` (`end` infinite for a
    /// ray that goes on for ever), as the two ends on the image of its part in front of
    /// the camera; `None` when no part is. A ray that goes on for ever away from the eye
    /// ends at its direction's vanishing point.
    pub fn segment_on_image(&self, origin: DVec3, dir: DVec3, end: f64) -> Option<[DVec2; 2]> {
        let inv = self.world_from_camera.inverse();
        let (o, d) = (inv.transform_point3(origin), inv.transform_vector3(dir));
        let near = NEAR * self.focal_length;
        let (mut t0, mut t1) = (0.0_f64, end);
        if d.z > 0.0 {
            t0 = t0.max((near - o.z) / d.z);
        } else if d.z < 0.0 {
            t1 = t1.min((near - o.z) / d.z);
        } else if o.z < near {
            return None;
        }
        if t0.is_nan() || t1.is_nan() || t0 > t1 {
            return None;
        }
        let a = self.project(o + t0 * d)?;
        let b = if t1.is_finite() {
            self.project(o + t1 * d)?
        } else if d.z > 0.0 {
            self.project(d)?
        } else {
            self.project(o + FAR * d)?
        };
        Some([a, b])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Limits, parse};

    fn camera(json: &str) -> PrimaryRays {
        PrimaryRays::new(&parse(json.as_bytes(), &Limits::NONE).unwrap())
    }

    const TILTED: &str = r#"{"version": 1, "image": {"width": 40, "height": 30},
        "camera": {"focal_length": 1.5, "look_at": {"eye": [1, 2, -3], "target": [0, 0, 4], "up": [0, 1, 0]}},
        "objects": [], "lights": []}"#;

    #[test]
    fn image_point_undoes_the_primary_ray() {
        let lecture = r#"{"version": 1, "image": {"width": 5, "height": 5},
            "camera": {"focal_length": 1}, "objects": [], "lights": []}"#;
        for cam in [camera(TILTED), camera(lecture)] {
            for (x, y) in [(0.5, 0.5), (20.0, 15.0), (39.5, 3.25), (-7.0, 44.0)] {
                let r = cam.through(x, y);
                let p = cam.image_point(r.origin + 2.5 * r.dir).unwrap();
                assert!((p - DVec2::new(x, y)).length() < 1e-9, "{x} {y}: {p}");
                // The ray's point at infinity is where it vanishes: its own pixel.
                let [a, b] = cam
                    .segment_on_image(r.origin + r.dir, r.dir, f64::INFINITY)
                    .unwrap();
                assert!((a - DVec2::new(x, y)).length() < 1e-9 && (b - a).length() < 1e-9);
            }
        }
    }

    #[test]
    fn behind_the_camera_is_cut_or_nothing() {
        let cam = camera(TILTED);
        let back = cam.through(20.0, 15.0);
        assert_eq!(cam.image_point(back.origin - back.dir), None);
        assert_eq!(
            cam.segment_on_image(back.origin - back.dir, -back.dir, 3.0),
            None
        );
        // From in front to behind: drawn from its start until it crosses the eye's plane.
        let start = back.origin + 2.0 * back.dir;
        let [a, b] = cam.segment_on_image(start, -back.dir, 10.0).unwrap();
        assert!((a - DVec2::new(20.0, 15.0)).length() < 1e-9);
        assert!(b.is_finite());
    }
}
