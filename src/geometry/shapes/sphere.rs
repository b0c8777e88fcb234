//! The unit sphere at the origin, `p · p = 1` (the lecture's shape).

use glam::DVec3;

use super::{CanonicalShape, discriminant, roots, roots_ahead};
use crate::geometry::arith::{Arith, Eight, Lanes4, One};
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
    let (a, b, c) = coefficients(One, ray.origin.to_array(), ray.dir.to_array());
    roots_ahead(Sphere::NAME, a, b, c, t_min, probe)
        .into_iter()
        .flatten()
        .find(|&t| t > t_min && t < t_max)
}

/// [`intersect`] for eight rays at once, in lanes (`origin` and `dir` in object
/// space, each lane a ray), nothing recorded: the bit set of the lanes with a root in
/// `(t_min, t_max[lane])`, and for those the first. Each lane's numbers are the lone
/// ray's, bit for bit, and so is its answer: the discriminant's test refuses the same
/// rays, and since `a = d·d > 0`, `(−b − √disc) / 2a ≤ (−b + √disc) / 2a` (the
/// rounding is monotone), so the first root in the interval is the nearer where it
/// lies there, else the farther (a NaN root lies nowhere, and where one of the two
/// is NaN the lone ray's `min` and `max` both give the other).
#[inline(always)]
pub(crate) fn intersect8<L: Lanes4>(
    n: Eight<L>,
    origin: [[L::V; 2]; 3],
    dir: [[L::V; 2]; 3],
    t_min: f64,
    t_max: &[f64; 8],
) -> (u32, [f64; 8]) {
    let (a, b, c) = coefficients(n, origin, dir);
    let disc = discriminant(n, a, b, c);
    let zero = n.splat(0.0);
    let real = n.ge(disc, zero) & n.ne(a, zero);
    if real == 0 {
        // Most of a packet's tests: the rays pass the sphere by.
        return (0, [0.0; 8]);
    }
    let (near, far) = roots(n, a, b, disc);
    let (low, high) = (n.splat(t_min), n.load(t_max));
    let near_within = n.gt(near, low) & n.gt(high, near);
    let far_within = n.gt(far, low) & n.gt(high, far);
    let (near, far) = (n.store(near), n.store(far));
    let mut first = [0.0; 8];
    for k in 0..8 {
        first[k] = if near_within >> k & 1 == 1 {
            near[k]
        } else {
            far[k]
        };
    }
    (real & (near_within | far_within), first)
}

/// The quadratic's `a = d·d`, `b = 2 p₀·d`, `c = p₀·p₀ − 1` for a ray from `origin`
/// along `dir`, in one number or in lanes.
#[inline(always)]
fn coefficients<A: Arith>(n: A, origin: [A::N; 3], dir: [A::N; 3]) -> (A::N, A::N, A::N) {
    let a = n.dot(dir, dir);
    let b = n.mul(n.splat(2.0), n.dot(origin, dir));
    let c = n.sub(n.dot(origin, origin), n.splat(1.0));
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

    use crate::geometry::shapes::tests::{
        Watching, any_t_max, any_t_min, lanes_agree, off_surface, ray_scale,
    };
    use crate::geometry::shapes::{Shape, leaves_from_outside};
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

    /// A ray of any of the kinds above, a tangent one (the lecture's pixel), or one
    /// without a direction.
    fn any_ray() -> impl Strategy<Value = Ray> {
        let anywhere = prop::array::uniform3(-3.0f64..3.0).prop_map(DVec3::from_array);
        (
            vector(),
            vector(),
            off_surface(),
            anywhere,
            ray_scale(),
            0..7usize,
        )
            .prop_map(|(u, d, off, anywhere, scale, kind)| {
                let n = u.try_normalize().unwrap_or(DVec3::X);
                match kind {
                    0 => Ray::new(n * (1.0 + off), d),
                    1 => Ray::new(n * (1.0 + off), n + d * 0.5),
                    2 => Ray::new(anywhere, d),
                    3 => Ray::new(anywhere, d * scale),
                    4 => Ray::new(n * (1.0 + off), d * scale),
                    5 => Ray::new(DVec3::new(-1.0, 0.0, -2.0) * scale, DVec3::Z * scale),
                    _ => Ray::new(anywhere, DVec3::ZERO),
                }
            })
    }

    proptest! {
        /// Eight rays of every kind at once, each in its lane to its own `t_max`: each
        /// lane finds what its ray finds alone, bit for bit, in SSE2 lanes and, where
        /// the processor has them, in AVX2 lanes.
        #[test]
        fn eight_rays_in_lanes_find_what_each_finds_alone(
            rays in prop::array::uniform8(any_ray()),
            t_min in any_t_min(),
            t_max in prop::array::uniform8(any_t_max()),
        ) {
            lanes_agree(&Shape::Sphere, &rays, t_min, &t_max)?;
        }
    }

    /// The rays the shortcut is for take it: a shadow ray leaving a lit point, started
    /// off the surface as the shader starts it.
    #[test]
    fn a_shadow_ray_leaving_its_sphere_skips_the_roots() {
        let n = DVec3::new(0.3, 0.8, -0.2).normalize();
        let r = Ray::new(n * (1.0 + 1e-9), DVec3::new(5.0, 9.0, 1.0));
        let (_, b, c) = coefficients(One, r.origin.to_array(), r.dir.to_array());
        assert!(leaves_from_outside(b, c));
        assert_eq!(intersect(&r, 1e-9, 1.0, &mut ()), None);
        // Toward the inside (a specular term's shadow ray can point there), it is hit.
        let inward = Ray::new(r.origin, -n);
        let (_, b, c) = coefficients(One, inward.origin.to_array(), inward.dir.to_array());
        assert!(!leaves_from_outside(b, c));
        assert!(intersect(&inward, 1e-9, 10.0, &mut ()).is_some());
    }
}
