//! The axis-aligned cube `[-1, 1]³`, tested face by face as the lecture does.

use glam::DVec3;

use std::borrow::Cow;

use super::CanonicalShape;
use crate::geometry::{
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

    fn normal(&self, _object_point: DVec3, part: u32) -> DVec3 {
        normal(part)
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
#[inline]
pub fn intersect<P: Probe>(ray: &Ray, t_min: f64, t_max: f64, probe: &mut P) -> Option<(f64, u32)> {
    let mut best: Option<(f64, u32)> = None;
    let mut limit = t_max;
    for (i, face) in Face::ALL.into_iter().enumerate() {
        let (axis, sign) = face.axis_sign();
        let d = ray.dir[axis];
        if d.abs() < PARALLEL_EPSILON {
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
        let t = (sign - ray.origin[axis]) / d;
        let (j, k) = ((axis + 1) % 3, (axis + 2) % 3);
        let pj = ray.origin[j] + t * ray.dir[j];
        let pk = ray.origin[k] + t * ray.dir[k];
        let within = (-1.0..=1.0).contains(&pj) && (-1.0..=1.0).contains(&pk);
        if probe.active() {
            let mut p = DVec3::ZERO;
            p[axis] = sign;
            p[j] = pj;
            p[k] = pk;
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

    #[test]
    fn corner_hit() {
        assert_eq!(
            hit([-2.0, -2.0, -2.0], [1.0, 1.0, 1.0]),
            Some((1.0, Face::NegX))
        );
    }
}
