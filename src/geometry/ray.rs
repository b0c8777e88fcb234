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

/// Eight rays coordinate by coordinate, each coordinate's eight side by side: a
/// packet's shadow rays toward a light as its terms are computed (in lanes), read in
/// lanes by the planes' test and the wide tree's set-up, a ray at a time by the rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rays8 {
    /// The origins' coordinates: `origin[a][k]` is coordinate `a` of ray `k`'s origin.
    pub origin: [[f64; 8]; 3],
    /// The directions' coordinates, likewise.
    pub dir: [[f64; 8]; 3],
}

impl Rays8 {
    /// `rays`, coordinate by coordinate.
    #[inline(always)]
    pub fn from_rays(rays: &[Ray; 8]) -> Rays8 {
        Rays8 {
            origin: lanes3(rays, |r| r.origin),
            dir: lanes3(rays, |r| r.dir),
        }
    }

    /// Ray `k` (of the eight, `k < 8`).
    #[inline(always)]
    pub fn ray(&self, k: usize) -> Ray {
        let at = |v: &[[f64; 8]; 3]| DVec3::new(v[0][k], v[1][k], v[2][k]);
        Ray::new(at(&self.origin), at(&self.dir))
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    /// Eight rays taken apart coordinate by coordinate give each ray back, bit for bit
    /// (a negative zero and a NaN too), in its lane.
    #[test]
    fn eight_rays_by_coordinate_give_each_ray_back() {
        let rays: [Ray; 8] = std::array::from_fn(|k| {
            let k = k as f64;
            Ray::new(
                DVec3::new(k, -0.0, 1.5 * k - 3.0),
                DVec3::new(f64::NAN, 2.0 - k, 1e-300 * k),
            )
        });
        let eight = Rays8::from_rays(&rays);
        let bits = |r: &Ray| [r.origin.to_array(), r.dir.to_array()].map(|v| v.map(f64::to_bits));
        for (k, ray) in rays.iter().enumerate() {
            assert_eq!(bits(&eight.ray(k)), bits(ray), "ray {k}");
            assert_eq!(eight.origin[2][k].to_bits(), ray.origin.z.to_bits());
            assert_eq!(eight.dir[1][k].to_bits(), ray.dir.y.to_bits());
        }
    }
}
