//! The unit disk `y = 0, x² + z² ≤ 1`, normal `(0, 1, 0)`.

use glam::DVec3;

use super::CanonicalShape;
use crate::geometry::{bounds::Aabb, hit::Probe, ray::Ray};

/// The disk as a [`CanonicalShape`]: one part, open.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Disk;

impl CanonicalShape for Disk {
    const NAME: &'static str = "disk";
    const CLOSED: bool = false;

    fn bounds(&self) -> Option<Aabb> {
        Some(Aabb {
            min: DVec3::new(-1.0, 0.0, -1.0),
            max: DVec3::new(1.0, 0.0, 1.0),
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

    fn normal(&self, _object_point: DVec3, _part: u32) -> DVec3 {
        super::plane::NORMAL
    }
}

/// The disk's hit `λ` in `(t_min, t_max)`; the rim counts.
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<f64> {
    super::plane::intersect_y0("disk", ray, 0.0, 1.0, t_min, t_max, probe)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inside_rim_and_outside() {
        let down = |x: f64| Ray::new(DVec3::new(x, 1.0, 0.0), DVec3::new(0.0, -1.0, 0.0));
        assert_eq!(
            intersect(&down(0.5), 1e-9, f64::INFINITY, &mut ()),
            Some(1.0)
        );
        assert_eq!(
            intersect(&down(1.0), 1e-9, f64::INFINITY, &mut ()),
            Some(1.0)
        );
        assert_eq!(
            intersect(&down(1.0 + 1e-12), 1e-9, f64::INFINITY, &mut ()),
            None
        );
    }
}
