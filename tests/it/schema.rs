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

fn both(v: &jsonschema::Validator, d: &Value) -> (bool, bool) {
    let parsed = parse(&serde_json::to_vec(d).unwrap(), &Limits::default());
    (v.is_valid(d), parsed.is_ok())
}

fn base_with_mesh() -> Value {
    json!({"version": 1, "image": {"width": 4, "height": 4},
        "objects": [{"shape": "sphere"},
            {"shape": "mesh", "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "indices": [[0, 1, 2]]}],
        "lights": [{"type": "point", "position": [0, 0, 0], "colour": [1, 1, 1]}]})
}

#[test]
fn whole_numbers_are_integers_for_both_and_fractions_are_not() {
    let v = schema();
    let whole: Vec<(&str, Edit)> = vec![
        ("width 5.0", Box::new(|d| d["image"]["width"] = json!(5.0))),
        (
            "height 5.0",
            Box::new(|d| d["image"]["height"] = json!(5.0)),
        ),
        (
            "samples 2.0",
            Box::new(|d| d["image"]["samples"] = json!(2.0)),
        ),
        ("max_depth 3.0", Box::new(|d| d["max_depth"] = json!(3.0))),
        ("max_depth -0.0", Box::new(|d| d["max_depth"] = json!(-0.0))),
        ("version 1.0", Box::new(|d| d["version"] = json!(1.0))),
        (
            "indices 0.0, 1.0, 2.0",
            Box::new(|d| d["objects"][1]["indices"] = json!([[0.0, 1.0, 2.0]])),
        ),
    ];
    for (what, edit) in whole {
        let mut d = base_with_mesh();
        edit(&mut d);
        assert_eq!(both(&v, &d), (true, true), "{what}");
    }
    let fractional: Vec<(&str, Edit)> = vec![
        ("width 5.5", Box::new(|d| d["image"]["width"] = json!(5.5))),
        (
            "height 0.5",
            Box::new(|d| d["image"]["height"] = json!(0.5)),
        ),
        (
            "samples 1.5",
            Box::new(|d| d["image"]["samples"] = json!(1.5)),
        ),
        ("max_depth 2.5", Box::new(|d| d["max_depth"] = json!(2.5))),
        ("version 1.5", Box::new(|d| d["version"] = json!(1.5))),
        (
            "indices 0.5",
            Box::new(|d| d["objects"][1]["indices"] = json!([[0.5, 1, 2]])),
        ),
        (
            "width beyond u32",
            Box::new(|d| d["image"]["width"] = json!(4294967296u64)),
        ),
        (
            "max_depth beyond u32",
            Box::new(|d| d["max_depth"] = json!(4294967296.0)),
        ),
    ];
    for (what, edit) in fractional {
        let mut d = base_with_mesh();
        edit(&mut d);
        assert_eq!(both(&v, &d), (false, false), "{what}");
    }
}

#[test]
fn an_explicit_null_fails_both_wherever_a_field_may_be_left_out() {
    let v = schema();
    let mut full = base_with_mesh();
    full["camera"] = json!({"focal_length": 1, "transform": []});
    full["background"] = json!([0, 0, 0]);
    full["ambient"] = json!([0, 0, 0]);
    full["max_depth"] = json!(2);
    full["image"]["samples"] = json!(1);
    full["image"]["gamma"] = json!(2.2);
    full["materials"] = json!({"m": {"ambient": [0, 0, 0], "diffuse": [0, 0, 0],
        "specular": [0, 0, 0], "shininess": 1, "mirror": [0, 0, 0],
        "transmission": [0, 0, 0], "ior": 1.5}});
    full["objects"][0] = json!({"name": "s", "shape": "sphere", "material": "m", "transform": []});
    full["objects"][1]["material"] = json!({"ior": 1.2});
    assert_eq!(both(&v, &full), (true, true));
    // Every member the format lets a document leave out.
    let optional = [
        "/camera",
        "/camera/focal_length",
        "/camera/transform",
        "/camera/look_at",
        "/background",
        "/ambient",
        "/max_depth",
        "/materials",
        "/lights",
        "/image/samples",
        "/image/gamma",
        "/materials/m/ambient",
        "/materials/m/diffuse",
        "/materials/m/specular",
        "/materials/m/shininess",
        "/materials/m/mirror",
        "/materials/m/transmission",
        "/materials/m/ior",
        "/objects/0/name",
        "/objects/0/material",
        "/objects/0/transform",
        "/objects/1/material/ior",
        "/objects/1/positions",
        "/objects/1/indices",
    ];
    for pointer in optional {
        let mut d = full.clone();
        if pointer == "/camera/look_at" {
            d["camera"] = json!({});
        }
        let (parent, key) = pointer.rsplit_once('/').unwrap();
        d.pointer_mut(parent).unwrap()[key] = Value::Null;
        assert_eq!(both(&v, &d), (false, false), "{pointer}: null");
    }
}

#[test]
fn duplicate_keys_fail_the_parser_and_the_schema_says_so() {
    // JSON Schema sees a document after parsing, when one of two equal keys is already
    // gone; its description says the server refuses them.
    let text = br#"{"version": 1, "image": {"width": 4, "height": 4, "height": 4}, "objects": []}"#;
    assert!(parse(text, &Limits::default()).is_err());
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("api/scene.schema.json");
    let schema: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let description = schema["description"].as_str().unwrap();
    assert!(description.contains("duplicate keys"), "{description}");
}

/// Keywords that schema-driven generators (hypothesis-jsonschema, and so Schemathesis)
/// cannot generate from: a schema that uses them yields no example at all.
#[test]
fn the_schema_uses_only_generable_keywords() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("api/scene.schema.json");
    let schema: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let mut found = Vec::new();
    let mut stack = vec![(String::new(), &schema)];
    while let Some((at, v)) = stack.pop() {
        match v {
            Value::Object(m) => {
                for (k, child) in m {
                    // Property names are data, not keywords.
                    let is_keyword = !at.ends_with("/properties") && !at.ends_with("/$defs");
                    if is_keyword
                        && ["prefixItems", "if", "then", "else", "not"].contains(&k.as_str())
                    {
                        found.push(format!("{at}/{k}"));
                    }
                    stack.push((format!("{at}/{k}"), child));
                }
            }
            Value::Array(items) => {
                for (i, child) in items.iter().enumerate() {
                    stack.push((format!("{at}/{i}"), child));
                }
            }
            _ => {}
        }
    }
    assert!(found.is_empty(), "{found:?}");
}
