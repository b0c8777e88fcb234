//! The scene document as it travels: serde types that *are* the wire format (`docs/spec/scene.md`).
//!
//! Strict: every struct refuses unknown fields, and `colour` may also be spelled
//! `color`. As in the published JSON Schema, an integer is any number without a
//! fractional part (`5.0` is 5), an optional member is either left out or given a value
//! (never `null`), and no object repeats a key. These types say only what was written; [`super::validate`] checks what it
//! means and turns it into a [`super::Scene`].
//!
//! ```json
//! { "version": 1, "image": { "width": 5, "height": 5 },
//!   "objects": [ { "name": "ball", "shape": "sphere", "transform": [ { "translate": [1, 0, 2] } ] } ],
//!   "lights": [ { "type": "point", "position": [0, -4, 0], "colour": [1, 1, 1] } ] }
//! ```

use std::collections::BTreeMap;
use std::fmt;

use serde::de::{self, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// `[x, y, z]`.
pub type Vec3 = [f64; 3];
/// Linear RGB, each channel non-negative.
pub type Colour = [f64; 3];

/// The whole document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDoc {
    /// Format version; only 1 exists.
    #[serde(deserialize_with = "whole")]
    pub version: u32,
    /// Image size, anti-aliasing and gamma.
    pub image: ImageDoc,
    /// The camera; the default looks along +z from the origin with f = 1.
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub camera: Option<CameraDoc>,
    /// Colour of rays that hit nothing (default black).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub background: Option<Colour>,
    /// Ambient light (default black).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub ambient: Option<Colour>,
    /// Recursion depth of reflection and refraction (default 5).
    #[serde(
        default,
        deserialize_with = "present_whole",
        skip_serializing_if = "Option::is_none"
    )]
    pub max_depth: Option<u32>,
    /// Named materials that objects refer to.
    #[serde(
        default,
        deserialize_with = "unique_keys",
        skip_serializing_if = "BTreeMap::is_empty"
    )]
    pub materials: BTreeMap<String, MaterialDoc>,
    /// The objects, in order (ties go to the earlier one).
    pub objects: Vec<ObjectDoc>,
    /// The lights.
    #[serde(default)]
    pub lights: Vec<LightDoc>,
}

/// `image`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageDoc {
    /// Width in pixels.
    #[serde(deserialize_with = "whole")]
    pub width: u32,
    /// Height in pixels.
    #[serde(deserialize_with = "whole")]
    pub height: u32,
    /// `s`: `s × s` rays per pixel (default 1).
    #[serde(
        default,
        deserialize_with = "present_whole",
        skip_serializing_if = "Option::is_none"
    )]
    pub samples: Option<u32>,
    /// When given, colours are raised to `1/gamma` before quantising.
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub gamma: Option<f64>,
}

/// `camera`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDoc {
    /// Distance of the image plane (default 1).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub focal_length: Option<f64>,
    /// camera → world, as transform steps.
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub transform: Option<Vec<StepDoc>>,
    /// camera → world from an eye, a target and an up vector.
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub look_at: Option<LookAtDoc>,
}

/// `camera.look_at`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LookAtDoc {
    /// The projection point.
    pub eye: Vec3,
    /// A point on the optical axis.
    pub target: Vec3,
    /// Which way is up in the image (camera y points along `−up`).
    pub up: Vec3,
}

/// One transform step, written as an object with exactly one key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum StepDoc {
    /// `{"translate": [x, y, z]}`.
    Translate(Vec3),
    /// `{"scale": s}` or `{"scale": [x, y, z]}`.
    Scale(ScaleDoc),
    /// `{"rotate": {"axis": "x" | [x, y, z], "degrees": a}}`.
    Rotate(RotateDoc),
    /// `{"matrix": [[…], [..], [..], [0, 0, 0, 1]]}`, rows. Boxed: the rare step
    /// would otherwise set the size of every step of every object.
    Matrix(Box<[[f64; 4]; 4]>),
}

/// A uniform or per-axis scale.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum ScaleDoc {
    /// The same factor on every axis.
    Uniform(f64),
    /// One factor per axis.
    Axes(Vec3),
}

