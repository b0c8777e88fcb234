//! Primary rays exactly as `docs/spec/camera.md` writes them:
//! `p(λ) = [0,0,0,1] + λ [−1 + x·2/w, −h/w + y·2/w, f, 0]` with `x = u + ½`, `y = v + ½`
//! at a pixel's centre, then carried into world space by `world_from_camera`.

use glam::{DAffine3, DVec3};

use super::shade::{Conventions, Lecture};
use crate::geometry::Ray;
use crate::scene::Scene;

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
}
