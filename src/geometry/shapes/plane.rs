//! The infinite plane `y = 0` with normal `(0, 1, 0)`.

use glam::DVec3;

use super::CanonicalShape;
use crate::geometry::{
    bounds::Aabb,
    hit::{FaceTest, Probe},
    ray::{PARALLEL_EPSILON, Ray},
};

/// The plane as a [`CanonicalShape`]: one part, open and unbounded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Plane;

impl CanonicalShape for Plane {
    const NAME: &'static str = "plane";
    const CLOSED: bool = false;

    fn bounds(&self) -> Option<Aabb> {
        None
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

    fn normal(&self, _object_point: DVec3, _part: u32) -> DVec3 {
        NORMAL
    }
}

/// `λ = (0 − y₀)/Δy`, skipped when `|Δy| < 1e-12`. `radius2` bounds `x² + z²` (a disk);
/// `f64::INFINITY` gives the plane.
#[inline]
pub(crate) fn intersect_y0<P: Probe>(
    label: &'static str,
    ray: &Ray,
    height: f64,
    radius2: f64,
    t_min: f64,
    t_max: f64,
    probe: &mut P,
) -> Option<f64> {
    if ray.dir.y.abs() < PARALLEL_EPSILON {
        if probe.active() {
            probe.face(&FaceTest {
                face: label,
                lambda: None,
                point: None,
                within: false,
            });
        }
        return None;
    }
    let t = crossing(height, ray.origin.y, ray.dir.y);
    let x = ray.origin.x + t * ray.dir.x;
    let z = ray.origin.z + t * ray.dir.z;
    let within = radius2 == f64::INFINITY || x * x + z * z <= radius2;
    if probe.active() {
        probe.face(&FaceTest {
            face: label,
            lambda: Some(t),
            point: Some(DVec3::new(x, height, z)),
            within,
        });
    }
    (within && t > t_min && t < t_max).then_some(t)
}

/// Where a ray at height `y0` climbing `dy` per unit `λ` crosses `y = height`.
#[inline(always)]
fn crossing(height: f64, y0: f64, dy: f64) -> f64 {
    (height - y0) / dy
}

/// The plane's hit `λ` in `(t_min, t_max)` from the ray's `y₀` and `Δy` alone: what
/// [`intersect`] finds, for a caller that has not computed the ray's other
/// components (a world's planes, tested by every ray).
#[inline(always)]
pub fn lambda_from_y(y0: f64, dy: f64, t_min: f64, t_max: f64) -> Option<f64> {
    if dy.abs() < PARALLEL_EPSILON {
        return None;
    }
    let t = crossing(0.0, y0, dy);
    (t > t_min && t < t_max).then_some(t)
}

/// The plane's hit `λ` in `(t_min, t_max)`.
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<f64> {
    intersect_y0("plane", ray, 0.0, f64::INFINITY, t_min, t_max, probe)
}

/// The geometric normal, before it is turned to face the ray.
pub const NORMAL: DVec3 = DVec3::Y;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_above_and_below() {
        let down = Ray::new(DVec3::new(3.0, 2.0, 7.0), DVec3::new(0.0, -1.0, 0.0));
        assert_eq!(intersect(&down, 1e-9, f64::INFINITY, &mut ()), Some(2.0));
        let up = Ray::new(DVec3::new(0.0, -4.0, 0.0), DVec3::new(1.0, 2.0, 0.0));
        assert_eq!(intersect(&up, 1e-9, f64::INFINITY, &mut ()), Some(2.0));
    }

    use proptest::prelude::*;

    proptest! {
        #[test]
        fn the_height_alone_gives_the_whole_rays_lambda(
            o in prop::array::uniform3(-5.0f64..5.0),
            y0 in prop_oneof![Just(0.0), Just(-0.0), -5.0f64..5.0],
            d in prop::array::uniform3(-1.0f64..1.0),
            dy in prop_oneof![Just(0.0), Just(1e-13), Just(-2e-12), -1.0f64..1.0],
            t_max in prop_oneof![Just(f64::INFINITY), 0.0f64..8.0],
        ) {
            let r = Ray::new(DVec3::new(o[0], y0, o[2]), DVec3::new(d[0], dy, d[2]));
            let whole = intersect(&r, 1e-9, t_max, &mut ());
            let alone = lambda_from_y(y0, dy, 1e-9, t_max);
            prop_assert_eq!(whole.map(f64::to_bits), alone.map(f64::to_bits));
        }
    }

    #[test]
    fn parallel_ray_misses() {
        let r = Ray::new(DVec3::new(0.0, 1.0, 0.0), DVec3::new(1.0, 1e-13, 0.0));
        assert_eq!(intersect(&r, 1e-9, f64::INFINITY, &mut ()), None);
    }
}
