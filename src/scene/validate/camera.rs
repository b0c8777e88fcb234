//! `camera`: a positive focal length, and the camera placed by `transform` steps or by
//! `look_at`, never both (see `docs/spec/camera.md`).
//!
//! ```json
//! "camera": { "focal_length": 1.5,
//!             "look_at": { "eye": [0, 2, 6], "target": [0, 0.5, 0], "up": [0, 1, 0] } }
//! ```

use glam::{DAffine3, DMat3};

use super::transform::transform_of;
use super::{Problems, unit, vec3};
use crate::geometry::Transform;
use crate::scene::Camera;
use crate::scene::document::{CameraDoc, LookAtDoc};
use crate::scene::problem::Pointer;

/// Checks `camera` (at `at`; absent, it is the default camera at the origin with f = 1)
/// and places it, or `None` when its placement is at fault.
pub(super) fn check(cam: Option<&CameraDoc>, at: &Pointer, p: &mut Problems) -> Option<Camera> {
    let default = CameraDoc::default();
    let cam = cam.unwrap_or(&default);
    let focal_length = cam.focal_length.unwrap_or(1.0);
    if focal_length <= 0.0 {
        p.add(&at.key("focal_length"), "must be greater than 0");
    }
    let world_from_camera = match (&cam.transform, &cam.look_at) {
        (Some(_), Some(_)) => {
            p.add(at, "give either `transform` or `look_at`, not both");
            None
        }
        (Some(steps), None) => transform_of(steps, &at.key("transform"), p),
        (None, Some(la)) => look_at(la, &at.key("look_at"), p),
        (None, None) => Some(Transform::IDENTITY),
    };
    Some(Camera {
        world_from_camera: world_from_camera?,
        focal_length,
    })
}

