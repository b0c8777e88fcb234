//! The closed cone `x² + z² = ((1 − y)/2)²`, apex `(0, 1, 0)`, base the unit disk at
//! `y = −1`. Parts: 0 the side, 1 the base.

use glam::DVec3;

use super::{
    CanonicalShape, Nearest8, offer_side_roots8, on_side,
    plane::{crossings8, intersect_y0},
    solve_quadratic,
};
use crate::geometry::arith::{Arith, Eight, Lanes4, One};
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

    fn flat_normal(&self, part: u32) -> Option<DVec3> {
        // The base; the side's normal depends on the point.
        (part == 1).then(|| normal(DVec3::ZERO, part))
    }
}

/// With `k = 1 − y₀`, the side is `a λ² + b λ + c = 0`, `a = Δx² + Δz² − Δy²/4`,
/// `b = 2(x₀Δx + z₀Δz) + kΔy/2`, `c = x₀² + z₀² − k²/4`, valid where `−1 ≤ y ≤ 1`
/// (the other nappe, above the apex, is not part of the cone).
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<(f64, u32)> {
    let (o, d) = (ray.origin, ray.dir);
    let (a, b, c) = coefficients(One, o.to_array(), d.to_array());
    let mut best: Option<(f64, u32)> = None;
    let mut limit = t_max;
    let roots = if a == 0.0 {
        // Parallel to a generator line: the quadratic is linear.
        [(b != 0.0).then(|| linear_root(One, b, c)), None]
    } else {
        solve_quadratic(PARTS[0], a, b, c, probe)
    };
    for t in roots.into_iter().flatten() {
        if on_side(One, o.y, d.y, t) != 0 && t > t_min && t < limit {
            best = Some((t, 0));
            limit = t;
        }
    }
    if let Some(t) = intersect_y0(PARTS[1], ray, BASE, 1.0, t_min, limit, probe) {
        best = Some((t, 1));
    }
    best
}

/// The base's height.
const BASE: f64 = -1.0;

/// [`intersect`] for eight rays at once, in lanes (`origin` and `dir` in object space,
/// each lane a ray), nothing recorded: the bit set of the lanes that find a part in
/// `(t_min, t_max[lane])`, and for those its `λ` and index. The side's roots and the
/// base's crossing are the lone ray's numbers (the same operations), kept by the same
/// rule ([`Nearest8`], [`offer_side_roots8`]): the nearest valid one, a tie to the side. A linear side has
/// one root where `a = 0`, else the quadratic has two, which the lone ray sorts (`a`
/// may be negative); here the nearer valid root is kept whichever comes first, and
/// where one is NaN, the lone ray's `min` and `max` both give the other, which is the
/// one valid here. A zero discriminant's two roots are equal, so the second changes
/// nothing where the lone ray has only the first.
#[inline(always)]
pub(crate) fn intersect8<L: Lanes4>(
    n: Eight<L>,
    origin: [[L::V; 2]; 3],
    dir: [[L::V; 2]; 3],
    t_min: f64,
    t_max: &[f64; 8],
) -> (u32, [f64; 8], [u32; 8]) {
    let mut nearest = Nearest8::new(n, t_min, t_max);
    let (a, b, c) = coefficients(n, origin, dir);
    let zero = n.splat(0.0);
    // `a = 0` exactly (a NaN is not).
    let linear = !n.ne(a, zero) & 0xff;
    if linear != 0 {
        let t = linear_root(n, b, c);
        nearest.offer(
            n,
            linear & n.ne(b, zero) & on_side(n, origin[1], dir[1], t),
            t,
            0,
        );
    }
    offer_side_roots8(n, &mut nearest, a, b, c, origin[1], dir[1]);
    let (across, t) = crossings8(n, BASE, 1.0, origin, dir);
    nearest.offer(n, across, t, 1);
    nearest.found()
}

/// The side's quadratic, with `k = 1 − y₀`: `a = Δx² + Δz² − Δy²/4`,
/// `b = 2(x₀Δx + z₀Δz) + kΔy/2`, `c = x₀² + z₀² − k²/4`, in one number or in lanes.
#[inline(always)]
fn coefficients<A: Arith>(n: A, o: [A::N; 3], d: [A::N; 3]) -> (A::N, A::N, A::N) {
    let k = n.sub(n.splat(1.0), o[1]);
    let a = n.sub(
        n.add(n.mul(d[0], d[0]), n.mul(d[2], d[2])),
        quarter(n, d[1]),
    );
    let b = n.add(
        n.mul(n.splat(2.0), n.add(n.mul(o[0], d[0]), n.mul(o[2], d[2]))),
        n.mul(n.mul(n.splat(0.5), k), d[1]),
    );
    let c = n.sub(n.add(n.mul(o[0], o[0]), n.mul(o[2], o[2])), quarter(n, k));
    (a, b, c)
}

/// `x²/4`, as `0.25 · x · x`.
#[inline(always)]
fn quarter<A: Arith>(n: A, x: A::N) -> A::N {
    n.mul(n.mul(n.splat(0.25), x), x)
}

/// The linear side's root `−c / b` (where `a = 0`), in one number or in lanes.
#[inline(always)]
fn linear_root<A: Arith>(n: A, b: A::N, c: A::N) -> A::N {
    n.div(n.neg(c), b)
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
