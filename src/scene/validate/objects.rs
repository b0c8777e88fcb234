//! `objects`: at most the limit of objects and of mesh triangles, unique names, and for
//! each object its material, its `transform` and its shape.
//!
//! ```json
//! "objects": [ { "name": "ball", "shape": "sphere", "material": "red",
//!                "transform": [ { "translate": [0, 1, 0] } ] } ]
//! ```

use std::collections::{HashMap, HashSet};

use super::Problems;
use super::materials::Materials;
use super::shape::shape;
use super::transform::transform_of;
use crate::geometry::{Shape, Transform};
use crate::scene::document::ObjectDoc;
use crate::scene::problem::Pointer;
use crate::scene::{Limits, Object};

/// Checks `objects` (at `at`), skipping those that could not be read (`unreadable`),
/// and returns those that passed, in document order.
pub(super) fn check(
    docs: &[ObjectDoc],
    unreadable: &HashSet<usize>,
    materials: &mut Materials,
    at: &Pointer,
    limits: &Limits,
    p: &mut Problems,
) -> Vec<Object> {
    if docs.len() as u64 > limits.max_objects {
        p.add(
            at,
            format!(
                "{} objects is more than the limit of {}",
                docs.len(),
                limits.max_objects
            ),
        );
    }
    let mut names: HashMap<&str, usize> = HashMap::new();
    let mut objects = Vec::with_capacity(docs.len());
    let mut triangles = 0u64;
    for (i, o) in docs.iter().enumerate() {
        if unreadable.contains(&i) {
            continue;
        }
        let at = at.index(i);
        if let Some(name) = &o.name
            && let Some(first) = names.insert(name, i)
        {
            p.add(
                &at.key("name"),
                format!("duplicate name `{name}`, already used by /objects/{first}"),
            );
            // The first use keeps the name, so that a third use points at it too.
            names.insert(name, first);
        }
        let material = materials.of_object(o.material.as_ref(), &at.key("material"), p);
        let transform = match &o.transform {
            Some(steps) => transform_of(steps, &at.key("transform"), p),
            None => Some(Transform::IDENTITY),
        };
        let shape = shape(o, &at, p);
        if let Some(Shape::Mesh(m)) = &shape {
            triangles += m.indices.len() as u64;
        }
        if let (Some(shape), Some(transform), Some(material)) = (shape, transform, material) {
            objects.push(Object {
                name: o.name.clone(),
                shape,
                transform,
                material,
            });
        }
    }
    if triangles > limits.max_triangles {
        p.add(
            at,
            format!(
                "{triangles} triangles is more than the limit of {}",
                limits.max_triangles
            ),
        );
    }
    objects
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use serde_json::json;

    use super::*;
    use crate::scene::document::MaterialDoc;

    fn objects(v: serde_json::Value) -> Vec<ObjectDoc> {
        serde_json::from_value(v).expect("objects")
    }

    /// Checks `docs` against a `materials` map holding only `red`.
    fn check_all(
        docs: &[ObjectDoc],
        unreadable: &HashSet<usize>,
        limits: &Limits,
    ) -> (Vec<Object>, Vec<(String, String)>) {
        let named: BTreeMap<String, MaterialDoc> =
            serde_json::from_value(json!({"red": {"diffuse": [1, 0, 0]}})).expect("materials");
        let mut p = Problems::default();
        let mut m = Materials::check(&named, false, &Pointer::root().key("materials"), &mut p);
        let out = check(
            docs,
            unreadable,
            &mut m,
            &Pointer::root().key("objects"),
            limits,
            &mut p,
        );
        (out, p.pairs())
    }

    #[test]
    fn good_objects_have_no_problem_and_keep_their_order() {
        let docs = objects(json!([
            {"name": "a", "shape": "sphere", "material": "red"},
            {"shape": "cube", "transform": [{"translate": [1, 0, 0]}]},
            {"name": "b", "shape": "plane", "material": {"diffuse": [0, 1, 0]}}
        ]));
        let (out, found) = check_all(&docs, &HashSet::new(), &Limits::default());
        assert_eq!(found, []);
        let names: Vec<Option<&str>> = out.iter().map(|o| o.name.as_deref()).collect();
        assert_eq!(names, [Some("a"), None, Some("b")]);
        // `red` is material 0; the default is added for the cube, the inline one after.
        let materials: Vec<u32> = out.iter().map(|o| o.material).collect();
        assert_eq!(materials, [0, 1, 2]);
        assert_eq!(out[0].transform, Transform::IDENTITY);
    }

    #[test]
    fn a_duplicate_name_points_at_its_first_use() {
        let docs = objects(json!([
            {"name": "a", "shape": "sphere"},
            {"name": "a", "shape": "sphere"},
            {"name": "a", "shape": "sphere"}
        ]));
        let (_, found) = check_all(&docs, &HashSet::new(), &Limits::default());
        assert_eq!(
            found,
            [
                (
                    "/objects/1/name".into(),
                    "duplicate name `a`, already used by /objects/0".into()
                ),
                (
                    "/objects/2/name".into(),
                    "duplicate name `a`, already used by /objects/0".into()
                ),
            ]
        );
    }

    #[test]
    fn each_part_of_an_object_is_checked_in_field_order() {
        let docs = objects(json!([
            {"shape": "sphere"},
            {"shape": "mesh", "material": "blue", "transform": [{"scale": 0}]}
        ]));
        let (out, found) = check_all(&docs, &HashSet::new(), &Limits::default());
        assert_eq!(out.len(), 1, "the good object is still built");
        assert_eq!(
            found,
            [
                (
                    "/objects/1/material".into(),
                    "no material named `blue` in /materials".into()
                ),
                (
                    "/objects/1/transform/0/scale".into(),
                    "a scale factor cannot be 0".into()
                ),
                ("/objects/1".into(), "a mesh needs `positions`".into()),
                ("/objects/1".into(), "a mesh needs `indices`".into()),
            ]
        );
    }

    #[test]
    fn objects_that_could_not_be_read_are_skipped_but_keep_their_index() {
        let docs = objects(json!([
            {"name": "a", "shape": "sphere", "material": "nowhere"},
            {"name": "a", "shape": "sphere", "material": "nowhere"}
        ]));
        let (out, found) = check_all(&docs, &HashSet::from([0]), &Limits::default());
        assert!(out.is_empty());
        assert_eq!(
            found,
            [(
                "/objects/1/material".into(),
                "no material named `nowhere` in /materials".into()
            )]
        );
    }

    #[test]
    fn more_objects_than_the_limit_is_a_problem_of_the_list() {
        let docs = objects(json!([{"shape": "sphere"}, {"shape": "cube"}]));
        let limits = Limits {
            max_objects: 1,
            ..Limits::default()
        };
        assert_eq!(
            check_all(&docs, &HashSet::new(), &limits).1,
            [(
                "/objects".into(),
                "2 objects is more than the limit of 1".into()
            )]
        );
    }

    #[test]
    fn mesh_triangles_are_counted_over_every_mesh_against_the_limit() {
        let mesh = json!({
            "shape": "mesh",
            "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
            "indices": [[0, 1, 2], [0, 2, 1]]
        });
        let docs = objects(json!([mesh, {"shape": "sphere"}, mesh]));
        let limits = Limits {
            max_triangles: 3,
            ..Limits::default()
        };
        assert_eq!(
            check_all(&docs, &HashSet::new(), &limits).1,
            [(
                "/objects".into(),
                "4 triangles is more than the limit of 3".into()
            )]
        );
        let limits = Limits {
            max_triangles: 4,
            ..Limits::default()
        };
        assert_eq!(check_all(&docs, &HashSet::new(), &limits).1, []);
    }
}
