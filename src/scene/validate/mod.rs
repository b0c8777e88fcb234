//! From bytes to a [`Scene`]: parse the JSON, read each part of the document on its own
//! so that one bad object does not hide the problems of the next, then check what the
//! document means. Every problem is reported with its JSON pointer; nothing here panics
//! on any input.
//!
//! The checks follow the document's sections, one file each, in the order they are
//! reported: `image`, `camera` (with `transform`, which objects share too), then
//! `background`, `ambient` and `max_depth` here, `materials`, `objects` (with `shape`)
//! and `lights`. `read` is the slow path that reads a document part by part when it does
//! not deserialise in one go; `normalise` writes out its defaults. What each field means
//! is specified in `docs/spec/scene.md`.

mod camera;
mod image;
mod lights;
mod materials;
mod normalise;
mod objects;
mod read;
mod shape;
mod transform;

use glam::DVec3;
use serde_json::Value;

use super::document::*;
use super::problem::{Pointer, Problem, SceneError};
use super::{DEEPEST, Limits, Scene};
use crate::json::strip_position;
pub(crate) use normalise::normalise;
use read::{Failed, read_document};

/// At most this many problems are listed; the rest are counted.
const MAX_PROBLEMS: usize = 100;

/// Parses and validates a scene from JSON bytes.
pub fn parse(bytes: &[u8], limits: &Limits) -> Result<Scene, SceneError> {
    // Fast path: a well-formed document deserialises straight into its types, without
    // building a JSON tree first (several times faster on large scenes). Any error sends
    // it through the slow path, which reads part by part to report every problem. The
    // bytes are checked to be UTF-8 once, as a whole: read from bytes, serde_json
    // checks each string on its own, which cost a tenth of reading `spheres-100k`.
    let fast = std::str::from_utf8(bytes)
        .ok()
        .and_then(|text| serde_json::from_str::<SceneDoc>(text).ok());
    if let Some(doc) = fast {
        let mut p = Problems::default();
        return match check(doc, &Failed::default(), limits, &mut p) {
            Some(s) if p.list.is_empty() => Ok(s),
            _ => Err(SceneError::Invalid(p.finish())),
        };
    }
    let syntax = |e: &serde_json::Error| SceneError::Syntax {
        message: strip_position(&e.to_string()),
        line: e.line(),
        column: e.column(),
    };
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let (value, duplicates) = match crate::scene::strict_json::deserialize(&mut de) {
        Ok(v) => v,
        Err(e) => {
            let at = Pointer::root().join_path(e.path());
            let inner = e.into_inner();
            // JSON has no NaN or infinity; a number too large for f64 is the one way to
            // write a non-finite value, and it is a problem of that field, not of syntax.
            if inner.to_string().starts_with("number out of range") {
                return Err(SceneError::Invalid(vec![Problem::new(
                    at.to_string(),
                    format!(
                        "the number at line {}, column {} is out of range: numbers must be finite",
                        inner.line(),
                        inner.column()
                    ),
                )]));
            }
            return Err(syntax(&inner));
        }
    };
    de.end().map_err(|e| syntax(&e))?;
    crate::scene::strict_json::with_duplicates(duplicates, parse_value(value, limits))
}

/// Validates a scene already parsed as JSON.
pub fn parse_value(value: Value, limits: &Limits) -> Result<Scene, SceneError> {
    let mut p = Problems::default();
    let doc = read_document(value, &mut p);
    let scene = doc.and_then(|(doc, failed)| check(doc, &failed, limits, &mut p));
    match scene {
        Some(s) if p.list.is_empty() => Ok(s),
        _ => Err(SceneError::Invalid(p.finish())),
    }
}

/// The problems found so far, in the order found, at most [`MAX_PROBLEMS`] of them.
#[derive(Default)]
struct Problems {
    list: Vec<Problem>,
    dropped: usize,
}

impl Problems {
    fn add(&mut self, at: &Pointer, message: impl Into<String>) {
        if self.list.len() < MAX_PROBLEMS {
            self.list.push(Problem::new(at.to_string(), message));
        } else {
            self.dropped += 1;
        }
    }

