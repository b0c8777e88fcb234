//! Shapes placed by transforms, against answers computed by hand.

use glam::DVec3;
use raytile::geometry::{Face, Ray, Shape, Transform, World};
use raytile::render::Renderer;
use raytile::scene::{Limits, parse};
use std::sync::Arc;

fn world(shape: Shape, t: Transform) -> World {
    World::new([(&shape, &t)])
}

fn close(a: DVec3, b: DVec3) -> bool {
    (a - b).length() < 1e-12
}

#[test]
fn non_uniform_scale_uses_inverse_transpose_normals() {
    // Ellipsoid with semi-axes (2, 1, 1) centred at z = 5.
    let t = Transform::scale(DVec3::new(2.0, 1.0, 1.0))
        .then(&Transform::translate(DVec3::new(0.0, 0.0, 5.0)));
    let w = world(Shape::Sphere, t);
    // A ray from (4, 0, 5−√0.5) toward −x meets x = √2·… at the point (√2, 0, 5 − √0.5).
    let p = DVec3::new(2f64.sqrt(), 0.0, 5.0 - 0.5f64.sqrt());
    let ray = Ray::new(DVec3::new(4.0, 0.0, p.z), DVec3::new(-1.0, 0.0, 0.0));
    let h = w.closest(&ray, 1e-9, f64::INFINITY).unwrap();
    let s = w.surface(&ray, &h);
    assert!((s.lambda - (4.0 - p.x)).abs() < 1e-12);
    // Gradient of (x/2)² + y² + (z−5)²: (x/4·2, 2y, 2(z−5)) ∝ (x/4, y, z − 5).
    let n = DVec3::new(p.x / 4.0, 0.0, p.z - 5.0).normalize();
    assert!(close(s.normal, n), "{} vs {n}", s.normal);
}

#[test]
fn rotated_cube_reports_the_rotated_face() {
    // Cube rotated 30° about y, at z = 5: the ray along +z meets its −z face.
    let t =
        Transform::rotate(DVec3::Y, 30.0).then(&Transform::translate(DVec3::new(0.0, 0.0, 5.0)));
    let w = world(Shape::Cube, t);
    let ray = Ray::new(DVec3::ZERO, DVec3::Z);
    let s = w.surface(&ray, &w.closest(&ray, 1e-9, f64::INFINITY).unwrap());
    assert_eq!(s.face, Some(Face::NegZ));
    // Face −z of the object is at distance 1 along the rotated −z axis: λ = 5 − 1/cos 30°.
    assert!((s.lambda - (5.0 - 1.0 / 30f64.to_radians().cos())).abs() < 1e-12);
    let n = DVec3::new(
        -(30f64.to_radians().sin()),
        0.0,
        -(30f64.to_radians().cos()),
    );
    assert!(close(s.normal, n), "{}", s.normal);
}

#[test]
fn ray_from_inside_a_closed_shape_reports_outward_normal() {
    let w = world(Shape::Sphere, Transform::scale(DVec3::splat(3.0)));
    let ray = Ray::new(DVec3::ZERO, DVec3::new(0.0, 0.0, 2.0));
    let s = w.surface(&ray, &w.closest(&ray, 1e-9, f64::INFINITY).unwrap());
    assert_eq!(s.lambda, 1.5);
    assert_eq!(s.normal, DVec3::Z);
    assert!(!s.front);
}

#[test]
fn open_surfaces_face_the_ray_origin() {
    let w = world(Shape::Plane, Transform::IDENTITY);
    let from_below = Ray::new(DVec3::new(0.0, -2.0, 0.0), DVec3::Y);
    let s = w.surface(
        &from_below,
        &w.closest(&from_below, 1e-9, f64::INFINITY).unwrap(),
    );
    assert_eq!(s.normal, DVec3::NEG_Y);
    let disk = world(Shape::Disk, Transform::rotate(DVec3::X, 90.0));
    // Rotated 90° about x, the disk lies in z = 0 with normal +z.
    let r = Ray::new(DVec3::new(0.2, 0.2, 3.0), DVec3::NEG_Z);
    let s = disk.surface(&r, &disk.closest(&r, 1e-9, f64::INFINITY).unwrap());
    assert_eq!((s.lambda, s.normal), (3.0, DVec3::Z));
}

