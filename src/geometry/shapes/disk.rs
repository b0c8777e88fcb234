//! The unit disk `y = 0, x² + z² ≤ 1`, normal `(0, 1, 0)`.

use glam::DVec3;

use super::{CanonicalShape, Nearest8};
use crate::geometry::arith::{Eight, Lanes4};
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

    fn flat_normal(&self, _part: u32) -> Option<DVec3> {
        Some(super::plane::NORMAL)
    }
}

/// The disk's hit `λ` in `(t_min, t_max)`; the rim counts.
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<f64> {
    super::plane::intersect_y0("disk", ray, HEIGHT, RADIUS2, t_min, t_max, probe)
}

/// The disk's plane, `y = 0`.
const HEIGHT: f64 = 0.0;
/// The disk's squared radius.
const RADIUS2: f64 = 1.0;

/// [`intersect`] for eight rays at once, in lanes (`origin` and `dir` in object space,
/// each lane a ray), nothing recorded: the bit set of the lanes with a hit in
/// `(t_min, t_max[lane])`, and for those its `λ` (part 0), each the lone ray's.
#[inline(always)]
pub(crate) fn intersect8<L: Lanes4>(
    n: Eight<L>,
    origin: [[L::V; 2]; 3],
    dir: [[L::V; 2]; 3],
    t_min: f64,
    t_max: &[f64; 8],
) -> (u32, [f64; 8], [u32; 8]) {
    let mut nearest = Nearest8::new(n, t_min, t_max);
    let (across, t) = super::plane::crossings8(n, HEIGHT, RADIUS2, origin, dir);
    nearest.offer(n, across, t, 0);
    nearest.found()
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
