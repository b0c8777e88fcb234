//! The closed cylinder `x² + z² = 1, −1 ≤ y ≤ 1` with caps at `y = ±1`.
//!
//! Parts: 0 the side, 1 the top cap (`y = +1`), 2 the bottom cap (`y = −1`).

use glam::DVec3;

use super::{
    CanonicalShape, Nearest8, offer_side_roots8, on_side,
    plane::{crossings8, intersect_y0},
    roots_ahead,
};
use crate::geometry::arith::{Arith, Eight, Lanes4, One};
use crate::geometry::{bounds::Aabb, hit::Probe, ray::Ray};

/// The parts' labels, by part index; the tests report under the same labels.
const PARTS: [&str; 3] = ["side", "top", "bottom"];

/// The cylinder as a [`CanonicalShape`]: closed, its side cut to `−1 ≤ y ≤ 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Cylinder;

impl CanonicalShape for Cylinder {
    const NAME: &'static str = "cylinder";
    const CLOSED: bool = true;
    const BOUNDED_QUADRIC: bool = true;
    const PARTS: &'static [&'static str] = &PARTS;

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
        // The caps; the side's normal depends on the point.
        (part != 0).then(|| normal(DVec3::ZERO, part))
    }
}

/// The side is `a λ² + b λ + c = 0` with `a = Δx² + Δz²`, `b = 2(x₀Δx + z₀Δz)`,
/// `c = x₀² + z₀² − 1`, valid where `−1 ≤ y ≤ 1`; the caps are disks at `y = ±1`.
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<(f64, u32)> {
    let (o, d) = (ray.origin, ray.dir);
    let (a, b, c) = side_coefficients(One, o.to_array(), d.to_array());
    let mut best: Option<(f64, u32)> = None;
    let mut limit = t_max;
    // A shadow or mirror ray leaving the side has no root of the side's ahead of it,
    // and only the caps are tested.
    for t in roots_ahead(PARTS[0], a, b, c, t_min, probe)
        .into_iter()
        .flatten()
    {
        if on_side(One, o.y, d.y, t) != 0 && t > t_min && t < limit {
            best = Some((t, 0));
            limit = t;
        }
    }
    for (part, (label, h)) in CAPS.into_iter().enumerate() {
        if let Some(t) = intersect_y0(label, ray, h, 1.0, t_min, limit, probe) {
            best = Some((t, part as u32 + 1));
            limit = t;
        }
    }
    best
}

/// The caps' labels and heights, in the order the tests take them.
const CAPS: [(&str, f64); 2] = [(PARTS[1], 1.0), (PARTS[2], -1.0)];

/// [`intersect`] for eight rays at once, in lanes (`origin` and `dir` in object space,
/// each lane a ray), nothing recorded: the bit set of the lanes that find a part in
/// `(t_min, t_max[lane])`, and for those its `λ` and index. The side's roots and the
/// caps' crossings are the lone ray's numbers (the same operations), kept by the same
/// rule ([`Nearest8`], [`offer_side_roots8`]; where one root is NaN, the lone ray's
/// `min` and `max` both give the other, which is the one valid here). Roots the lone
/// ray skips as behind it ([`roots_ahead`]) are computed here, and refused by the
/// interval as they would be there.
#[inline(always)]
pub(crate) fn intersect8<L: Lanes4>(
    n: Eight<L>,
    origin: [[L::V; 2]; 3],
    dir: [[L::V; 2]; 3],
    t_min: f64,
    t_max: &[f64; 8],
) -> (u32, [f64; 8], [u32; 8]) {
    let mut nearest = Nearest8::new(n, t_min, t_max);
    let (a, b, c) = side_coefficients(n, origin, dir);
    offer_side_roots8(n, &mut nearest, a, b, c, origin[1], dir[1]);
    for (part, (_, h)) in CAPS.into_iter().enumerate() {
        let (across, t) = crossings8(n, h, 1.0, origin, dir);
        nearest.offer(n, across, t, part as u32 + 1);
    }
    nearest.found()
}

/// The side's quadratic: `a = Δx² + Δz²`, `b = 2(x₀Δx + z₀Δz)`, `c = x₀² + z₀² − 1`,
/// in one number or in lanes.
#[inline(always)]
fn side_coefficients<A: Arith>(n: A, o: [A::N; 3], d: [A::N; 3]) -> (A::N, A::N, A::N) {
    let a = n.add(n.mul(d[0], d[0]), n.mul(d[2], d[2]));
    let b = n.mul(n.splat(2.0), n.add(n.mul(o[0], d[0]), n.mul(o[2], d[2])));
    let c = n.sub(n.add(n.mul(o[0], o[0]), n.mul(o[2], o[2])), n.splat(1.0));
    (a, b, c)
}

