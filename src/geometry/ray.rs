//! Rays `p(λ) = origin + λ · dir` with an unnormalised direction.
//!
//! `λ` is the lecture's parameter: for a primary ray it is measured along the `d` of
//! `docs/spec/camera.md`, which is not unit length. Affine maps carry a ray without changing `λ`.

use glam::{DAffine3, DVec3};

use super::arith::{Arith, One};

/// A ray: an origin (a point) and a direction (not normalised).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Where the ray starts (homogeneous w = 1).
    pub origin: DVec3,
    /// Where it goes per unit `λ` (homogeneous w = 0).
    pub dir: DVec3,
}

impl Ray {
    /// A ray from `origin` along `dir`.
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Self { origin, dir }
    }

    /// Whether the ray starts at `o` bit for bit (so an origin that is not a number
    /// starts at itself): what a caller that says rays share an origin claims.
    #[inline]
    pub fn starts_at(&self, o: DVec3) -> bool {
        self.origin.to_array().map(f64::to_bits) == o.to_array().map(f64::to_bits)
    }

    /// The point at parameter `lambda`.
    #[inline]
    pub fn at(&self, lambda: f64) -> DVec3 {
        self.origin + lambda * self.dir
    }

    /// The ray carried by an affine map: the origin as a point, the direction as a vector
    /// (by the arithmetic a packet's rays are carried by too, lane by lane).
    #[inline]
    pub fn transformed(&self, m: &DAffine3) -> Ray {
        Ray {
            origin: DVec3::from_array(One.carry_point(m, self.origin.to_array())),
            dir: DVec3::from_array(One.carry_vector(&m.matrix3, self.dir.to_array())),
        }
    }
}

/// The smallest `λ` a primary ray's hit may have: in front of the projection point (`docs/spec/shapes.md`, Which hit counts).
pub const PRIMARY_LAMBDA_MIN: f64 = 1e-9;

/// Below this `|Δ|` a ray is parallel to a face and the face is skipped (`docs/spec/shapes.md`).
pub const PARALLEL_EPSILON: f64 = 1e-12;

/// The vectors `v(ray)` of a packet's eight rays, coordinate by coordinate (each in
/// lanes).
#[inline(always)]
pub(crate) fn lanes3(rays: &[Ray; 8], v: impl Fn(&Ray) -> DVec3) -> [[f64; 8]; 3] {
    let mut c = [[0.0; 8]; 3];
    for (k, ray) in rays.iter().enumerate() {
        (c[0][k], c[1][k], c[2][k]) = v(ray).into();
    }
    c
}
