//! Every class of bad document SPEC §4 lists is refused, each problem with its pointer.

use raytile::scene::{Limits, SceneError, parse};
use serde_json::{Value, json};

fn base() -> Value {
    json!({
        "version": 1,
        "image": {"width": 8, "height": 6},
        "materials": {"red": {"diffuse": [0.8, 0.1, 0.1]}},
        "objects": [{"name": "a", "shape": "sphere", "material": "red", "transform": [{"translate": [0, 0, 5]}]}],
        "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]
    })
}

fn push(list: &mut Value, item: Value) {
    list.as_array_mut().expect("an array").push(item);
}

/// The pointers of the problems found in `doc`.
fn pointers(doc: &Value, limits: &Limits) -> Vec<String> {
    match parse(&serde_json::to_vec(doc).unwrap(), limits) {
        Ok(_) => vec![],
        Err(SceneError::Invalid(p)) => p.into_iter().map(|p| p.pointer).collect(),
        Err(e) => panic!("expected an invalid scene, got {e}"),
    }
}

fn refused_at(edit: impl FnOnce(&mut Value), pointer: &str) {
    let mut doc = base();
    edit(&mut doc);
    let found = pointers(&doc, &Limits::default());
    assert!(
        found.iter().any(|p| p == pointer),
        "expected a problem at {pointer}, got {found:?}"
    );
}

#[test]
fn the_base_document_is_valid() {
    assert!(pointers(&base(), &Limits::default()).is_empty());
}

#[test]
fn non_finite_numbers() {
    let text = serde_json::to_string(&base())
        .unwrap()
        .replace("[0,0,5]", "[0,0,1e999]");
    match parse(text.as_bytes(), &Limits::default()) {
        Err(SceneError::Invalid(p)) => {
            assert_eq!(p[0].pointer, "/objects/0/transform/0/translate/2")
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn singular_and_non_affine_matrices() {
    refused_at(
        |d| {
            d["objects"][0]["transform"] =
                json!([{"matrix": [[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}])
        },
        "/objects/0/transform/0/matrix",
    );
    refused_at(
        |d| {
            push(
                &mut d["objects"][0]["transform"],
                json!({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}),
            )
        },
        "/objects/0/transform/1/matrix/3",
    );
}

#[test]
fn zero_scale_axis_and_direction() {
    refused_at(
        |d| {
            push(
                &mut d["objects"][0]["transform"],
                json!({"scale": [1, 0, 1]}),
            )
        },
        "/objects/0/transform/1/scale",
    );
    refused_at(
        |d| d["objects"][0]["transform"][0] = json!({"rotate": {"axis": [0, 0, 0], "degrees": 10}}),
        "/objects/0/transform/0/rotate/axis",
    );
    refused_at(
        |d| {
            d["lights"][0] =
                json!({"type": "directional", "direction": [0, 0, 0], "colour": [1, 1, 1]})
        },
        "/lights/0/direction",
    );
}

#[test]
fn look_at_with_up_along_the_view() {
    refused_at(
        |d| {
            d["camera"] =
                json!({"look_at": {"eye": [0, 0, 0], "target": [0, 3, 0], "up": [0, -2, 0]}})
        },
        "/camera/look_at/up",
    );
}

#[test]
fn unknown_material_and_duplicate_name() {
    refused_at(
        |d| d["objects"][0]["material"] = json!("blue"),
        "/objects/0/material",
    );
    refused_at(
        |d| push(&mut d["objects"], json!({"name": "a", "shape": "cube"})),
        "/objects/1/name",
    );
}

#[test]
fn negative_colours() {
    refused_at(
        |d| d["materials"]["red"]["specular"] = json!([0, -0.1, 0]),
        "/materials/red/specular/1",
    );
    refused_at(
        |d| d["lights"][0]["colour"] = json!([1, 1, -1]),
        "/lights/0/colour/2",
    );
    refused_at(|d| d["background"] = json!([-1, 0, 0]), "/background/0");
}

#[test]
fn sizes_and_counts_beyond_the_limits() {
    let limits = Limits {
        max_pixels: 40,
        max_samples: 2,
        max_depth: 3,
        max_objects: 1,
        max_triangles: 1,
    };
    let mut d = base();
    d["image"]["samples"] = json!(3);
    d["max_depth"] = json!(4);
    push(
        &mut d["objects"],
        json!({"shape": "mesh", "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "indices": [[0, 1, 2], [0, 2, 1]]}),
    );
    let found = pointers(&d, &limits);
    for p in ["/image", "/image/samples", "/max_depth", "/objects"] {
        assert!(found.iter().any(|f| f == p), "{p} in {found:?}");
    }
}

#[test]
fn unknown_fields_and_both_colour_spellings() {
    refused_at(
        |d| d["objects"][0]["colour"] = json!([1, 0, 0]),
        "/objects/0/colour",
    );
    refused_at(|d| d["extra"] = json!(true), "/extra");
    refused_at(|d| d["lights"][0]["color"] = json!([1, 1, 1]), "/lights/0");
}

#[test]
fn color_is_accepted_for_colour() {
    let mut d = base();
    d["lights"][0] = json!({"type": "point", "position": [0, 0, 0], "color": [1, 1, 1]});
    assert!(pointers(&d, &Limits::default()).is_empty());
}

#[test]
fn mesh_indices_out_of_range() {
    refused_at(
        |d| {
            push(
                &mut d["objects"],
                json!({"shape": "mesh", "positions": [[0, 0, 0]], "indices": [[0, 0, 3]]}),
            )
        },
        "/objects/1/indices/0/2",
    );
}

#[test]
fn every_problem_is_reported_not_just_the_first() {
    let mut d = base();
    d["objects"][0]["material"] = json!("nope");
    push(&mut d["objects"], json!({"shape": "teapot"}));
    push(
        &mut d["objects"],
        json!({"shape": "cube", "transform": [{"scale": 0}]}),
    );
    d["image"]["width"] = json!(0);
    let found = pointers(&d, &Limits::default());
    for p in [
        "/objects/0/material",
        "/objects/1/shape",
        "/objects/2/transform/0/scale",
        "/image/width",
    ] {
        assert!(found.iter().any(|f| f == p), "{p} in {found:?}");
    }
}

#[test]
fn syntax_errors_give_line_and_column() {
    match parse(b"{\n  \"version\": 1,\n  oops\n}", &Limits::default()) {
        Err(SceneError::Syntax { line, column, .. }) => assert_eq!((line, column), (3, 3)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn garbage_never_panics() {
    for bytes in [
        &b""[..],
        b"[]",
        b"null",
        b"{\"objects\": 5}",
        b"{\"version\": -1}",
        b"\xff\xfe",
        b"{\"image\": {\"width\": 1e10}}",
    ] {
        assert!(parse(bytes, &Limits::default()).is_err());
    }
}
