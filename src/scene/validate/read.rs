//! The slow path: a document that did not deserialise in one go is read part by part
//! from its JSON tree, so that one bad object does not hide the problems of the next.
//! A part that cannot be read leaves a stand-in (so later indices keep their pointers)
//! and is marked in [`Failed`], whose checks are then skipped.

use std::collections::{BTreeMap, HashSet};

use serde::de::DeserializeOwned;
use serde_json::Value;

use super::Problems;
use crate::json::strip_position;
use crate::scene::document::*;
use crate::scene::problem::Pointer;

/// The top-level fields, in the order they are read.
const TOP_LEVEL: [&str; 9] = [
    "version",
    "image",
    "camera",
    "background",
    "ambient",
    "max_depth",
    "materials",
    "objects",
    "lights",
];

fn take<T: DeserializeOwned>(v: Value, at: &Pointer, p: &mut Problems) -> Option<T> {
    match serde_path_to_error::deserialize::<_, T>(v) {
        Ok(t) => Some(t),
        Err(e) => {
            p.add(
                &at.join_path(e.path()),
                strip_position(&e.inner().to_string()),
            );
            None
        }
    }
}

/// Reads each element of a list on its own; a bad element leaves `placeholder` in its
/// place (so later indices keep their pointers) and its index in `failed`.
fn take_list<T: DeserializeOwned>(
    v: Value,
    at: &Pointer,
    p: &mut Problems,
    placeholder: impl Fn() -> T,
    failed: &mut HashSet<usize>,
) -> Vec<T> {
    match v {
        Value::Array(items) => items
            .into_iter()
            .enumerate()
            .map(|(i, v)| {
                take(v, &at.index(i), p).unwrap_or_else(|| {
                    failed.insert(i);
                    placeholder()
                })
            })
            .collect(),
        other => take(other, at, p).unwrap_or_default(),
    }
}

/// The parts of a document that could not be read: their checks are skipped, so that
/// the problems reported are the real ones and not their consequences.
#[derive(Default)]
pub(super) struct Failed {
    /// Some material (or the whole map) could not be read, so an unknown material name
    /// may be that material's and is not reported.
    pub(super) materials: bool,
    /// Indices of the objects that could not be read.
    pub(super) objects: HashSet<usize>,
    /// Indices of the lights that could not be read.
    pub(super) lights: HashSet<usize>,
}

