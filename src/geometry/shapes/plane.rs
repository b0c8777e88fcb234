//! The infinite plane `y = 0` with normal `(0, 1, 0)`.

use glam::DVec3;

use super::CanonicalShape;
use crate::geometry::arith::{Arith, Eight, Lanes4, One};
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

    fn flat_normal(&self, _part: u32) -> Option<DVec3> {
        Some(NORMAL)
    }
}

/// `λ = (height − y₀)/Δy`, skipped when `|Δy| < 1e-12`. `radius2` bounds `x² + z²` (a
/// disk); `f64::INFINITY` gives the plane.
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
    if parallel(One, ray.dir.y) != 0 {
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
    let (origin, dir) = (ray.origin.to_array(), ray.dir.to_array());
    let (t, x, z, within) = crossing_point(One, height, radius2, origin, dir);
    let within = within != 0;
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

/// [`intersect_y0`] for eight rays at once, in lanes (`origin` and `dir` in object
/// space, each lane a ray), nothing recorded and no interval: the lanes that are not
/// skipped as parallel and cross `y = height` within `radius2`, and every lane's `λ`.
/// The same operations as alone, so each lane's numbers are its ray's, bit for bit.
#[inline(always)]
pub(crate) fn crossings8<L: Lanes4>(
    n: Eight<L>,
    height: f64,
    radius2: f64,
    origin: [[L::V; 2]; 3],
    dir: [[L::V; 2]; 3],
) -> (u32, [L::V; 2]) {
    let (t, _, _, within) = crossing_point(n, height, radius2, origin, dir);
    (within & !parallel(n, dir[1]), t)
}

/// The lanes whose rays a test skips as parallel to the planes `y = const`:
/// `|Δy| < 1e-12` (a NaN is not skipped).
#[inline(always)]
fn parallel<A: Arith>(n: A, dy: A::N) -> u32 {
    n.gt(n.splat(PARALLEL_EPSILON), n.abs(dy))
}

/// Where rays cross `y = height`: `λ`, the point's `x` and `z`, and the lanes where
/// `x² + z² ≤ radius2` (every lane for an infinite `radius2`, the plane's), in one
/// number or in lanes.
#[inline(always)]
fn crossing_point<A: Arith>(
    n: A,
    height: f64,
    radius2: f64,
    origin: [A::N; 3],
    dir: [A::N; 3],
) -> (A::N, A::N, A::N, u32) {
    let t = crossing(n, n.splat(height), origin[1], dir[1]);
    let x = n.add(origin[0], n.mul(t, dir[0]));
    let z = n.add(origin[2], n.mul(t, dir[2]));
    let within = if radius2 == f64::INFINITY {
        !0
    } else {
        n.ge(n.splat(radius2), n.add(n.mul(x, x), n.mul(z, z)))
    };
    (t, x, z, within)
}

/// Where a ray at height `y0` climbing `dy` per unit `λ` crosses `y = height`, in one
/// number or in lanes.
#[inline(always)]
fn crossing<A: Arith>(n: A, height: A::N, y0: A::N, dy: A::N) -> A::N {
    n.div(n.sub(height, y0), dy)
}

/// The plane's hit `λ` in `(t_min, t_max)` from the ray's `y₀` and `Δy` alone: what
/// [`intersect`] finds, for a caller that has not computed the ray's other
/// components (a world's planes, tested by every ray).
#[inline(always)]
pub fn lambda_from_y(y0: f64, dy: f64, t_min: f64, t_max: f64) -> Option<f64> {
    let (hit, t) = lambdas_from_y(One, y0, dy, t_min, t_max);
    (hit == 1).then_some(t)
}

/// [`lambda_from_y`] in one number or in lanes, each lane that number's, bit for bit:
/// the lanes with a hit, and each lane's crossing (read only where it hits).
#[inline(always)]
pub(crate) fn lambdas_from_y<A: Arith>(
    n: A,
    y0: A::N,
    dy: A::N,
    t_min: f64,
    t_max: A::N,
) -> (u32, A::N) {
    let t = crossing(n, n.splat(0.0), y0, dy);
    let within = n.gt(t, n.splat(t_min)) & n.gt(t_max, t);
    (within & !parallel(n, dy), t)
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

    /// A height or a climb of any sign and scale, zeros, the parallel threshold and
    /// the extremes included.
    fn any_y() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(0.0),
            Just(-0.0),
            Just(PARALLEL_EPSILON),
            Just(-PARALLEL_EPSILON),
            Just(1e-13),
            Just(1e-300),
            Just(1e300),
            Just(f64::INFINITY),
            -5.0f64..5.0,
        ]
    }

    /// [`lambdas_from_y`] in the lanes of `n` against [`lambda_from_y`] of each lane.
    fn lanes_agree<L: crate::geometry::arith::Lanes4>(
        n: crate::geometry::arith::Eight<L>,
        y0: &[f64; 8],
        dy: &[f64; 8],
        t_min: f64,
        t_max: &[f64; 8],
    ) -> Result<(), TestCaseError> {
        let (hit, t) = lambdas_from_y(n, n.load(y0), n.load(dy), t_min, n.load(t_max));
        let t = n.store(t);
        for k in 0..8 {
            let lane = (hit >> k & 1 == 1).then_some(t[k]);
            let alone = lambda_from_y(y0[k], dy[k], t_min, t_max[k]);
            prop_assert_eq!(
                lane.map(f64::to_bits),
                alone.map(f64::to_bits),
                "lane {}",
                k
            );
        }
        Ok(())
    }

    proptest! {
        /// Eight rays' heights and climbs at once, each lane to its own `t_max`: each
        /// finds what it finds alone, bit for bit, in SSE2 lanes and, where the
        /// processor has them, in AVX2 lanes.
        #[test]
        fn eight_heights_in_lanes_find_what_each_finds_alone(
            y0 in prop::array::uniform8(any_y()),
            dy in prop::array::uniform8(any_y()),
            t_min in prop_oneof![Just(1e-9), Just(0.0), Just(-1.0), 0.0f64..2.0],
            t_max in prop::array::uniform8(prop_oneof![Just(f64::INFINITY), 0.0f64..8.0]),
        ) {
            let n = crate::geometry::arith::Eight(crate::geometry::arith::Portable);
            lanes_agree(n, &y0, &dy, t_min, &t_max)?;
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = crate::geometry::bounds::x86::Avx2::detect() {
                let n = crate::geometry::arith::Eight(avx2);
                avx2.run(|| lanes_agree(n, &y0, &dy, t_min, &t_max))?;
            }
        }
    }

    #[test]
    fn parallel_ray_misses() {
        let r = Ray::new(DVec3::new(0.0, 1.0, 0.0), DVec3::new(1.0, 1e-13, 0.0));
        assert_eq!(intersect(&r, 1e-9, f64::INFINITY, &mut ()), None);
    }
}
