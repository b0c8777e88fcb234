//! The unit sphere at the origin, `p · p = 1` (the lecture's shape).

use glam::DVec3;

use super::{CanonicalShape, solve_quadratic};
use crate::geometry::{bounds::Aabb, hit::Probe, ray::Ray, transform::Transform};

/// The unit sphere as a [`CanonicalShape`]: one part, closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sphere;

impl CanonicalShape for Sphere {
    const NAME: &'static str = "sphere";
    const CLOSED: bool = true;

    fn bounds(&self) -> Option<Aabb> {
        Some(Aabb::CANONICAL)
    }

    /// A transformed sphere is an ellipsoid whose exact extent along axis i is the
    /// length of row i of the 3 × 3 part.
    fn world_bounds(&self, world_from_object: &Transform) -> Option<Aabb> {
        let m = world_from_object.forward.matrix3;
        let t = world_from_object.forward.translation;
        let r = DVec3::new(m.row(0).length(), m.row(1).length(), m.row(2).length());
        Some(Aabb {
            min: t - r,
            max: t + r,
        })
    }

    #[inline(always)]
    fn intersect<P: Probe>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        intersect(ray, t_min, t_max, probe).map(|t| (t, 0))
    }

    #[inline(always)]
    fn normal(&self, object_point: DVec3, _part: u32) -> DVec3 {
        normal(object_point)
    }
}

/// The smallest root of `a λ² + b λ + c = 0` in `(t_min, t_max)`, with
/// `a = d·d`, `b = 2 p₀·d`, `c = p₀·p₀ − 1`.
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<f64> {
    let a = ray.dir.dot(ray.dir);
    let b = 2.0 * ray.origin.dot(ray.dir);
    let c = ray.origin.dot(ray.origin) - 1.0;
    first_root(a, b, c, t_min, t_max, probe)
}

#[inline(always)]
fn first_root<P: Probe>(
    a: f64,
    b: f64,
    c: f64,
    t_min: f64,
    t_max: f64,
    probe: &mut P,
) -> Option<f64> {
    solve_quadratic("sphere", a, b, c, probe)
        .into_iter()
        .flatten()
        .find(|&t| t > t_min && t < t_max)
}

/// The outward normal at an object-space point: the point itself.
#[inline]
pub fn normal(p: DVec3) -> DVec3 {
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lecture_tangent_hit() {
        // Pixel (2, 2) of the lecture: [-1,0,-2] + λ[0,0,1] grazes at λ = 2.
        let r = Ray::new(DVec3::new(-1.0, 0.0, -2.0), DVec3::Z);
        assert_eq!(intersect(&r, 1e-9, f64::INFINITY, &mut ()), Some(2.0));
    }

    #[test]
    fn two_roots_take_the_nearer_in_front() {
        let r = Ray::new(DVec3::new(0.0, 0.0, -3.0), DVec3::new(0.0, 0.0, 2.0));
        assert_eq!(intersect(&r, 1e-9, f64::INFINITY, &mut ()), Some(1.0));
    }

    #[test]
    fn from_inside_takes_the_far_root() {
        let r = Ray::new(DVec3::ZERO, DVec3::X);
        assert_eq!(intersect(&r, 1e-9, f64::INFINITY, &mut ()), Some(1.0));
    }

    #[test]
    fn behind_and_missing_rays() {
        let behind = Ray::new(DVec3::new(0.0, 0.0, 3.0), DVec3::Z);
        assert_eq!(intersect(&behind, 1e-9, f64::INFINITY, &mut ()), None);
        let miss = Ray::new(DVec3::new(0.0, 1.5, -3.0), DVec3::Z);
        assert_eq!(intersect(&miss, 1e-9, f64::INFINITY, &mut ()), None);
    }
}