    fn finish(mut self) -> Vec<Problem> {
        if self.dropped > 0 {
            self.list.push(Problem::new(
                "",
                format!("{} more problems not listed", self.dropped),
            ));
        }
        self.list
    }

    /// The problems as `(pointer, message)` pairs, for tests to compare whole.
    #[cfg(test)]
    fn pairs(&self) -> Vec<(String, String)> {
        self.list
            .iter()
            .map(|p| (p.pointer.clone(), p.message.clone()))
            .collect()
    }
}

/// Checks what the document means, section by section, and builds the scene.
fn check(doc: SceneDoc, failed: &Failed, limits: &Limits, p: &mut Problems) -> Option<Scene> {
    let root = Pointer::root();
    if doc.version != 1 {
        p.add(
            &root.key("version"),
            format!(
                "unsupported version {}: this renderer reads version 1",
                doc.version
            ),
        );
    }
    let samples = image::check(&doc.image, &root.key("image"), limits, p);
    let camera = camera::check(doc.camera.as_ref(), &root.key("camera"), p);
    let background = colour(doc.background, [0.0; 3], &root.key("background"), p);
    let ambient = colour(doc.ambient, [0.0; 3], &root.key("ambient"), p);
    let max_depth = doc.max_depth.unwrap_or(5);
    let deepest = limits.max_depth.min(DEEPEST);
    if max_depth > deepest {
        p.add(
            &root.key("max_depth"),
            format!("{max_depth} is more than the limit of {deepest}"),
        );
    }
    let mut materials =
        materials::Materials::check(&doc.materials, failed.materials, &root.key("materials"), p);
    let objects = objects::check(
        &doc.objects,
        &failed.objects,
        &mut materials,
        &root.key("objects"),
        limits,
        p,
    );
    let materials = materials.into_list();
    let lights = lights::check(&doc.lights, &failed.lights, &root.key("lights"), p);

    if !p.list.is_empty() {
        return None;
    }
    Some(Scene {
        width: doc.image.width,
        height: doc.image.height,
        samples,
        gamma: doc.image.gamma,
        camera: camera?,
        background,
        ambient,
        max_depth,
        objects,
        materials,
        lights,
        document: doc,
    })
}

fn vec3(a: Vec3) -> DVec3 {
    DVec3::from_array(a)
}

/// A unit vector along `v`, or `None` when `v` is zero. Scaling by the largest component
/// first keeps huge vectors from overflowing the length.
pub(crate) fn unit(v: DVec3) -> Option<DVec3> {
    let m = v.abs().max_element();
    if m == 0.0 || !m.is_finite() {
        return None;
    }
    (v / m).try_normalize()
}