#[test]
fn tangent_rays_hit_once() {
    let w = world(
        Shape::Sphere,
        Transform::translate(DVec3::new(0.0, 1.0, 5.0)),
    );
    let ray = Ray::new(DVec3::ZERO, DVec3::Z);
    let h = w.closest(&ray, 1e-9, f64::INFINITY).unwrap();
    assert_eq!(h.lambda, 5.0);
}

#[test]
fn cylinder_and_cone_under_transforms() {
    // A cylinder of radius 2 lying along x (rotated 90° about z), at z = 10.
    let t = Transform::scale(DVec3::new(2.0, 1.0, 2.0))
        .then(&Transform::rotate(DVec3::Z, 90.0))
        .then(&Transform::translate(DVec3::new(0.0, 0.0, 10.0)));
    let w = world(Shape::Cylinder, t);
    let ray = Ray::new(DVec3::ZERO, DVec3::Z);
    let s = w.surface(&ray, &w.closest(&ray, 1e-9, f64::INFINITY).unwrap());
    assert_eq!(s.lambda, 8.0);
    assert!(close(s.normal, DVec3::NEG_Z));
    // Along its axis the ray meets a cap.
    let along = Ray::new(DVec3::new(-5.0, 0.0, 10.0), DVec3::X);
    let s = w.surface(&along, &w.closest(&along, 1e-9, f64::INFINITY).unwrap());
    assert_eq!(s.lambda, 4.0);
    assert!(close(s.normal, DVec3::NEG_X));

    let cone = world(Shape::Cone, Transform::translate(DVec3::new(0.0, 0.0, 4.0)));
    let r = Ray::new(DVec3::new(0.0, -0.5, 0.0), DVec3::Z);
    // At y = −0.5 the radius is 0.75.
    assert_eq!(cone.closest(&r, 1e-9, f64::INFINITY).unwrap().lambda, 3.25);
}

#[test]
fn ties_go_to_the_object_listed_first() {
    let a = Shape::Cube;
    let ta = Transform::translate(DVec3::new(0.0, 0.0, 5.0));
    let b = Shape::Sphere;
    let tb = Transform::translate(DVec3::new(0.0, 0.0, 5.0));
    // Both are first met at z = 4.
    let w = World::new([(&b, &tb), (&a, &ta)]);
    let ray = Ray::new(DVec3::ZERO, DVec3::Z);
    assert_eq!(w.closest(&ray, 1e-9, f64::INFINITY).unwrap().object, 0);
    let w = World::new([(&a, &ta), (&b, &tb)]);
    assert_eq!(w.closest(&ray, 1e-9, f64::INFINITY).unwrap().object, 0);
}

#[test]
fn look_at_camera_puts_the_target_at_the_centre() {
    let doc = serde_json::json!({
        "version": 1, "image": {"width": 3, "height": 3},
        "camera": {"look_at": {"eye": [0, 0, -5], "target": [0, 0, 0], "up": [0, 1, 0]}},
        "objects": [{"shape": "sphere"}, {"shape": "sphere", "transform": [{"scale": 0.3}, {"translate": [-2, 2, -2]}]}]
    });
    let scene = parse(&serde_json::to_vec(&doc).unwrap(), &Limits::default()).unwrap();
    let r = Renderer::new(Arc::new(scene));
    let s = r.pixel_hit(1, 1).unwrap();
    assert_eq!(s.lambda, 4.0);
    assert!(close(s.normal, DVec3::NEG_Z));
    // Camera y is −up and x = y × z: world −x is image right, so the small sphere at
    // world (−2, +2, −2) appears top right.
    let corner = r
        .pixel_hit(2, 0)
        .expect("top-right pixel sees the small sphere");
    assert_eq!(corner.object, 1);
    assert!(r.pixel_hit(0, 0).is_none());
}
