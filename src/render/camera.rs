//! Primary rays exactly as `docs/spec/camera.md` writes them:
//! `p(λ) = [0,0,0,1] + λ [−1 + x·2/w, −h/w + y·2/w, f, 0]` with `x = u + ½`, `y = v + ½`
//! at a pixel's centre, then carried into world space by `world_from_camera`.

use glam::{DAffine3, DMat3, DVec2, DVec3};

use super::Rect;
use super::shade::{Conventions, Lecture};
use crate::geometry::{Ray, bounds::Aabb};
use crate::scene::Scene;

/// How far in front of the eye, in focal lengths, a path on its way behind the camera is
/// cut when it is drawn on the image.
const NEAR: f64 = 1e-6;

/// How far along a path that runs parallel to the image plane for ever it is drawn, in
/// lengths of its direction: far enough to leave any image it crosses.
const FAR: f64 = 1e6;

/// How far outside a block's view a box must lie, relative to its distance from the
/// eye (about an angle, in radians), for [`PrimaryRays::misses`] to say no ray meets
/// it: far above the rounding of a ray's direction, even through an ill-conditioned
/// camera transform, and far below a pixel's width.
const SEPARATION: f64 = 1e-6;

/// Makes the primary rays of a scene's camera.
#[derive(Debug, Clone, Copy)]
pub struct PrimaryRays {
    world_from_camera: DAffine3,
    origin: DVec3,
    width: f64,
    height: f64,
    focal_length: f64,
    identity: bool,
    /// `(M⁻¹)ᵀ` of the linear part `M` of `world_from_camera`: carries a camera-space
    /// plane's normal into world space. `None` when `M` has no usable inverse.
    normal_to_world: Option<DMat3>,
}

impl PrimaryRays {
    /// The camera of `scene`.
    pub fn new(scene: &Scene) -> Self {
        let m = scene.camera.world_from_camera.forward;
        PrimaryRays {
            world_from_camera: m,
            origin: m.transform_point3(DVec3::ZERO),
            width: scene.width as f64,
            height: scene.height as f64,
            focal_length: scene.camera.focal_length,
            identity: m == DAffine3::IDENTITY,
            normal_to_world: Some(m.matrix3.inverse().transpose())
                .filter(|n| m.matrix3.determinant() != 0.0 && n.is_finite()),
        }
    }

    /// Whether no primary ray through any point of the pixels of `block`, under any
    /// conventions and any samples, can meet world-space box `bounds`: a ray starts at
    /// the eye, and its direction lies in the cone of the block's corners (it is
    /// linear in the image point), so a box wholly outside one of the cone's four
    /// sides is missed by every ray. Conservative: the cone is taken a pixel wider on
    /// every side, and the box must lie outside it by `SEPARATION`, so rounding
    /// never makes it say so of a box some ray enters. `false` when unsure (a camera
    /// transform without an inverse, a box that is not finite).
    pub fn misses(&self, block: Rect, bounds: &Aabb) -> bool {
        let Some(to_world) = self.normal_to_world else {
            return false;
        };
        // The camera-space directions through the widened block's two far corners.
        let near = self.camera_dir(f64::from(block.x) - 1.0, f64::from(block.y) - 1.0);
        let far = self.camera_dir(
            f64::from(block.x) + f64::from(block.width) + 1.0,
            f64::from(block.y) + f64::from(block.height) + 1.0,
        );
        // Each side's inward normal in camera space: a camera-space point `q` on a ray
        // of the block has `f·q.x − near.x·q.z ≥ 0`, and so on (`f > 0`, `q.z > 0`).
        let f = self.focal_length;
        let sides = [
            DVec3::new(f, 0.0, -near.x),
            DVec3::new(-f, 0.0, far.x),
            DVec3::new(0.0, f, -near.y),
            DVec3::new(0.0, -f, far.y),
        ];
        let (lo, hi) = (bounds.min - self.origin, bounds.max - self.origin);
        sides.iter().any(|&side| {
            let n = to_world * side;
            // The box's corner farthest along the normal, and a bound on every
            // corner's product with it, to measure the margin against.
            let farthest = DVec3::select(n.cmpgt(DVec3::ZERO), hi, lo);
            let scale = n.abs().dot(lo.abs().max(hi.abs()));
            n.dot(farthest) < -SEPARATION * scale
        })
    }

