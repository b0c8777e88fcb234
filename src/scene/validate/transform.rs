//! A `transform` list, of an object or of the camera: each step checked where it stands,
//! then composed in the listed order (see `docs/spec/transforms.md`).
//!
//! ```json
//! "transform": [ { "scale": 0.5 }, { "rotate": { "axis": "y", "degrees": 30 } },
//!                { "translate": [-1.5, 0.5, 0] } ]
//! ```

use glam::{DAffine3, DMat3, DVec3};

use super::{Problems, unit, vec3};
use crate::geometry::Transform;
use crate::scene::document::*;
use crate::scene::problem::Pointer;

/// Composes transform steps in the listed order.
pub(super) fn transform_of(steps: &[StepDoc], at: &Pointer, p: &mut Problems) -> Option<Transform> {
    let mut t = Transform::IDENTITY;
    let mut ok = true;
    for (k, step) in steps.iter().enumerate() {
        let at = at.index(k);
        let s = match step {
            StepDoc::Translate(v) => Some(Transform::translate(vec3(*v))),
            StepDoc::Scale(s) => {
                let v = match s {
                    ScaleDoc::Uniform(f) => DVec3::splat(*f),
                    ScaleDoc::Axes(a) => vec3(*a),
                };
                if v.cmpeq(DVec3::ZERO).any() {
                    p.add(&at.key("scale"), "a scale factor cannot be 0");
                    None
                } else {
                    Some(Transform::scale(v))
                }
            }
            StepDoc::Rotate(r) => {
                let axis = match r.axis {
                    AxisDoc::Named(AxisName::X) => Some(DVec3::X),
                    AxisDoc::Named(AxisName::Y) => Some(DVec3::Y),
                    AxisDoc::Named(AxisName::Z) => Some(DVec3::Z),
                    AxisDoc::Vector(v) => unit(vec3(v)),
                };
                match axis {
                    Some(a) => Some(Transform::rotate(a, r.degrees)),
                    None => {
                        p.add(
                            &at.key("rotate").key("axis"),
                            "the rotation axis has zero length",
                        );
                        None
                    }
                }
            }
            StepDoc::Matrix(rows) => {
                if rows[3] != [0.0, 0.0, 0.0, 1.0] {
                    p.add(
                        &at.key("matrix").index(3),
                        "the last row must be [0, 0, 0, 1]: only affine matrices are allowed",
                    );
                    None
                } else {
                    let m3 = DMat3::from_cols(
                        DVec3::new(rows[0][0], rows[1][0], rows[2][0]),
                        DVec3::new(rows[0][1], rows[1][1], rows[2][1]),
                        DVec3::new(rows[0][2], rows[1][2], rows[2][2]),
                    );
                    let m = DAffine3::from_mat3_translation(
                        m3,
                        DVec3::new(rows[0][3], rows[1][3], rows[2][3]),
                    );
                    let t = Transform::matrix(m);
                    if t.is_none() {
                        p.add(
                            &at.key("matrix"),
                            "the matrix is singular (determinant 0): it has no inverse",
                        );
                    }
                    t
                }
            }
        };
        match s {
            Some(s) => t = t.then(&s),
            None => ok = false,
        }
    }
    if ok && !t.is_finite() {
        p.add(
            at,
            "the composed transform overflows: its entries or its inverse's are not finite",
        );
        return None;
    }
    ok.then_some(t)
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn steps(v: serde_json::Value) -> Vec<StepDoc> {
        serde_json::from_value(v).expect("transform steps")
    }

    fn compose(v: serde_json::Value) -> (Option<Transform>, Vec<(String, String)>) {
        let mut p = Problems::default();
        let t = transform_of(&steps(v), &Pointer::root().key("transform"), &mut p);
        (t, p.pairs())
    }

    fn one(pointer: &str, message: &str) -> Vec<(String, String)> {
        vec![(pointer.into(), message.into())]
    }

    #[test]
    fn good_steps_compose_in_the_listed_order_without_a_problem() {
        let (t, found) = compose(json!([
            {"scale": 2},
            {"rotate": {"axis": "z", "degrees": 90}},
            {"translate": [1, 0, 2]},
            {"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}
        ]));
        assert_eq!(found, []);
        let t = t.expect("a transform");
        // Scale first: (1, 0, 0) → (2, 0, 0), then a quarter turn about z → (0, 2, 0),
        // then the translation.
        assert_eq!(
            t.forward.transform_point3(DVec3::X),
            DVec3::new(1.0, 2.0, 2.0)
        );
    }

    #[test]
    fn no_steps_is_the_identity() {
        assert_eq!(compose(json!([])), (Some(Transform::IDENTITY), vec![]));
    }

    #[test]
    fn a_zero_scale_factor_is_refused_at_the_step() {
        for scale in [json!(0), json!([1, 0, 1])] {
            assert_eq!(
                compose(json!([{"translate": [1, 2, 3]}, {"scale": scale}])),
                (
                    None,
                    one("/transform/1/scale", "a scale factor cannot be 0")
                )
            );
        }
    }

    #[test]
    fn a_zero_rotation_axis_is_refused_at_the_axis() {
        assert_eq!(
            compose(json!([{"rotate": {"axis": [0, 0, 0], "degrees": 30}}])),
            (
                None,
                one(
                    "/transform/0/rotate/axis",
                    "the rotation axis has zero length"
                )
            )
        );
    }

    #[test]
    fn a_vector_axis_need_not_be_unit_length() {
        let (t, found) = compose(json!([{"rotate": {"axis": [0, 0, 5], "degrees": 90}}]));
        assert_eq!(found, []);
        let moved = t.expect("a transform").forward.transform_point3(DVec3::X);
        assert!((moved - DVec3::Y).length() < 1e-15, "{moved}");
    }

    #[test]
    fn a_matrix_whose_last_row_is_not_0_0_0_1_is_refused_at_that_row() {
        assert_eq!(
            compose(json!([{"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}])),
            (
                None,
                one(
                    "/transform/0/matrix/3",
                    "the last row must be [0, 0, 0, 1]: only affine matrices are allowed"
                )
            )
        );
    }

    #[test]
    fn a_singular_matrix_is_refused_at_the_matrix() {
        assert_eq!(
            compose(json!([{"matrix": [[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}])),
            (
                None,
                one(
                    "/transform/0/matrix",
                    "the matrix is singular (determinant 0): it has no inverse"
                )
            )
        );
    }

    #[test]
    fn every_bad_step_is_reported() {
        let (t, found) = compose(json!([
            {"scale": 0},
            {"translate": [1, 1, 1]},
            {"rotate": {"axis": [0, 0, 0], "degrees": 1}}
        ]));
        assert!(t.is_none());
        let at: Vec<&str> = found.iter().map(|(at, _)| at.as_str()).collect();
        assert_eq!(at, ["/transform/0/scale", "/transform/2/rotate/axis"]);
    }

    #[test]
    fn a_composition_that_overflows_is_refused_at_the_list() {
        assert_eq!(
            compose(json!([{"scale": 1e200}, {"scale": 1e200}])),
            (
                None,
                one(
                    "/transform",
                    "the composed transform overflows: its entries or its inverse's are not finite"
                )
            )
        );
    }
}