/// Reads every part of the document it can, reporting each part that it cannot.
pub(super) fn read_document(value: Value, p: &mut Problems) -> Option<(SceneDoc, Failed)> {
    let root = Pointer::root();
    let Value::Object(mut map) = value else {
        p.add(&root, "a scene must be a JSON object");
        return None;
    };
    for key in map.keys() {
        if !TOP_LEVEL.contains(&key.as_str()) {
            p.add(
                &root.key(key),
                format!(
                    "unknown field `{key}`, expected one of {}",
                    TOP_LEVEL.map(|k| format!("`{k}`")).join(", ")
                ),
            );
        }
    }
    let mut failed = Failed::default();
    let mut required = |p: &mut Problems, k: &str| {
        let v = map.remove(k);
        if v.is_none() {
            p.add(&root, format!("missing field `{k}`"));
        }
        v
    };
    let version = required(p, "version")
        .and_then(|v| take::<Integer>(v, &root.key("version"), p).map(u32::from))
        .unwrap_or(1);
    let image = required(p, "image").and_then(|v| take::<ImageDoc>(v, &root.key("image"), p));
    let image = image.unwrap_or(ImageDoc {
        width: 1,
        height: 1,
        samples: None,
        gamma: None,
    });
    let objects = required(p, "objects");
    let mut optional = |k: &str| map.remove(k);
    let camera = optional("camera").and_then(|v| take::<CameraDoc>(v, &root.key("camera"), p));
    let background =
        optional("background").and_then(|v| take::<Colour>(v, &root.key("background"), p));
    let ambient = optional("ambient").and_then(|v| take::<Colour>(v, &root.key("ambient"), p));
    let max_depth = optional("max_depth")
        .and_then(|v| take::<Integer>(v, &root.key("max_depth"), p).map(u32::from));
    let materials = match optional("materials") {
        None => BTreeMap::new(),
        Some(Value::Object(m)) => {
            let at = root.key("materials");
            m.into_iter()
                .map(|(k, v)| {
                    let m = take(v, &at.key(&k), p).unwrap_or_else(|| {
                        failed.materials = true;
                        MaterialDoc::default()
                    });
                    (k, m)
                })
                .collect()
        }
        Some(other) => {
            failed.materials = true;
            take(other, &root.key("materials"), p).unwrap_or_default()
        }
    };
    let lights = optional("lights").map_or_else(Vec::new, |v| {
        take_list(
            v,
            &root.key("lights"),
            p,
            || LightDoc::Point {
                position: [0.0; 3],
                colour: [0.0; 3],
            },
            &mut failed.lights,
        )
    });
    let objects = objects.map_or_else(Vec::new, |v| {
        take_list(
            v,
            &root.key("objects"),
            p,
            || ObjectDoc {
                name: None,
                shape: ShapeName::Sphere,
                material: None,
                transform: None,
                positions: None,
                indices: None,
            },
            &mut failed.objects,
        )
    });
    let doc = SceneDoc {
        version,
        image,
        camera,
        background,
        ambient,
        max_depth,
        materials,
        objects,
        lights,
    };
    Some((doc, failed))
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    /// What was read, and the problems as `(pointer, message)` pairs.
    type Read = (Option<(SceneDoc, Failed)>, Vec<(String, String)>);

    fn read(v: Value) -> Read {
        let mut p = Problems::default();
        let doc = read_document(v, &mut p);
        (doc, p.pairs())
    }

    fn minimal() -> Value {
        json!({"version": 1, "image": {"width": 2, "height": 1}, "objects": []})
    }

    #[test]
    fn a_minimal_document_reads_without_problems() {
        let (doc, problems) = read(minimal());
        assert_eq!(problems, []);
        let (doc, failed) = doc.expect("a document");
        assert_eq!((doc.image.width, doc.image.height), (2, 1));
        assert!(!failed.materials && failed.objects.is_empty() && failed.lights.is_empty());
    }

    #[test]
    fn a_document_that_is_not_an_object_is_one_problem_at_the_root() {
        let (doc, problems) = read(json!([1, 2]));
        assert!(doc.is_none());
        assert_eq!(
            problems,
            [("".into(), "a scene must be a JSON object".into())]
        );
    }

    #[test]
    fn an_unknown_top_level_field_is_named_with_the_fields_expected() {
        let mut v = minimal();
        v["colour"] = json!([1, 1, 1]);
        let (_, problems) = read(v);
        assert_eq!(
            problems,
            [(
                "/colour".into(),
                "unknown field `colour`, expected one of `version`, `image`, `camera`, \
                 `background`, `ambient`, `max_depth`, `materials`, `objects`, `lights`"
                    .into()
            )]
        );
    }

    #[test]
    fn missing_required_fields_are_reported_at_the_root_in_reading_order() {
        let (doc, problems) = read(json!({}));
        assert!(doc.is_some(), "the rest of the document is still checked");
        assert_eq!(
            problems,
            [
                ("".into(), "missing field `version`".into()),
                ("".into(), "missing field `image`".into()),
                ("".into(), "missing field `objects`".into()),
            ]
        );
    }

    #[test]
    fn a_bad_field_is_reported_at_its_own_pointer_without_the_serde_position() {
        let mut v = minimal();
        v["image"]["width"] = json!("wide");
        let (_, problems) = read(v);
        assert_eq!(
            problems,
            [(
                "/image/width".into(),
                "invalid type: string \"wide\", expected u32".into()
            )]
        );
    }

    #[test]
    fn a_bad_object_keeps_its_index_and_the_next_objects_are_still_read() {
        let mut v = minimal();
        v["objects"] = json!([{"shape": "teapot"}, {"shape": "cube"}]);
        let (doc, problems) = read(v);
        let (doc, failed) = doc.expect("a document");
        // The list of shapes the message goes on with grows with the shapes.
        assert_eq!(problems.len(), 1);
        assert_eq!(problems[0].0, "/objects/0/shape");
        assert!(
            problems[0]
                .1
                .starts_with("unknown variant `teapot`, expected one of `sphere`"),
            "{}",
            problems[0].1
        );
        assert_eq!(doc.objects.len(), 2);
        assert_eq!(doc.objects[1].shape, ShapeName::Cube);
        assert_eq!(failed.objects, HashSet::from([0]));
    }

    #[test]
    fn a_bad_light_keeps_its_index() {
        let mut v = minimal();
        v["lights"] = json!([
            {"type": "point", "position": [0, 0, 0], "colour": [1, 1, 1]},
            {"type": "laser"}
        ]);
        let (doc, problems) = read(v);
        let (doc, failed) = doc.expect("a document");
        assert_eq!(
            problems,
            [(
                "/lights/1/type".into(),
                "unknown variant `laser`, expected one of `point`, `directional`, `spot`".into()
            )]
        );
        assert_eq!(doc.lights.len(), 2);
        assert_eq!(failed.lights, HashSet::from([1]));
    }

    #[test]
    fn a_bad_material_marks_the_materials_failed() {
        let mut v = minimal();
        v["materials"] = json!({"red": {"diffuse": [1, 0, 0]}, "odd": {"glow": 1}});
        let (doc, problems) = read(v);
        let (doc, failed) = doc.expect("a document");
        assert_eq!(
            problems,
            [("/materials/odd/glow".into(), "unknown field `glow`, expected one of `ambient`, `diffuse`, `specular`, `shininess`, `mirror`, `transmission`, `ior`".into())]
        );
        assert!(failed.materials);
        assert_eq!(doc.materials.len(), 2);
    }

    #[test]
    fn materials_that_are_not_a_map_mark_the_materials_failed() {
        let mut v = minimal();
        v["materials"] = json!([]);
        let (doc, problems) = read(v);
        assert_eq!(
            problems,
            [(
                "/materials".into(),
                "invalid type: sequence, expected a map".into()
            )]
        );
        assert!(doc.expect("a document").1.materials);
    }
}