    /// The camera-space direction through image point `(x, y)` in pixel units.
    #[inline]
    pub fn camera_dir(&self, x: f64, y: f64) -> DVec3 {
        let (w, h) = (self.width, self.height);
        DVec3::new(-1.0 + x * 2.0 / w, -h / w + y * 2.0 / w, self.focal_length)
    }

    /// The camera-space ray through `(x, y)`.
    #[inline]
    pub fn camera_ray(&self, x: f64, y: f64) -> Ray {
        Ray::new(DVec3::ZERO, self.camera_dir(x, y))
    }

    /// The world-space ray through image point `(x, y)`.
    #[inline]
    pub fn through(&self, x: f64, y: f64) -> Ray {
        let d = self.camera_dir(x, y);
        if self.identity {
            // Skipping the identity keeps the lecture's rays bit-exact (no `+ 0·x` terms).
            Ray::new(DVec3::ZERO, d)
        } else {
            Ray::new(self.origin, self.world_from_camera.transform_vector3(d))
        }
    }

    /// The world-space ray through the centre of pixel `(u, v)`.
    #[inline]
    pub fn pixel_centre(&self, u: u32, v: u32) -> Ray {
        self.pixel_ray::<Lecture>(u, v)
    }

    /// The world-space ray of pixel `(u, v)` under conventions `C`: through its centre,
    /// or through its corner for a tracer that forgets the `+ ½`.
    #[inline]
    pub fn pixel_ray<C: Conventions>(&self, u: u32, v: u32) -> Ray {
        self.through(u as f64 + C::PIXEL_OFFSET, v as f64 + C::PIXEL_OFFSET)
    }

    /// The world-space ray of sample `(i, j)` of pixel `(u, v)`, the pixel cut into
    /// `s × s` cells, under conventions `C`: through the cell's centre in the lecture's.
    #[inline]
    pub fn sample_ray<C: Conventions>(&self, u: u32, v: u32, i: u32, j: u32, s: u32) -> Ray {
        let [x, y] = sample_point::<C>(u, v, i, j, s);
        self.through(x, y)
    }

    /// The world-space origin every primary ray shares.
    pub fn origin(&self) -> DVec3 {
        self.origin
    }
    /// Where world point `p` lands on the image, in pixel units (`(u + ½, v + ½)` at a
    /// pixel's centre): the primary rays' mapping run backwards. `None` for a point that
    /// is not in front of the camera (camera-space `z ≤ 0`).
    pub fn image_point(&self, p: DVec3) -> Option<DVec2> {
        self.project(self.world_from_camera.inverse().transform_point3(p))
    }

    /// The image point of camera-space `q`: the `(x, y)` whose direction
    /// `[−1 + x·2/w, −h/w + y·2/w, f]` is `q` scaled by `f / q.z`.
    fn project(&self, q: DVec3) -> Option<DVec2> {
        if q.z.is_nan() || q.z <= 0.0 {
            return None;
        }
        let (w, h, f) = (self.width, self.height, self.focal_length);
        let p = DVec2::new(
            (1.0 + q.x * f / q.z) * w / 2.0,
            (h / w + q.y * f / q.z) * w / 2.0,
        );
        p.is_finite().then_some(p)
    }

    /// The world-space path `origin + t·dir`, `t` in `[0, end]` (`end` infinite for a
    /// ray that goes on for ever), as the two ends on the image of its part in front of
    /// the camera; `None` when no part is. A ray that goes on for ever away from the eye
    /// ends at its direction's vanishing point.
    pub fn segment_on_image(&self, origin: DVec3, dir: DVec3, end: f64) -> Option<[DVec2; 2]> {
        let inv = self.world_from_camera.inverse();
        let (o, d) = (inv.transform_point3(origin), inv.transform_vector3(dir));
        let near = NEAR * self.focal_length;
        let (mut t0, mut t1) = (0.0_f64, end);
        if d.z > 0.0 {
            t0 = t0.max((near - o.z) / d.z);
        } else if d.z < 0.0 {
            t1 = t1.min((near - o.z) / d.z);
        } else if o.z < near {
            return None;
        }
        if t0.is_nan() || t1.is_nan() || t0 > t1 {
            return None;
        }
        let a = self.project(o + t0 * d)?;
        let b = if t1.is_finite() {
            self.project(o + t1 * d)?
        } else if d.z > 0.0 {
            self.project(d)?
        } else {
            self.project(o + FAR * d)?
        };
        Some([a, b])
    }
}