/// A rotation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotateDoc {
    /// `"x"`, `"y"`, `"z"` or a vector.
    pub axis: AxisDoc,
    /// Angle, right-hand rule.
    pub degrees: f64,
}

/// A rotation axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum AxisDoc {
    /// A coordinate axis by name.
    Named(AxisName),
    /// Any non-zero vector.
    Vector(Vec3),
}

/// `"x"`, `"y"` or `"z"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxisName {
    /// x.
    X,
    /// y.
    Y,
    /// z.
    Z,
}

/// A material; every field optional (`docs/spec/shading.md` gives the defaults).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDoc {
    /// Ambient reflectance (defaults to `diffuse`).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub ambient: Option<Colour>,
    /// Diffuse reflectance (default 0.8 grey).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub diffuse: Option<Colour>,
    /// Specular reflectance (default black).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub specular: Option<Colour>,
    /// Phong exponent (default 32).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub shininess: Option<f64>,
    /// Mirror reflectance (default black).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub mirror: Option<Colour>,
    /// Transmittance (default black).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub transmission: Option<Colour>,
    /// Index of refraction (default 1.5).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub ior: Option<f64>,
}

/// A material by name or inline.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum MaterialRefDoc {
    /// The name of an entry of `materials`.
    Named(String),
    /// A material written in place. Boxed: a name is what large scenes write, and
    /// the material's seven optional fields would otherwise size every object.
    Inline(Box<MaterialDoc>),
}

/// The shapes of `docs/spec/shapes.md`, by the names documents use. The list lives with the shapes
/// (`crate::geometry::shapes`), so a new shape is a name here too.
pub use crate::geometry::ShapeName;

/// One object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDoc {
    /// A unique name, reported in hit data.
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub name: Option<String>,
    /// Which canonical shape.
    pub shape: ShapeName,
    /// Its material (default: the default material).
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub material: Option<MaterialRefDoc>,
    /// object → world, applied in the listed order.
    #[serde(
        default,
        deserialize_with = "present_steps",
        skip_serializing_if = "Option::is_none"
    )]
    pub transform: Option<Vec<StepDoc>>,
    /// Mesh vertices.
    #[serde(
        default,
        deserialize_with = "present",
        skip_serializing_if = "Option::is_none"
    )]
    pub positions: Option<Vec<Vec3>>,
    /// Mesh triangles, as indices into `positions`.
    #[serde(
        default,
        deserialize_with = "present_indices",
        skip_serializing_if = "Option::is_none"
    )]
    pub indices: Option<Vec<[u32; 3]>>,
}

/// A light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum LightDoc {
    /// Light from a point.
    Point {
        /// Where.
        position: Vec3,
        /// Its colour.
        #[serde(alias = "color")]
        colour: Colour,
    },
    /// Parallel light travelling along `direction`.
    Directional {
        /// The direction the light travels.
        direction: Vec3,
        /// Its colour.
        #[serde(alias = "color")]
        colour: Colour,
    },
    /// A point light limited to a cone.
    Spot {
        /// Where.
        position: Vec3,
        /// The cone's axis.
        direction: Vec3,
        /// The cone's half-angle.
        angle_degrees: f64,
        /// Its colour.
        #[serde(alias = "color")]
        colour: Colour,
    },
}

/// A `u32` as JSON Schema counts integers: any number without a fractional part, so
/// `5`, `5.0` and `5e0` are all 5. Other values are refused with serde's own messages
/// for a `u32` (`invalid type: floating point `5.5`, expected u32`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Integer(pub u32);

impl From<Integer> for u32 {
    fn from(i: Integer) -> u32 {
        i.0
    }
}

impl<'de> Deserialize<'de> for Integer {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Integer;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("u32")
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
                u32::try_from(v)
                    .map(Integer)
                    .map_err(|_| E::invalid_value(de::Unexpected::Unsigned(v), &self))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
                u32::try_from(v)
                    .map(Integer)
                    .map_err(|_| E::invalid_value(de::Unexpected::Signed(v), &self))
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
                if v.fract() != 0.0 || !v.is_finite() {
                    Err(E::invalid_type(de::Unexpected::Float(v), &self))
                } else if (0.0..=f64::from(u32::MAX)).contains(&v) {
                    // Whole and in range, so the conversion is exact.
                    Ok(Integer(v as u32))
                } else {
                    Err(E::invalid_value(de::Unexpected::Float(v), &self))
                }
            }
        }
        d.deserialize_u32(V)
    }
}