/// A colour, `default` when absent, each negative channel reported at its index.
fn colour(c: Option<Colour>, default: Colour, at: &Pointer, p: &mut Problems) -> DVec3 {
    let c = c.unwrap_or(default);
    for (i, x) in c.iter().enumerate() {
        if *x < 0.0 {
            p.add(&at.index(i), format!("colours cannot be negative ({x})"));
        }
    }
    vec3(c)
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn good() -> Value {
        json!({
            "version": 1,
            "image": {"width": 8, "height": 6, "samples": 2},
            "camera": {"focal_length": 1.5},
            "background": [0.1, 0.1, 0.2],
            "ambient": [0.1, 0.1, 0.1],
            "max_depth": 3,
            "materials": {"red": {"diffuse": [0.8, 0.1, 0.1]}},
            "objects": [{"name": "ball", "shape": "sphere", "material": "red"}],
            "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]
        })
    }

    /// The problems of `v` as `(pointer, message)` pairs, by both paths, which must agree.
    fn problems(v: &Value, limits: &Limits) -> Vec<(String, String)> {
        let pairs = |r: Result<Scene, SceneError>| match r {
            Ok(_) => vec![],
            Err(SceneError::Invalid(p)) => p.into_iter().map(|p| (p.pointer, p.message)).collect(),
            Err(e) => panic!("expected an invalid scene, got {e}"),
        };
        let bytes = serde_json::to_vec(v).expect("serialisable");
        let fast = pairs(parse(&bytes, limits));
        let slow = pairs(parse_value(v.clone(), limits));
        assert_eq!(fast, slow, "the fast and slow paths disagree");
        fast
    }

    fn one(pointer: &str, message: &str) -> Vec<(String, String)> {
        vec![(pointer.into(), message.into())]
    }

    #[test]
    fn a_good_document_is_a_scene_with_its_values() {
        assert_eq!(problems(&good(), &Limits::default()), []);
        let s = parse_value(good(), &Limits::default()).expect("a scene");
        assert_eq!((s.width, s.height, s.samples, s.gamma), (8, 6, 2, None));
        assert_eq!(s.camera.focal_length, 1.5);
        assert_eq!(s.background, DVec3::new(0.1, 0.1, 0.2));
        assert_eq!(s.ambient, DVec3::splat(0.1));
        assert_eq!(s.max_depth, 3);
        assert_eq!(
            (s.objects.len(), s.materials.len(), s.lights.len()),
            (1, 1, 1)
        );
        assert_eq!(
            s.document,
            serde_json::from_value(good()).expect("a document")
        );
    }

    #[test]
    fn what_a_document_leaves_out_takes_its_default() {
        let s = parse_value(
            json!({"version": 1, "image": {"width": 1, "height": 1}, "objects": []}),
            &Limits::default(),
        )
        .expect("a scene");
        assert_eq!(s.samples, 1);
        assert_eq!(s.camera.focal_length, 1.0);
        assert_eq!((s.background, s.ambient), (DVec3::ZERO, DVec3::ZERO));
        assert_eq!(s.max_depth, 5);
        assert!(s.lights.is_empty() && s.materials.is_empty());
    }

    #[test]
    fn only_version_1_is_read() {
        let mut v = good();
        v["version"] = json!(2);
        assert_eq!(
            problems(&v, &Limits::default()),
            one(
                "/version",
                "unsupported version 2: this renderer reads version 1"
            )
        );
    }

    #[test]
    fn background_and_ambient_cannot_be_negative() {
        let mut v = good();
        v["background"] = json!([0, -1, 0]);
        v["ambient"] = json!([-0.5, 0, 0]);
        assert_eq!(
            problems(&v, &Limits::default()),
            [
                (
                    "/background/1".into(),
                    "colours cannot be negative (-1)".into()
                ),
                (
                    "/ambient/0".into(),
                    "colours cannot be negative (-0.5)".into()
                ),
            ]
        );
    }

    #[test]
    fn max_depth_beyond_the_limit() {
        let mut v = good();
        v["max_depth"] = json!(11);
        assert_eq!(
            problems(&v, &Limits::default()),
            one("/max_depth", "11 is more than the limit of 10")
        );
        assert_eq!(problems(&v, &Limits::NONE), []);
    }

    /// No caller's limits let a scene recurse deeper than the renderer's stack allows.
    #[test]
    fn max_depth_beyond_the_deepest_the_renderer_traces() {
        let mut v = good();
        v["max_depth"] = json!(DEEPEST);
        let unbounded = Limits {
            max_depth: u32::MAX,
            ..Limits::NONE
        };
        assert_eq!(problems(&v, &Limits::NONE), []);
        assert_eq!(problems(&v, &unbounded), []);
        v["max_depth"] = json!(DEEPEST + 1);
        for limits in [Limits::NONE, unbounded] {
            assert_eq!(
                problems(&v, &limits),
                one(
                    "/max_depth",
                    &format!("{} is more than the limit of {DEEPEST}", DEEPEST + 1)
                )
            );
        }
    }

    #[test]
    fn problems_are_reported_in_the_order_of_the_document() {
        let mut v = good();
        v["version"] = json!(3);
        v["lights"][0]["colour"] = json!([-1, 0, 0]);
        v["objects"][0]["material"] = json!("blue");
        v["materials"]["red"]["ior"] = json!(0);
        v["max_depth"] = json!(99);
        v["ambient"] = json!([-1, 0, 0]);
        v["background"] = json!([-1, 0, 0]);
        v["camera"]["focal_length"] = json!(0);
        v["image"]["width"] = json!(0);
        let at: Vec<String> = problems(&v, &Limits::default())
            .into_iter()
            .map(|(at, _)| at)
            .collect();
        assert_eq!(
            at,
            [
                "/version",
                "/image/width",
                "/camera/focal_length",
                "/background/0",
                "/ambient/0",
                "/max_depth",
                "/materials/red/ior",
                "/objects/0/material",
                "/lights/0/colour/0",
            ]
        );
    }

    #[test]
    fn at_most_100_problems_are_listed_and_the_rest_counted() {
        let mut v = good();
        v["objects"] = Value::Array(
            (0..120)
                .map(|_| json!({"shape": "sphere", "material": "nowhere"}))
                .collect(),
        );
        let found = problems(&v, &Limits::default());
        assert_eq!(found.len(), MAX_PROBLEMS + 1);
        assert_eq!(
            found[99],
            (
                "/objects/99/material".into(),
                "no material named `nowhere` in /materials".into()
            )
        );
        assert_eq!(
            found[100],
            ("".into(), "20 more problems not listed".into())
        );
    }

    #[test]
    fn bytes_that_are_not_json_are_a_syntax_error_with_its_position() {
        assert_eq!(
            parse(b"{\n  \"version\": 1,,", &Limits::default()).err(),
            Some(SceneError::Syntax {
                message: "key must be a string".into(),
                line: 2,
                column: 16,
            })
        );
        assert!(matches!(
            parse(b"{} x", &Limits::default()),
            Err(SceneError::Syntax {
                line: 1,
                column: 4,
                ..
            })
        ));
    }

    #[test]
    fn text_is_read_as_utf_8_and_other_bytes_are_a_syntax_error_where_they_stand() {
        let doc = |name: &[u8]| {
            [
                br#"{"version": 1, "image": {"width": 1, "height": 1}, "objects": [{"name": ""#
                    .as_slice(),
                name,
                br#"", "shape": "sphere"}]}"#,
            ]
            .concat()
        };
        let scene = parse(&doc("sphère ☀".as_bytes()), &Limits::default()).expect("a scene");
        assert_eq!(scene.objects[0].name.as_deref(), Some("sphère ☀"));
        // Latin-1's è, not UTF-8: the error stands on its byte.
        assert_eq!(
            parse(&doc(b"sph\xe8re"), &Limits::default()).err(),
            Some(SceneError::Syntax {
                message: "invalid unicode code point".into(),
                line: 1,
                column: 77,
            })
        );
    }

    #[test]
    fn a_number_too_large_for_f64_is_a_problem_of_its_field() {
        let text = br#"{"version": 1, "image": {"width": 1, "height": 1}, "objects": [], "ambient": [0, 1e999, 0]}"#;
        assert_eq!(
            parse(text, &Limits::default()).err(),
            Some(SceneError::Invalid(vec![Problem::new(
                "/ambient/1",
                "the number at line 1, column 86 is out of range: numbers must be finite"
            )]))
        );
    }

    #[test]
    fn unit_vectors_of_huge_and_zero_vectors() {
        assert_eq!(unit(DVec3::new(0.0, 0.0, -4.0)), Some(DVec3::NEG_Z));
        // Unscaled, its squared length (2e600) would overflow to infinity.
        let u = unit(DVec3::new(1e300, 0.0, 1e300)).expect("a unit vector");
        assert!((u.length() - 1.0).abs() < 1e-15 && u.x == u.z, "{u}");
        assert_eq!(unit(DVec3::ZERO), None);
        assert_eq!(unit(DVec3::new(f64::INFINITY, 0.0, 0.0)), None);
    }
}