/// The outward normal at an object-space point of a part.
pub fn normal(p: DVec3, part: u32) -> DVec3 {
    match part {
        1 => DVec3::Y,
        2 => DVec3::NEG_Y,
        _ => DVec3::new(p.x, 0.0, p.z),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: [f64; 3], d: [f64; 3]) -> Option<(f64, u32)> {
        intersect(&Ray::new(o.into(), d.into()), 1e-9, f64::INFINITY, &mut ())
    }

    #[test]
    fn side_cap_and_miss() {
        assert_eq!(hit([0.0, 0.0, -3.0], [0.0, 0.0, 1.0]), Some((2.0, 0)));
        assert_eq!(hit([0.0, 3.0, 0.0], [0.0, -1.0, 0.0]), Some((2.0, 1)));
        assert_eq!(hit([0.0, -3.0, 0.5], [0.0, 1.0, 0.0]), Some((2.0, 2)));
        assert_eq!(hit([0.0, 1.5, -3.0], [0.0, 0.0, 1.0]), None);
    }

    #[test]
    fn from_inside_leaves_through_side() {
        assert_eq!(hit([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]), Some((1.0, 0)));
        assert_eq!(normal(DVec3::new(1.0, 0.0, 0.0), 0), DVec3::X);
    }

    use crate::geometry::shapes::tests::{
        Watching, any_t_max, any_t_min, lanes_agree, off_surface, ray_scale,
    };
    use crate::geometry::shapes::{Shape, leaves_from_outside};
    use proptest::prelude::*;

    proptest! {
        /// Rays leaving the side (started a hair outside it, on it and a hair inside),
        /// rays from anywhere, and rays of extreme scale: every answer, part included,
        /// is the whole formula's, bit for bit.
        #[test]
        fn a_ray_leaving_the_side_is_told_without_its_roots(
            angle in 0.0f64..std::f64::consts::TAU,
            y in -1.2f64..1.2,
            d in prop::array::uniform3(-1.0f64..1.0).prop_map(DVec3::from_array),
            off in off_surface(),
            anywhere in prop::array::uniform3(-3.0f64..3.0).prop_map(DVec3::from_array),
            scale in ray_scale(),
            t_min in any_t_min(),
            t_max in any_t_max(),
        ) {
            let n = DVec3::new(angle.cos(), 0.0, angle.sin());
            let on = n * (1.0 + off) + DVec3::Y * y;
            let rays = [
                Ray::new(on, d),
                Ray::new(on, n + d * 0.5),
                Ray::new(anywhere, d),
                Ray::new(anywhere, d * scale),
                Ray::new(on, (n + d * 0.5) * scale),
            ];
            for r in rays {
                let got = intersect(&r, t_min, t_max, &mut ());
                let want = intersect(&r, t_min, t_max, &mut Watching);
                prop_assert_eq!(got.map(|(t, p)| (t.to_bits(), p)), want.map(|(t, p)| (t.to_bits(), p)), "{:?}", r);
            }
            // In lanes, which compute every root: the same answers.
            let eight = std::array::from_fn(|k| rays[k % rays.len()]);
            lanes_agree(&Shape::Cylinder, &eight, t_min, &[t_max; 8])?;
        }
    }

    /// A shadow ray leaving the side as the shader starts it (a hair outside), which
    /// the shortcut tells without the side's roots, is not blocked, even toward the
    /// caps' heights; the same point's rays inward meet the far side or a cap.
    #[test]
    fn rays_from_the_side_outward_and_inward() {
        let n = DVec3::new(0.6, 0.0, -0.8);
        let o = n * (1.0 + 1e-9) + DVec3::Y * 0.25;
        let at = |d: DVec3, t_max| intersect(&Ray::new(o, d), 1e-6, t_max, &mut ());
        let (_, b, c) = side_coefficients(One, o.to_array(), (n + DVec3::Y).to_array());
        assert!(leaves_from_outside(b, c));
        assert_eq!(at(n + DVec3::Y, 1.0), None);
        assert_eq!(at(n * 0.1 + DVec3::NEG_Y * 3.0, 10.0), None);
        assert_eq!(at(-n, 10.0).map(|(_, part)| part), Some(0));
        assert_eq!(at(-n + DVec3::Y * 2.0, 10.0).map(|(_, part)| part), Some(1));
    }
}
