//! The axis-aligned cube `[-1, 1]³`, tested face by face as the lecture does.

use glam::DVec3;
use wide::f64x4;

use std::borrow::Cow;

use super::{CanonicalShape, Nearest8, within_unit};
use crate::geometry::{
    arith::{Arith, Eight, Four, Lanes4, Portable},
    bounds::Aabb,
    hit::{Face, FaceTest, Probe},
    ray::{PARALLEL_EPSILON, Ray},
};

/// The cube as a [`CanonicalShape`]: six parts, the faces in [`Face::ALL`] order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Cube;

impl CanonicalShape for Cube {
    const NAME: &'static str = "cube";
    const CLOSED: bool = true;

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

    #[inline(always)]
    fn occludes(&self, ray: &Ray, t_min: f64, t_max: f64) -> bool {
        occludes(ray, t_min, t_max)
    }

    fn normal(&self, _object_point: DVec3, part: u32) -> DVec3 {
        normal(part)
    }

    fn flat_normal(&self, part: u32) -> Option<DVec3> {
        Some(normal(part))
    }

    fn face(&self, part: u32) -> Option<Face> {
        Some(face(part))
    }

    fn part_label(&self, part: u32) -> Cow<'static, str> {
        Cow::Borrowed(face(part).label())
    }
}

/// The smallest valid face `λ` in `(t_min, t_max)` and the face's index in
/// [`Face::ALL`]. For the face `x = ±1`: `λ = (±1 − x₀)/Δx`, valid when the other two
/// coordinates lie in `[−1, 1]` (closed); faces with `|Δx| < 1e-12` are skipped. A tie
/// (an edge or corner) goes to the face tested first.
///
/// The three faces of each sign are computed together, a lane an axis (the same
/// operations as face by face, so the same bits): their six divisions are then two
/// vector divisions, where one after another they kept the divider busy for most of
/// a cube's test.
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<(f64, u32)> {
    let d = ray.dir;
    let [plus, minus] =
        faces(ray).map(|(t, pj, pk, within)| (t.to_array(), pj.to_array(), pk.to_array(), within));
    let mut best: Option<(f64, u32)> = None;
    let mut limit = t_max;
    for (i, face) in Face::ALL.into_iter().enumerate() {
        let (axis, sign) = face.axis_sign();
        if d[axis].abs() < PARALLEL_EPSILON {
            if probe.active() {
                probe.face(&FaceTest {
                    face: face.label(),
                    lambda: None,
                    point: None,
                    within: false,
                });
            }
            continue;
        }
        let (t, pj, pk, within) = if sign > 0.0 { &plus } else { &minus };
        let (t, within) = (t[axis], within >> axis & 1 == 1);
        if probe.active() {
            let (j, k) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut p = DVec3::ZERO;
            p[axis] = sign;
            p[j] = pj[axis];
            p[k] = pk[axis];
            probe.face(&FaceTest {
                face: face.label(),
                lambda: Some(t),
                point: Some(p),
                within,
            });
        }
        if within && t > t_min && t < limit {
            best = Some((t, i as u32));
            limit = t;
        }
    }
    best
}

/// For the faces of sign +1, then −1, a lane an axis ([`crossing`] in four lanes):
/// `λ`, the point's other two coordinates, and the lanes where they lie on the face.
/// Lane `a` holds axis `a`, then its two others (`(a + 1) % 3`, `(a + 2) % 3`); the
/// fourth lane is unused (a direction of 1 there keeps it finite).
#[inline(always)]
fn faces(ray: &Ray) -> [(f64x4, f64x4, f64x4, u32); 2] {
    let (o, d) = (ray.origin, ray.dir);
    let lanes = |x: f64, y: f64, z: f64, w: f64| f64x4::new([x, y, z, w]);
    let o = [
        lanes(o.x, o.y, o.z, 0.0),
        lanes(o.y, o.z, o.x, 0.0),
        lanes(o.z, o.x, o.y, 0.0),
    ];
    let d = [
        lanes(d.x, d.y, d.z, 1.0),
        lanes(d.y, d.z, d.x, 0.0),
        lanes(d.z, d.x, d.y, 0.0),
    ];
    [1.0, -1.0].map(|sign| crossing(Four(Portable), sign, o, d))
}

