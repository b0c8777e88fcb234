//! The unit sphere at the origin, `p · p = 1` (the lecture's shape).

use glam::DVec3;

use super::{CanonicalShape, roots_ahead};
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
    let (a, b, c) = coefficients(ray);
    roots_ahead(Sphere::NAME, a, b, c, t_min, probe)
        .into_iter()
        .flatten()
        .find(|&t| t > t_min && t < t_max)
}

/// The quadratic's `a = d·d`, `b = 2 p₀·d`, `c = p₀·p₀ − 1` for `ray`.
#[inline(always)]
fn coefficients(ray: &Ray) -> (f64, f64, f64) {
    let a = ray.dir.dot(ray.dir);
    let b = 2.0 * ray.origin.dot(ray.dir);
    let c = ray.origin.dot(ray.origin) - 1.0;
    (a, b, c)
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

    use crate::geometry::shapes::leaves_from_outside;
    use crate::geometry::shapes::tests::{Watching, any_t_max, any_t_min, off_surface, ray_scale};
    use proptest::prelude::*;

    /// What the lecture's formula gives, every root computed.
    fn full(ray: &Ray, t_min: f64, t_max: f64) -> Option<f64> {
        intersect(ray, t_min, t_max, &mut Watching)
    }

    fn vector() -> impl Strategy<Value = DVec3> {
        prop::array::uniform3(-1.0f64..1.0).prop_map(DVec3::from_array)
    }

    proptest! {
        /// Rays leaving the surface (shadow and mirror rays, started a hair off it, or on
        /// it), rays from anywhere, and rays of extreme scale: the skipped roots are
        /// never a hit, and every answer is the full formula's, bit for bit.
        #[test]
        fn a_ray_leaving_from_outside_is_told_without_its_roots(
            u in vector(),
            d in vector(),
            off in off_surface(),
            anywhere in prop::array::uniform3(-3.0f64..3.0),
            scale in ray_scale(),
            t_min in any_t_min(),
            t_max in any_t_max(),
        ) {
            let Some(n) = u.try_normalize() else { return Ok(()) };
            let rays = [
                Ray::new(n * (1.0 + off), d),
                Ray::new(n * (1.0 + off), n + d * 0.5),
                Ray::new(DVec3::from_array(anywhere), d),
                Ray::new(DVec3::from_array(anywhere), d * scale),
                Ray::new(n * (1.0 + off), d * scale),
            ];
            for r in rays {
                let (got, want) = (intersect(&r, t_min, t_max, &mut ()), full(&r, t_min, t_max));
                prop_assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "{:?}", r);
            }
        }
    }

    /// The rays the shortcut is for take it: a shadow ray leaving a lit point, started
    /// off the surface as the shader starts it.
    #[test]
    fn a_shadow_ray_leaving_its_sphere_skips_the_roots() {
        let n = DVec3::new(0.3, 0.8, -0.2).normalize();
        let r = Ray::new(n * (1.0 + 1e-9), DVec3::new(5.0, 9.0, 1.0));
        let (_, b, c) = coefficients(&r);
        assert!(leaves_from_outside(b, c));
        assert_eq!(intersect(&r, 1e-9, 1.0, &mut ()), None);
        // Toward the inside (a specular term's shadow ray can point there), it is hit.
        let inward = Ray::new(r.origin, -n);
        let (_, b, c) = coefficients(&inward);
        assert!(!leaves_from_outside(b, c));
        assert!(intersect(&inward, 1e-9, 10.0, &mut ()).is_some());
    }
}