/// camera z from eye to target, camera y along −up made orthogonal to z, x = y × z.
fn look_at(la: &LookAtDoc, at: &Pointer, p: &mut Problems) -> Option<Transform> {
    let (eye, target, up) = (vec3(la.eye), vec3(la.target), vec3(la.up));
    let Some(z) = unit(target - eye) else {
        p.add(
            &at.key("target"),
            "the target is the eye: there is no view direction",
        );
        return None;
    };
    let Some(up_dir) = unit(up) else {
        p.add(&at.key("up"), "the up vector has zero length");
        return None;
    };
    let ortho = up_dir - up_dir.dot(z) * z;
    if ortho.length() < 1e-9 {
        p.add(
            &at.key("up"),
            "the up vector is parallel to the view direction",
        );
        return None;
    }
    let y = -ortho.normalize();
    let x = y.cross(z);
    let m = DAffine3::from_mat3_translation(DMat3::from_cols(x, y, z), eye);
    // The inverse of a rotation is its transpose: exact, no general inversion.
    let rt = DMat3::from_cols(x, y, z).transpose();
    let inverse = DAffine3::from_mat3_translation(rt, -(rt * eye));
    let t = Transform {
        forward: m,
        inverse,
    };
    if !t.is_finite() {
        p.add(at, "the camera placement overflows");
        return None;
    }
    Some(t)
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use serde_json::json;

    use super::*;

    fn camera(v: serde_json::Value) -> (Option<Camera>, Vec<(String, String)>) {
        let doc: CameraDoc = serde_json::from_value(v).expect("a camera");
        let mut p = Problems::default();
        let cam = check(Some(&doc), &Pointer::root().key("camera"), &mut p);
        (cam, p.pairs())
    }

    fn one(pointer: &str, message: &str) -> Vec<(String, String)> {
        vec![(pointer.into(), message.into())]
    }

    #[test]
    fn no_camera_is_at_the_origin_looking_along_z_with_f_1() {
        let mut p = Problems::default();
        let cam = check(None, &Pointer::root().key("camera"), &mut p);
        assert_eq!(p.pairs(), []);
        assert_eq!(
            cam,
            Some(Camera {
                world_from_camera: Transform::IDENTITY,
                focal_length: 1.0
            })
        );
    }

    #[test]
    fn a_camera_placed_by_steps_has_no_problem() {
        let (cam, found) =
            camera(json!({"focal_length": 2, "transform": [{"translate": [0, 0, -4]}]}));
        assert_eq!(found, []);
        let cam = cam.expect("a camera");
        assert_eq!(cam.focal_length, 2.0);
        assert_eq!(
            cam.world_from_camera.forward.transform_point3(DVec3::ZERO),
            DVec3::new(0.0, 0.0, -4.0)
        );
    }

    #[test]
    fn the_focal_length_must_be_greater_than_0() {
        for f in [0.0, -1.0] {
            assert_eq!(
                camera(json!({"focal_length": f})).1,
                one("/camera/focal_length", "must be greater than 0")
            );
        }
    }

    #[test]
    fn transform_and_look_at_together_are_a_problem_of_the_camera() {
        assert_eq!(
            camera(json!({
                "transform": [],
                "look_at": {"eye": [0, 0, 0], "target": [0, 0, 1], "up": [0, 1, 0]}
            })),
            (
                None,
                one("/camera", "give either `transform` or `look_at`, not both")
            )
        );
    }

    #[test]
    fn a_bad_transform_step_is_reported_under_the_camera() {
        assert_eq!(
            camera(json!({"transform": [{"scale": 0}]})),
            (
                None,
                one("/camera/transform/0/scale", "a scale factor cannot be 0")
            )
        );
    }

    #[test]
    fn look_at_gives_z_toward_the_target_and_y_along_minus_up() {
        let (cam, found) = camera(json!({
            "look_at": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0]}
        }));
        assert_eq!(found, []);
        let t = cam.expect("a camera").world_from_camera;
        assert_eq!(
            t.forward.transform_point3(DVec3::ZERO),
            DVec3::new(0.0, 0.0, 5.0)
        );
        assert_eq!(t.forward.transform_vector3(DVec3::Z), DVec3::NEG_Z);
        assert_eq!(t.forward.transform_vector3(DVec3::Y), DVec3::NEG_Y);
        // x = y × z = (0, −1, 0) × (0, 0, −1) = (1, 0, 0).
        assert_eq!(t.forward.transform_vector3(DVec3::X), DVec3::X);
        assert_eq!(
            t.inverse.transform_point3(DVec3::new(0.0, 0.0, 5.0)),
            DVec3::ZERO
        );
    }

    #[test]
    fn look_at_at_its_own_eye_has_no_view_direction() {
        assert_eq!(
            camera(json!({"look_at": {"eye": [1, 2, 3], "target": [1, 2, 3], "up": [0, 1, 0]}})),
            (
                None,
                one(
                    "/camera/look_at/target",
                    "the target is the eye: there is no view direction"
                )
            )
        );
    }

    #[test]
    fn look_at_with_a_zero_up_vector() {
        assert_eq!(
            camera(json!({"look_at": {"eye": [0, 0, 0], "target": [0, 0, 1], "up": [0, 0, 0]}})),
            (
                None,
                one("/camera/look_at/up", "the up vector has zero length")
            )
        );
    }

    #[test]
    fn look_at_with_up_parallel_to_the_view() {
        assert_eq!(
            camera(json!({"look_at": {"eye": [0, 0, 0], "target": [0, 3, 0], "up": [0, -2, 0]}})),
            (
                None,
                one(
                    "/camera/look_at/up",
                    "the up vector is parallel to the view direction"
                )
            )
        );
    }

    #[test]
    fn look_at_that_overflows_is_a_problem_of_the_look_at() {
        assert_eq!(
            camera(
                json!({"look_at": {"eye": [1.5e308, 1.5e308, 0], "target": [0, 0, 0], "up": [0, 0, 1]}})
            ),
            (
                None,
                one("/camera/look_at", "the camera placement overflows")
            )
        );
    }
}