/// Where rays cross the plane `axis = sign` of a face, given their coordinates along
/// the face's axis and its two others (`o`, `d`: `[a, j, k]`), in one number or in
/// lanes: `λ = (sign − o_a) / d_a`, the point's other two coordinates, and the lanes
/// where both lie in `[−1, 1]` (the point on the face, edges included).
#[inline(always)]
fn crossing<A: Arith>(n: A, sign: f64, o: [A::N; 3], d: [A::N; 3]) -> (A::N, A::N, A::N, u32) {
    let t = n.div(n.sub(n.splat(sign), o[0]), d[0]);
    let pj = n.add(o[1], n.mul(t, d[1]));
    let pk = n.add(o[2], n.mul(t, d[2]));
    (t, pj, pk, within_unit(n, pj) & within_unit(n, pk))
}

/// [`intersect`] for eight rays at once, in lanes (`origin` and `dir` in object space,
/// each lane a ray), nothing recorded: the bit set of the lanes that find a face in
/// `(t_min, t_max[lane])`, and for those its `λ` and index. Each face's numbers are
/// the lone ray's ([`crossing`], the same operations), and the faces are taken in the
/// same order by the same rule (a parallel face skipped, a nearer valid one replacing
/// the best, a tie kept by the first), so each lane's answer is the lone ray's.
#[inline(always)]
pub(crate) fn intersect8<L: Lanes4>(
    n: Eight<L>,
    origin: [[L::V; 2]; 3],
    dir: [[L::V; 2]; 3],
    t_min: f64,
    t_max: &[f64; 8],
) -> (u32, [f64; 8], [u32; 8]) {
    let epsilon = n.splat(PARALLEL_EPSILON);
    let mut nearest = Nearest8::new(n, t_min, t_max);
    for (i, face) in Face::ALL.into_iter().enumerate() {
        let (axis, sign) = face.axis_sign();
        let (j, k) = ((axis + 1) % 3, (axis + 2) % 3);
        // Not skipped as parallel: `|Δ| < ε` fails (a NaN is not skipped, as alone).
        let across = !n.gt(epsilon, n.abs(dir[axis]));
        let o = [origin[axis], origin[j], origin[k]];
        let (t, _, _, within) = crossing(n, sign, o, [dir[axis], dir[j], dir[k]]);
        nearest.offer(n, across & within, t, i as u32);
    }
    nearest.found()
}

/// Whether [`intersect`] finds a face in `(t_min, t_max)`: whether some face that it
/// does not skip as parallel has a valid `λ` there. The same lanes, without choosing
/// the nearest face: for a shadow ray, any will do.
#[inline]
pub fn occludes(ray: &Ray, t_min: f64, t_max: f64) -> bool {
    let d = ray.dir;
    let n = Four(Portable);
    // The fourth lane's direction is 0: never a face.
    let across = n.ge(
        n.abs(f64x4::new([d.x, d.y, d.z, 0.0])),
        n.splat(PARALLEL_EPSILON),
    );
    let (lo, hi) = (n.splat(t_min), n.splat(t_max));
    faces(ray)
        .into_iter()
        .any(|(t, _, _, within)| within & across & n.gt(t, lo) & n.gt(hi, t) != 0)
}

/// The face of a part index.
pub fn face(part: u32) -> Face {
    Face::ALL[part as usize % 6]
}