fn whole<'de, D: Deserializer<'de>>(d: D) -> Result<u32, D::Error> {
    Integer::deserialize(d).map(u32::from)
}

/// An optional member that is there: `null` is not a way to leave it out (the schema
/// gives each a type, and null is none of them). A `null` is refused with the member
/// type's own message, e.g. `invalid type: null, expected f64`.
fn present<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    match Option::<T>::deserialize(d)? {
        Some(t) => Ok(Some(t)),
        None => Err(null_for::<T, D::Error>()),
    }
}

/// The error `T` gives for a `null`.
fn null_for<'de, T: Deserialize<'de>, E: de::Error>() -> E {
    match T::deserialize(de::value::UnitDeserializer::<E>::new()) {
        Err(e) => e,
        Ok(_) => E::invalid_type(de::Unexpected::Unit, &"a value"),
    }
}

/// [`present`] for a transform's steps, one or two of them (what most objects list) in
/// a vector of their own length: serde's `Vec` grows from room for four (for 100 000
/// objects, 8 MB of pages touched while the document is read).
fn present_steps<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Vec<StepDoc>>, D::Error> {
    present::<D, Steps>(d).map(|s| s.map(|s| s.0))
}

/// A transform's steps, read as `Vec<StepDoc>` reads them.
struct Steps(Vec<StepDoc>);

impl<'de> Deserialize<'de> for Steps {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Steps;
            // `Vec`'s own words, so that a wrong type reads as it always did.
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a sequence")
            }
            fn visit_seq<A: de::SeqAccess<'de>>(self, mut seq: A) -> Result<Steps, A::Error> {
                let Some(first) = seq.next_element()? else {
                    return Ok(Steps(Vec::new()));
                };
                let Some(second) = seq.next_element()? else {
                    return Ok(Steps(vec![first]));
                };
                // Beyond two, the vector grows as `Vec`'s own reading grows it.
                let mut steps = vec![first, second];
                while let Some(step) = seq.next_element()? {
                    steps.push(step);
                }
                Ok(Steps(steps))
            }
        }
        d.deserialize_seq(V)
    }
}

fn present_whole<'de, D: Deserializer<'de>>(d: D) -> Result<Option<u32>, D::Error> {
    present::<D, Integer>(d).map(|i| i.map(u32::from))
}

fn present_indices<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Vec<[u32; 3]>>, D::Error> {
    let indices = present::<D, Vec<[Integer; 3]>>(d)?;
    Ok(indices.map(|t| t.into_iter().map(|tri| tri.map(u32::from)).collect()))
}

/// A map whose keys are unique: a repeated key is refused rather than replacing the
/// value before it.
fn unique_keys<'de, D, T>(d: D) -> Result<BTreeMap<String, T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct V<T>(std::marker::PhantomData<T>);
    impl<'de, T: Deserialize<'de>> Visitor<'de> for V<T> {
        type Value = BTreeMap<String, T>;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a map")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
            let mut out = BTreeMap::new();
            while let Some(key) = map.next_key::<String>()? {
                if out.contains_key(&key) {
                    return Err(de::Error::custom(format_args!("duplicate key `{key}`")));
                }
                let value = map.next_value()?;
                out.insert(key, value);
            }
            Ok(out)
        }
    }
    d.deserialize_map(V(std::marker::PhantomData))
}

// The untagged enums get hand-written visitors: serde's derived untagged errors say only
// "did not match any variant", and route inline materials around the path tracker.

