//! An object's `shape`: the canonical shape it names, and for a mesh its inline
//! `positions` and `indices` (see `docs/spec/shapes.md`), which no other shape may have.
//!
//! ```json
//! { "shape": "mesh", "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "indices": [[0, 1, 2]] }
//! ```

use std::sync::Arc;

use super::{Problems, vec3};
use crate::geometry::{Mesh, NeedsData, Shape};
use crate::scene::document::ObjectDoc;
use crate::scene::problem::Pointer;

/// The shape of object `o` (at `at`), or `None` when it is at fault.
pub(super) fn shape(o: &ObjectDoc, at: &Pointer, p: &mut Problems) -> Option<Shape> {
    let s = match Shape::plain(o.shape) {
        Ok(s) => s,
        Err(NeedsData::Mesh) => {
            let (Some(positions), Some(indices)) = (&o.positions, &o.indices) else {
                for (k, present) in [
                    ("positions", o.positions.is_some()),
                    ("indices", o.indices.is_some()),
                ] {
                    if !present {
                        p.add(at, format!("a mesh needs `{k}`"));
                    }
                }
                return None;
            };
            let n = positions.len();
            let mut ok = true;
            for (t, tri) in indices.iter().enumerate() {
                for (k, &i) in tri.iter().enumerate() {
                    if i as usize >= n {
                        p.add(
                            &at.key("indices").index(t).index(k),
                            format!("index {i} is out of range: `positions` has {n} entries"),
                        );
                        ok = false;
                    }
                }
            }
            if !ok {
                return None;
            }
            return Some(Shape::Mesh(Arc::new(Mesh::new(
                positions.iter().map(|&v| vec3(v)).collect(),
                indices.clone(),
            ))));
        }
    };
    for (k, present) in [
        ("positions", o.positions.is_some()),
        ("indices", o.indices.is_some()),
    ] {
        if present {
            p.add(&at.key(k), format!("only a mesh has `{k}`"));
        }
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn check(v: serde_json::Value) -> (Option<Shape>, Vec<(String, String)>) {
        let o: ObjectDoc = serde_json::from_value(v).expect("an object");
        let mut p = Problems::default();
        let s = shape(&o, &Pointer::root().key("objects").index(3), &mut p);
        (s, p.pairs())
    }

    #[test]
    fn every_canonical_shape_is_accepted_without_a_problem() {
        for name in ["sphere", "cube", "plane", "disk", "cylinder", "cone"] {
            let (s, found) = check(json!({ "shape": name }));
            assert!(s.is_some(), "{name}");
            assert_eq!(found, [], "{name}");
        }
    }

    #[test]
    fn a_good_mesh_keeps_its_positions_and_triangles() {
        let (s, found) = check(json!({
            "shape": "mesh",
            "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
            "indices": [[0, 1, 2], [2, 1, 0]]
        }));
        assert_eq!(found, []);
        let Some(Shape::Mesh(m)) = s else {
            panic!("a mesh, got {s:?}")
        };
        assert_eq!(m.positions.len(), 3);
        assert_eq!(m.indices, [[0, 1, 2], [2, 1, 0]]);
    }

    #[test]
    fn a_mesh_without_its_lists_names_each_missing_one_at_the_object() {
        assert_eq!(
            check(json!({"shape": "mesh"})).1,
            [
                ("/objects/3".into(), "a mesh needs `positions`".into()),
                ("/objects/3".into(), "a mesh needs `indices`".into()),
            ]
        );
        assert_eq!(
            check(json!({"shape": "mesh", "positions": []})).1,
            [("/objects/3".into(), "a mesh needs `indices`".into())]
        );
    }

    #[test]
    fn each_index_out_of_range_is_reported_at_its_place() {
        let (s, found) = check(json!({
            "shape": "mesh",
            "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
            "indices": [[0, 1, 2], [3, 1, 7]]
        }));
        assert!(s.is_none());
        assert_eq!(
            found,
            [
                (
                    "/objects/3/indices/1/0".into(),
                    "index 3 is out of range: `positions` has 3 entries".into()
                ),
                (
                    "/objects/3/indices/1/2".into(),
                    "index 7 is out of range: `positions` has 3 entries".into()
                ),
            ]
        );
    }

    #[test]
    fn only_a_mesh_has_positions_or_indices() {
        let (s, found) = check(json!({"shape": "sphere", "positions": [], "indices": []}));
        assert!(s.is_some(), "the shape itself is still known");
        assert_eq!(
            found,
            [
                (
                    "/objects/3/positions".into(),
                    "only a mesh has `positions`".into()
                ),
                (
                    "/objects/3/indices".into(),
                    "only a mesh has `indices`".into()
                ),
            ]
        );
    }
}