/// The outward normal of a face.
pub fn normal(part: u32) -> DVec3 {
    face(part).normal()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: [f64; 3], d: [f64; 3]) -> Option<(f64, Face)> {
        intersect(&Ray::new(o.into(), d.into()), 1e-9, f64::INFINITY, &mut ())
            .map(|(t, i)| (t, face(i)))
    }

    #[test]
    fn front_face() {
        assert_eq!(
            hit([0.0, 0.0, -3.0], [0.0, 0.0, 1.0]),
            Some((2.0, Face::NegZ))
        );
    }

    #[test]
    fn from_inside_hits_exit_face() {
        assert_eq!(
            hit([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
            Some((1.0, Face::PosX))
        );
    }

    #[test]
    fn parallel_faces_are_skipped() {
        // Δx = 1e-13 is below the threshold: ±x faces are not tested, the ray still
        // meets −z.
        assert_eq!(
            hit([0.5, 0.0, -3.0], [1e-13, 0.0, 1.0]),
            Some((2.0, Face::NegZ))
        );
        // Running along the x = 1 plane outside the cube misses.
        assert_eq!(hit([1.5, 0.0, -3.0], [0.0, 0.0, 1.0]), None);
    }

    #[test]
    fn edge_hit_counts_and_ties_to_first_face() {
        // Through the edge x = −1, z = −1: both faces at λ = 1; −x is tested before −z.
        assert_eq!(
            hit([-2.0, 0.0, -2.0], [1.0, 0.0, 1.0]),
            Some((1.0, Face::NegX))
        );
    }

    /// The lecture's test written face by face, one division at a time: what the
    /// lanes must give, bit for bit.
    fn face_by_face(ray: &Ray, t_min: f64, t_max: f64) -> Option<(f64, u32)> {
        let mut best = None;
        let mut limit = t_max;
        for (i, face) in Face::ALL.into_iter().enumerate() {
            let (axis, sign) = face.axis_sign();
            let d = ray.dir[axis];
            if d.abs() < PARALLEL_EPSILON {
                continue;
            }
            let t = (sign - ray.origin[axis]) / d;
            let (j, k) = ((axis + 1) % 3, (axis + 2) % 3);
            let pj = ray.origin[j] + t * ray.dir[j];
            let pk = ray.origin[k] + t * ray.dir[k];
            if (-1.0..=1.0).contains(&pj) && (-1.0..=1.0).contains(&pk) && t > t_min && t < limit {
                best = Some((t, i as u32));
                limit = t;
            }
        }
        best
    }

    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        #[test]
        fn lanes_give_the_face_by_face_test_bit_for_bit(
            o in prop::array::uniform3(prop_oneof![
                (-8i32..8).prop_map(|c| c as f64 * 0.5),
                -3.0f64..3.0,
            ]),
            d in prop::array::uniform3(prop_oneof![
                Just(0.0),
                Just(1e-13),
                (-2i32..=2).prop_map(|c| c as f64 * 0.5),
                -1.0f64..1.0,
            ]),
            t_max in prop_oneof![Just(f64::INFINITY), 0.0f64..6.0],
        ) {
            let ray = Ray::new(o.into(), d.into());
            let lanes = intersect(&ray, 1e-9, t_max, &mut ());
            let one_by_one = face_by_face(&ray, 1e-9, t_max);
            prop_assert_eq!(lanes.map(|(t, i)| (t.to_bits(), i)), one_by_one.map(|(t, i)| (t.to_bits(), i)));
            // A shadow ray is blocked exactly when the full test finds a face: rays
            // along a face, through edges and corners, ending on a face (`t_max`).
            prop_assert_eq!(occludes(&ray, 1e-9, t_max), one_by_one.is_some());
            if let Some((t, _)) = one_by_one {
                prop_assert_eq!(occludes(&ray, 1e-9, t), intersect(&ray, 1e-9, t, &mut ()).is_some());
            }
        }
    }

    #[test]
    fn corner_hit() {
        assert_eq!(
            hit([-2.0, -2.0, -2.0], [1.0, 1.0, 1.0]),
            Some((1.0, Face::NegX))
        );
    }
}