impl<'de> Deserialize<'de> for MaterialRefDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = MaterialRefDoc;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a material name or a material object")
            }
            fn visit_str<E: de::Error>(self, s: &str) -> Result<Self::Value, E> {
                Ok(MaterialRefDoc::Named(s.to_owned()))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
                MaterialDoc::deserialize(de::value::MapAccessDeserializer::new(map))
                    .map(|m| MaterialRefDoc::Inline(Box::new(m)))
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Deserialize<'de> for ScaleDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = ScaleDoc;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or an array of 3 numbers")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(ScaleDoc::Uniform(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(ScaleDoc::Uniform(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(ScaleDoc::Uniform(v as f64))
            }
            fn visit_seq<A: de::SeqAccess<'de>>(self, seq: A) -> Result<Self::Value, A::Error> {
                Vec3::deserialize(de::value::SeqAccessDeserializer::new(seq)).map(ScaleDoc::Axes)
            }
        }
        d.deserialize_any(V)
    }
}

impl<'de> Deserialize<'de> for AxisDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = AxisDoc;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("\"x\", \"y\", \"z\" or an array of 3 numbers")
            }
            fn visit_str<E: de::Error>(self, s: &str) -> Result<Self::Value, E> {
                match s {
                    "x" => Ok(AxisDoc::Named(AxisName::X)),
                    "y" => Ok(AxisDoc::Named(AxisName::Y)),
                    "z" => Ok(AxisDoc::Named(AxisName::Z)),
                    _ => Err(E::invalid_value(de::Unexpected::Str(s), &self)),
                }
            }
            fn visit_seq<A: de::SeqAccess<'de>>(self, seq: A) -> Result<Self::Value, A::Error> {
                Vec3::deserialize(de::value::SeqAccessDeserializer::new(seq)).map(AxisDoc::Vector)
            }
        }
        d.deserialize_any(V)
    }
}

// `ShapeName` is written and read exactly as serde's derive does it for a unit enum with
// lowercase names (the same messages for an unknown shape), its names coming from the
// shapes themselves.

impl Serialize for ShapeName {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_unit_variant("ShapeName", *self as u32, self.as_str())
    }
}

