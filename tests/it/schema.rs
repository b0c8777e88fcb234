//! `api/scene.schema.json` and the Rust parser agree: every shipped scene passes both,
//! and documents that break the format fail both.

use raytile::scene::{Limits, parse};
use serde_json::{Value, json};

use crate::support::*;

fn schema() -> jsonschema::Validator {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("api/scene.schema.json");
    let schema: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    jsonschema::draft202012::new(&schema).expect("the scene schema is a valid JSON Schema 2020-12")
}

#[test]
fn every_shipped_scene_passes_the_schema_and_the_parser() {
    let v = schema();
    let mut n = 0;
    for entry in std::fs::read_dir(scene("")).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "json") {
            let bytes = std::fs::read(&p).unwrap();
            let doc: Value = serde_json::from_slice(&bytes).unwrap();
            let errors: Vec<String> = v
                .iter_errors(&doc)
                .map(|e| format!("{} at {}", e, e.instance_path()))
                .collect();
            assert!(errors.is_empty(), "{}: {errors:?}", p.display());
            assert!(parse(&bytes, &Limits::default()).is_ok(), "{}", p.display());
            n += 1;
        }
    }
    assert!(n >= 9, "expected the example scenes, found {n}");
}

/// A change that makes a document break the format.
type Edit = Box<dyn Fn(&mut Value)>;

#[test]
fn format_violations_fail_both() {
    let v = schema();
    let base = json!({"version": 1, "image": {"width": 4, "height": 4},
        "objects": [{"shape": "sphere"}], "lights": [{"type": "point", "position": [0, 0, 0], "colour": [1, 1, 1]}]});
    let cases: Vec<(&str, Edit)> = vec![
        (
            "unknown top-level field",
            Box::new(|d| d["extra"] = json!(1)),
        ),
        (
            "unknown object field",
            Box::new(|d| d["objects"][0]["colour"] = json!([1, 0, 0])),
        ),
        (
            "unknown shape",
            Box::new(|d| d["objects"][0]["shape"] = json!("teapot")),
        ),
        (
            "positions on a sphere",
            Box::new(|d| d["objects"][0]["positions"] = json!([[0, 0, 0]])),
        ),
        (
            "light without colour",
            Box::new(|d| d["lights"][0] = json!({"type": "point", "position": [0, 0, 0]})),
        ),
        (
            "two keys in a step",
            Box::new(|d| {
                d["objects"][0]["transform"] = json!([{"scale": 2, "translate": [0, 0, 1]}])
            }),
        ),
        (
            "zero scale",
            Box::new(|d| d["objects"][0]["transform"] = json!([{"scale": 0}])),
        ),
        (
            "missing image",
            Box::new(|d| {
                d.as_object_mut()
                    .map(|m| m.remove("image"))
                    .map_or((), |_| ())
            }),
        ),
        (
            "negative width",
            Box::new(|d| d["image"]["width"] = json!(-3)),
        ),
    ];
    for (what, edit) in cases {
        let mut d = base.clone();
        edit(&mut d);
        assert!(!v.is_valid(&d), "the schema accepts: {what}");
        assert!(
            parse(&serde_json::to_vec(&d).unwrap(), &Limits::default()).is_err(),
            "the parser accepts: {what}"
        );
    }
    assert!(
        v.is_valid(&base) && parse(&serde_json::to_vec(&base).unwrap(), &Limits::default()).is_ok()
    );
}
