//! Every class of bad document `docs/spec/scene.md` lists is refused, each problem with its pointer.

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

/// The problems found in `text`, as (pointer, message).
fn problems_of(text: &str) -> Vec<(String, String)> {
    match parse(text.as_bytes(), &Limits::default()) {
        Ok(_) => vec![],
        Err(SceneError::Invalid(p)) => p.into_iter().map(|p| (p.pointer, p.message)).collect(),
        Err(e) => panic!("expected an invalid scene, got {e}"),
    }
}

/// A mesh whose indices are written as `[[a, b, c]]`.
fn with_mesh(indices: Value) -> Value {
    let mut d = base();
    push(
        &mut d["objects"],
        json!({"shape": "mesh", "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "indices": indices}),
    );
    d
}

#[test]
fn whole_numbers_written_with_a_fraction_or_exponent_are_integers() {
    let mut d = with_mesh(json!([[0.0, 1.0, 2.0]]));
    d["version"] = json!(1.0);
    d["image"]["width"] = json!(8.0);
    d["image"]["samples"] = json!(2.0);
    d["max_depth"] = json!(3.0);
    let text = serde_json::to_string(&d)
        .unwrap()
        .replace(r#""height":6"#, r#""height":6e0"#);
    assert!(text.contains("6e0"), "{text}");
    let scene = parse(text.as_bytes(), &Limits::default()).unwrap();
    assert_eq!(
        (scene.width, scene.height, scene.samples, scene.max_depth),
        (8, 6, 2, 3)
    );
    // The slow path, which reads part by part, agrees.
    d["objects"][0]["material"] = json!("nope");
    assert_eq!(pointers(&d, &Limits::default()), ["/objects/0/material"]);
}

#[test]
fn integers_with_a_fractional_part_are_refused_at_their_pointer() {
    let expect = |d: &Value, pointer: &str, message: &str| {
        let found = problems_of(&serde_json::to_string(d).unwrap());
        assert!(
            found.iter().any(|(p, m)| p == pointer && m == message),
            "expected {pointer}: {message} in {found:?}"
        );
    };
    let mut d = base();
    d["image"]["width"] = json!(5.5);
    expect(
        &d,
        "/image/width",
        "invalid type: floating point `5.5`, expected u32",
    );
    let mut d = base();
    d["image"]["samples"] = json!(1.25);
    expect(
        &d,
        "/image/samples",
        "invalid type: floating point `1.25`, expected u32",
    );
    let mut d = base();
    d["max_depth"] = json!(2.5);
    expect(
        &d,
        "/max_depth",
        "invalid type: floating point `2.5`, expected u32",
    );
    let mut d = base();
    d["version"] = json!(1.5);
    expect(
        &d,
        "/version",
        "invalid type: floating point `1.5`, expected u32",
    );
    let d = with_mesh(json!([[0, 1.5, 2]]));
    expect(
        &d,
        "/objects/1/indices/0/1",
        "invalid type: floating point `1.5`, expected u32",
    );
    let mut d = base();
    d["image"]["height"] = json!(-2.0);
    expect(
        &d,
        "/image/height",
        "invalid value: floating point `-2.0`, expected u32",
    );
}

#[test]
fn an_explicit_null_is_refused_wherever_a_field_is_optional() {
    let mut full = with_mesh(json!([[0, 1, 2]]));
    full["objects"][1]["name"] = json!("m");
    full["objects"][1]["material"] = json!({"ior": 1.3});
    full["objects"][1]["transform"] = json!([]);
    for pointer in [
        "/camera",
        "/background",
        "/ambient",
        "/max_depth",
        "/materials",
        "/lights",
        "/image/samples",
        "/image/gamma",
        "/camera/focal_length",
        "/camera/transform",
        "/camera/look_at",
        "/materials/red/ambient",
        "/materials/red/diffuse",
        "/materials/red/specular",
        "/materials/red/shininess",
        "/materials/red/mirror",
        "/materials/red/transmission",
        "/materials/red/ior",
        "/objects/0/name",
        "/objects/0/material",
        "/objects/0/transform",
        "/objects/1/positions",
        "/objects/1/indices",
        "/objects/1/material/ior",
        "/objects/1/material/diffuse",
    ] {
        let mut d = full.clone();
        if pointer.starts_with("/camera/") {
            d["camera"] = json!({});
        }
        let (parent, key) = pointer.rsplit_once('/').unwrap();
        d.pointer_mut(parent).unwrap()[key] = Value::Null;
        let found = problems_of(&serde_json::to_string(&d).unwrap());
        assert!(
            found
                .iter()
                .any(|(p, m)| p == pointer && m.starts_with("invalid type: null, expected ")),
            "expected {pointer} to refuse null, got {found:?}"
        );
    }
    assert!(pointers(&full, &Limits::default()).is_empty());
}

#[test]
fn duplicate_keys_are_refused_at_the_duplicated_member() {
    let cases = [
        (
            r#"{"version": 1, "image": {"width": 8, "height": 6, "width": 9}, "objects": []}"#,
            "/image/width",
            "duplicate key `width`",
        ),
        (
            r#"{"version": 1, "image": {"width": 8, "height": 6}, "objects": [],
               "materials": {"red": {}, "blue": {}, "red": {"ior": 2}}}"#,
            "/materials/red",
            "duplicate key `red`",
        ),
        (
            r#"{"version": 1, "version": 1, "image": {"width": 8, "height": 6}, "objects": []}"#,
            "/version",
            "duplicate key `version`",
        ),
        (
            r#"{"version": 1, "image": {"width": 8, "height": 6},
               "objects": [{"shape": "cube"}, {"shape": "sphere", "shape": "sphere"}]}"#,
            "/objects/1/shape",
            "duplicate key `shape`",
        ),
        (
            r#"{"version": 1, "image": {"width": 8, "height": 6}, "objects": [{"shape": "cube",
               "transform": [{"translate": [0, 0, 1], "translate": [0, 0, 2]}]}]}"#,
            "/objects/0/transform/0/translate",
            "duplicate key `translate`",
        ),
        (
            r#"{"version": 1, "image": {"width": 8, "height": 6}, "objects": [],
               "lights": [{"type": "point", "position": [0, 0, 0], "colour": [1, 1, 1],
                           "colour": [0, 0, 0]}]}"#,
            "/lights/0/colour",
            "duplicate key `colour`",
        ),
        (
            r#"{"version": 1, "image": {"width": 8, "height": 6}, "objects": [],
               "materials": {"a/b": {"ior": 1, "ior": 1}}}"#,
            "/materials/a~1b/ior",
            "duplicate key `ior`",
        ),
    ];
    for (text, pointer, message) in cases {
        let found = problems_of(text);
        assert_eq!(
            found,
            [(pointer.to_string(), message.to_string())],
            "in {text}"
        );
    }
}

#[test]
fn duplicate_keys_are_reported_with_every_other_problem() {
    let text = r#"{"version": 1, "image": {"width": 0, "height": 6, "height": 6},
        "objects": [{"shape": "teapot"}], "objects": [{"shape": "sphere", "material": "nope"}]}"#;
    let found: Vec<String> = problems_of(text).into_iter().map(|(p, _)| p).collect();
    assert_eq!(
        found,
        [
            "/image/height",
            "/objects",
            "/image/width",
            "/objects/0/material"
        ]
    );
}

#[test]
fn many_duplicate_keys_are_counted_past_the_listed_ones() {
    let members: Vec<String> = (0..150).map(|_| r#""ior": 1"#.to_string()).collect();
    let text = format!(
        r#"{{"version": 1, "image": {{"width": 8, "height": 6}}, "objects": [],
            "materials": {{"m": {{{}}}}}}}"#,
        members.join(", ")
    );
    let found = problems_of(&text);
    assert_eq!(found.len(), 101);
    assert!(found[..100].iter().all(|(p, _)| p == "/materials/m/ior"));
    assert_eq!(
        found[100],
        (String::new(), "49 more problems not listed".to_string())
    );
}
