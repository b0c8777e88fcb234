//! The closed cone `x² + z² = ((1 − y)/2)²`, apex `(0, 1, 0)`, base the unit disk at
//! `y = −1`. Parts: 0 the side, 1 the base.

use glam::DVec3;

use super::{CanonicalShape, plane::intersect_y0, solve_quadratic};
use crate::geometry::{bounds::Aabb, hit::Probe, ray::Ray};

/// The parts' labels, by part index; the tests report under the same labels.
const PARTS: [&str; 2] = ["side", "base"];

/// The cone as a [`CanonicalShape`]: closed, its side cut to `−1 ≤ y ≤ 1` and linear
/// for rays parallel to a generator line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Cone;

impl CanonicalShape for Cone {
    const NAME: &'static str = "cone";
    const CLOSED: bool = true;
    const BOUNDED_QUADRIC: bool = true;
    const PARTS: &'static [&'static str] = &PARTS;
    const LINEAR_SIDE: bool = true;

    fn bounds(&self) -> Option<Aabb> {
        Some(Aabb::CANONICAL)
    }

    #[inline(always)]
    fn intersect<P: Probe>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        intersect(ray, t_min, t_max, probe)
    }

    fn normal(&self, object_point: DVec3, part: u32) -> DVec3 {
        normal(object_point, part)
    }
}

/// With `k = 1 − y₀`, the side is `a λ² + b λ + c = 0`, `a = Δx² + Δz² − Δy²/4`,
/// `b = 2(x₀Δx + z₀Δz) + kΔy/2`, `c = x₀² + z₀² − k²/4`, valid where `−1 ≤ y ≤ 1`
/// (the other nappe, above the apex, is not part of the cone).
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<(f64, u32)> {
    let (o, d) = (ray.origin, ray.dir);
    let k = 1.0 - o.y;
    let a = d.x * d.x + d.z * d.z - 0.25 * d.y * d.y;
    let b = 2.0 * (o.x * d.x + o.z * d.z) + 0.5 * k * d.y;
    let c = o.x * o.x + o.z * o.z - 0.25 * k * k;
    let mut best: Option<(f64, u32)> = None;
    let mut limit = t_max;
    let roots = if a == 0.0 {
        // Parallel to a generator line: the quadratic is linear.
        [(b != 0.0).then(|| -c / b), None]
    } else {
        solve_quadratic(PARTS[0], a, b, c, probe)
    };
    for t in roots.into_iter().flatten() {
        let y = o.y + t * d.y;
        if (-1.0..=1.0).contains(&y) && t > t_min && t < limit {
            best = Some((t, 0));
            limit = t;
        }
    }
    if let Some(t) = intersect_y0(PARTS[1], ray, -1.0, 1.0, t_min, limit, probe) {
        best = Some((t, 1));
    }
    best
}

/// The outward normal: the gradient `(x, (1 − y)/4, z)` of the side, `(0, −1, 0)` on the
/// base, and `(0, 1, 0)` at the apex where the gradient vanishes.
pub fn normal(p: DVec3, part: u32) -> DVec3 {
    if part == 1 {
        return DVec3::NEG_Y;
    }
    let n = DVec3::new(p.x, 0.25 * (1.0 - p.y), p.z);
    if n.length_squared() == 0.0 {
        DVec3::Y
    } else {
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: [f64; 3], d: [f64; 3]) -> Option<(f64, u32)> {
        intersect(&Ray::new(o.into(), d.into()), 1e-9, f64::INFINITY, &mut ())
    }

    #[test]
    fn side_at_half_height() {
        // At y = 0 the radius is 1/2.
        assert_eq!(hit([0.0, 0.0, -3.0], [0.0, 0.0, 1.0]), Some((2.5, 0)));
    }

    #[test]
    fn base_and_apex() {
        assert_eq!(hit([0.2, -3.0, 0.0], [0.0, 1.0, 0.0]), Some((2.0, 1)));
        // Straight down onto the apex.
        assert_eq!(hit([0.0, 3.0, 0.0], [0.0, -1.0, 0.0]), Some((2.0, 0)));
        assert_eq!(normal(DVec3::Y, 0), DVec3::Y);
    }

    #[test]
    fn upper_nappe_is_not_part_of_the_cone() {
        // At y = 2 the double cone has radius 1/2; the real cone ends at y = 1.
        assert_eq!(hit([0.0, 2.0, -3.0], [0.0, 0.0, 1.0]), None);
    }

    #[test]
    fn side_normal_is_gradient() {
        let n = normal(DVec3::new(0.5, 0.0, 0.0), 0).normalize();
        let expect = DVec3::new(1.0, 0.5, 0.0).normalize();
        assert!((n - expect).length() < 1e-15);
    }
}