/// The image point, in pixel units, of sample `(i, j)` of pixel `(u, v)` cut into
/// `s × s` cells, under conventions `C`: the cell's centre in the lecture's.
#[inline]
pub fn sample_point<C: Conventions>(u: u32, v: u32, i: u32, j: u32, s: u32) -> [f64; 2] {
    let sf = s as f64;
    [
        u as f64 + (i as f64 + C::PIXEL_OFFSET) / sf,
        v as f64 + (j as f64 + C::PIXEL_OFFSET) / sf,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Limits, parse};
    use proptest::prop_oneof;
    use proptest::strategy::Strategy;

    fn camera(json: &str) -> PrimaryRays {
        PrimaryRays::new(&parse(json.as_bytes(), &Limits::NONE).unwrap())
    }

    const TILTED: &str = r#"{"version": 1, "image": {"width": 40, "height": 30},
        "camera": {"focal_length": 1.5, "look_at": {"eye": [1, 2, -3], "target": [0, 0, 4], "up": [0, 1, 0]}},
        "objects": [], "lights": []}"#;

    #[test]
    fn image_point_undoes_the_primary_ray() {
        let lecture = r#"{"version": 1, "image": {"width": 5, "height": 5},
            "camera": {"focal_length": 1}, "objects": [], "lights": []}"#;
        for cam in [camera(TILTED), camera(lecture)] {
            for (x, y) in [(0.5, 0.5), (20.0, 15.0), (39.5, 3.25), (-7.0, 44.0)] {
                let r = cam.through(x, y);
                let p = cam.image_point(r.origin + 2.5 * r.dir).unwrap();
                assert!((p - DVec2::new(x, y)).length() < 1e-9, "{x} {y}: {p}");
                // The ray's point at infinity is where it vanishes: its own pixel.
                let [a, b] = cam
                    .segment_on_image(r.origin + r.dir, r.dir, f64::INFINITY)
                    .unwrap();
                assert!((a - DVec2::new(x, y)).length() < 1e-9 && (b - a).length() < 1e-9);
            }
        }
    }

    /// Whether some ray of the block (through its pixels' corners, edges' midpoints,
    /// centres and sample points) enters `b` in front of the eye.
    fn some_ray_enters(cam: &PrimaryRays, block: Rect, b: &Aabb) -> bool {
        let steps = [0.0, 0.25, 0.5, 0.75, 1.0 - 1e-12];
        (0..block.width).any(|i| {
            (0..block.height).any(|j| {
                steps.iter().any(|&dx| {
                    steps.iter().any(|&dy| {
                        let x = f64::from(block.x + i) + dx;
                        let y = f64::from(block.y + j) + dy;
                        let r = cam.through(x, y);
                        crate::geometry::bounds::SlabRay::new(r.origin, r.dir)
                            .enter(b.min, b.max, 0.0, f64::INFINITY)
                            .is_some()
                    })
                })
            })
        })
    }

    fn cube(centre: DVec3, half: f64) -> Aabb {
        Aabb {
            min: centre - DVec3::splat(half),
            max: centre + DVec3::splat(half),
        }
    }

    #[test]
    fn a_box_beside_behind_or_in_view_of_a_block() {
        let cam = camera(TILTED);
        let block = Rect {
            x: 10,
            y: 8,
            width: 8,
            height: 2,
        };
        let through = |x: f64, y: f64, t: f64| {
            let r = cam.through(x, y);
            r.origin + t * r.dir
        };
        // In view: a box on the block's middle ray, or around the eye.
        let seen = cube(through(14.0, 9.0, 5.0), 0.01);
        assert!(!cam.misses(block, &seen) && some_ray_enters(&cam, block, &seen));
        assert!(!cam.misses(block, &cube(cam.origin(), 0.5)));
        // Beside it, five pixels left, right, above or below; behind the eye.
        for (x, y) in [(5.0, 9.0), (23.0, 9.0), (14.0, 3.0), (14.0, 15.0)] {
            let beside = cube(through(x, y, 5.0), 0.01);
            assert!(cam.misses(block, &beside), "({x}, {y})");
        }
        assert!(cam.misses(block, &cube(through(14.0, 9.0, -5.0), 0.5)));
        // Not far enough out to be sure: within the pixel of margin.
        assert!(!cam.misses(block, &cube(through(9.5, 9.0, 5.0), 1e-6)));
        // Boxes that are not finite, and a camera without an inverse, say nothing.
        let everything = Aabb {
            min: DVec3::splat(f64::NEG_INFINITY),
            max: DVec3::splat(f64::INFINITY),
        };
        assert!(!cam.misses(block, &everything));
        let mut flat = cam;
        flat.normal_to_world = None;
        assert!(!flat.misses(block, &cube(through(5.0, 9.0, 5.0), 0.01)));
    }

    proptest::proptest! {
        /// A box around a point of a ray through any point of a block (its pixels'
        /// edges too), however small, is never said to be missed by the block's rays:
        /// from any camera, near the eye or far from it.
        #[test]
        fn a_box_some_ray_of_the_block_enters_is_never_said_to_be_missed(
            eye in proptest::array::uniform3(-20.0f64..20.0),
            target in proptest::array::uniform3(-20.0f64..20.0),
            focal in prop_oneof![0.05f64..0.5, 0.5f64..5.0, 5.0f64..500.0],
            (w, h) in (8u32..4096, 8u32..4096),
            corner in (0.0f64..1.0, 0.0f64..1.0),
            size in (1u32..81, 1u32..3),
            at in (edge_or_inside(), edge_or_inside()),
            t in prop_oneof![1e-3f64..1.0, 1.0f64..1e4],
            half in prop_oneof![1e-13f64..1e-9, 1e-9f64..1e-2],
        ) {
            let (eye, target) = (DVec3::from(eye), DVec3::from(target));
            proptest::prop_assume!((target - eye).length() > 0.1);
            let doc = format!(
                r#"{{"version": 1, "image": {{"width": {w}, "height": {h}}},
                "camera": {{"focal_length": {focal}, "look_at": {{"eye": [{}, {}, {}],
                "target": [{}, {}, {}], "up": [0.3, 1, 0.1]}}}},
                "objects": [], "lights": []}}"#,
                eye.x, eye.y, eye.z, target.x, target.y, target.z
            );
            let scene = parse(doc.as_bytes(), &Limits::NONE).expect("a camera");
            let cam = PrimaryRays::new(&scene);
            let (x, y) = ((corner.0 * f64::from(w)) as u32, (corner.1 * f64::from(h)) as u32);
            let block = Rect {
                x,
                y,
                width: size.0.min(w - x),
                height: size.1.min(h - y),
            };
            let r = cam.through(
                f64::from(block.x) + at.0 * f64::from(block.width),
                f64::from(block.y) + at.1 * f64::from(block.height),
            );
            let p = r.origin + t * r.dir;
            let b = cube(p, half * (p - r.origin).length().max(1e-300));
            proptest::prop_assert!(!cam.misses(block, &b), "{block:?} {b:?}");
        }
    }

    /// Where in a block a ray goes through, as a fraction of its width or height: its
    /// edges (the far one a hair inside) or anywhere between.
    fn edge_or_inside() -> impl Strategy<Value = f64> {
        prop_oneof![
            proptest::strategy::Just(0.0),
            proptest::strategy::Just(1.0 - 1e-15),
            0.0f64..1.0
        ]
    }

    #[test]
    fn behind_the_camera_is_cut_or_nothing() {
        let cam = camera(TILTED);
        let back = cam.through(20.0, 15.0);
        assert_eq!(cam.image_point(back.origin - back.dir), None);
        assert_eq!(
            cam.segment_on_image(back.origin - back.dir, -back.dir, 3.0),
            None
        );
        // From in front to behind: drawn from its start until it crosses the eye's plane.
        let start = back.origin + 2.0 * back.dir;
        let [a, b] = cam.segment_on_image(start, -back.dir, 10.0).unwrap();
        assert!((a - DVec2::new(20.0, 15.0)).length() < 1e-9);
        assert!(b.is_finite());
    }
}