impl<'de> Deserialize<'de> for ShapeName {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        /// The variant's identifier: a name, or its index in formats that write one.
        struct Variant(ShapeName);
        impl<'de> Deserialize<'de> for Variant {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                struct V;
                impl<'de> Visitor<'de> for V {
                    type Value = Variant;
                    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                        f.write_str("variant identifier")
                    }
                    fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
                        let all = ShapeName::ALL;
                        match usize::try_from(v).ok().and_then(|i| all.get(i)) {
                            Some(&n) => Ok(Variant(n)),
                            None => Err(E::invalid_value(
                                de::Unexpected::Unsigned(v),
                                &format!("variant index 0 <= i < {}", all.len()).as_str(),
                            )),
                        }
                    }
                    fn visit_str<E: de::Error>(self, v: &str) -> Result<Self::Value, E> {
                        ShapeName::from_name(v)
                            .map(Variant)
                            .ok_or_else(|| E::unknown_variant(v, ShapeName::NAMES))
                    }
                    fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Self::Value, E> {
                        match std::str::from_utf8(v).ok().and_then(ShapeName::from_name) {
                            Some(n) => Ok(Variant(n)),
                            None => Err(E::unknown_variant(
                                &String::from_utf8_lossy(v),
                                ShapeName::NAMES,
                            )),
                        }
                    }
                }
                d.deserialize_identifier(V)
            }
        }
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = ShapeName;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("enum ShapeName")
            }
            fn visit_enum<A: de::EnumAccess<'de>>(self, data: A) -> Result<Self::Value, A::Error> {
                let (Variant(name), variant) = data.variant()?;
                de::VariantAccess::unit_variant(variant)?;
                Ok(name)
            }
        }
        d.deserialize_enum("ShapeName", ShapeName::NAMES, V)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The enum as serde's derive wrote it before the names moved to the shapes.
    mod derived {
        #[derive(Debug, serde::Serialize, serde::Deserialize)]
        #[serde(rename_all = "lowercase")]
        pub enum ShapeName {
            Sphere,
            Cube,
            Plane,
            Disk,
            Cylinder,
            Cone,
            Mesh,
        }
    }

    fn outcome<T: Serialize>(r: Result<T, serde_json::Error>) -> Result<String, String> {
        r.map(|v| serde_json::to_string(&v).unwrap())
            .map_err(|e| e.to_string())
    }

    #[test]
    fn shape_names_read_and_write_as_the_derived_enum_did() {
        for text in [
            r#""sphere""#,
            r#""cube""#,
            r#""plane""#,
            r#""disk""#,
            r#""cylinder""#,
            r#""cone""#,
            r#""mesh""#,
            r#""m\u0065sh""#,
            r#""teapot""#,
            r#""Sphere""#,
            r#""""#,
            "3",
            "-1",
            "1.5",
            "null",
            "true",
            "[]",
            "{}",
            r#"{"sphere": null}"#,
            r#"{"sphere": 1}"#,
            r#"{"teapot": null}"#,
            r#"{"sphere": null, "cube": null}"#,
        ] {
            assert_eq!(
                outcome(serde_json::from_str::<ShapeName>(text)),
                outcome(serde_json::from_str::<derived::ShapeName>(text)),
                "from text {text}"
            );
            let value: serde_json::Value = serde_json::from_str(text).unwrap();
            assert_eq!(
                outcome(serde_json::from_value::<ShapeName>(value.clone())),
                outcome(serde_json::from_value::<derived::ShapeName>(value)),
                "from a value {text}"
            );
        }
    }

    #[test]
    fn steps_read_as_a_vec_reads_them_one_or_two_in_a_vector_of_their_length() {
        #[derive(Debug, Serialize, Deserialize)]
        struct Plain {
            #[serde(default, deserialize_with = "present")]
            transform: Option<Vec<StepDoc>>,
        }
        #[derive(Debug, Serialize, Deserialize)]
        struct Ours {
            #[serde(default, deserialize_with = "present_steps")]
            transform: Option<Vec<StepDoc>>,
        }
        let step = |k: usize| format!(r#"{{"translate": [{k}, 0, 1]}}"#);
        let steps = |n: usize| (0..n).map(step).collect::<Vec<_>>().join(", ");
        let mut texts: Vec<String> = [0, 1, 2, 3, 4, 5, 9]
            .map(|n| format!(r#"{{"transform": [{}]}}"#, steps(n)))
            .into();
        for bad in [
            "null",
            "3",
            r#""scale""#,
            "{}",
            r#"[null]"#,
            r#"[{"scale": 2}, 7]"#,
            r#"[{"scale": 2}, {"scale": 2}, {"scale": 2}, {"scale": 2}, {"turn": 1}]"#,
        ] {
            texts.push(format!(r#"{{"transform": {bad}}}"#));
        }
        texts.push("{}".into());
        for text in &texts {
            assert_eq!(
                outcome(serde_json::from_str::<Ours>(text)),
                outcome(serde_json::from_str::<Plain>(text)),
                "from text {text}"
            );
            let value: serde_json::Value = serde_json::from_str(text).unwrap();
            assert_eq!(
                outcome(serde_json::from_value::<Ours>(value.clone())),
                outcome(serde_json::from_value::<Plain>(value)),
                "from a value {text}"
            );
            if let Ok(Ours { transform: Some(t) }) = serde_json::from_str::<Ours>(text)
                && t.len() <= 2
            {
                assert_eq!(t.capacity(), t.len(), "{text}");
            }
        }
    }

    /// A scene of 100 000 objects holds its document while it renders: each object
    /// and each of its steps is as small as what large scenes write needs, the rare
    /// inline material and matrix living apart (before they were boxed, an object took
    /// nearly 300 bytes and a step 136).
    #[test]
    fn objects_and_steps_are_sized_for_large_scenes() {
        assert!(std::mem::size_of::<ObjectDoc>() <= 160);
        assert!(std::mem::size_of::<StepDoc>() <= 48);
    }

    #[test]
    fn an_unknown_shape_lists_every_name() {
        let doc = r#"{"shape": "teapot"}"#;
        let e = serde_json::from_str::<ObjectDoc>(doc)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(
                "unknown variant `teapot`, expected one of `sphere`, `cube`, `plane`, `disk`, \
                 `cylinder`, `cone`, `mesh`"
            ),
            "{e}"
        );
    }
}
