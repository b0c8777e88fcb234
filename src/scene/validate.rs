//! From bytes to a [`Scene`]: parse the JSON, read each part of the document on its own
//! so that one bad object does not hide the problems of the next, then check what the
//! document means. Every problem is reported with its JSON pointer; nothing here panics
//! on any input.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::Arc;

use glam::{DAffine3, DMat3, DVec3};
use serde::de::DeserializeOwned;
use serde_json::Value;

use super::document::*;
use super::problem::{Pointer, Problem, SceneError};
use super::{Camera, Light, Limits, Material, Object, Scene};
use crate::geometry::{Mesh, NeedsData, Shape, Transform};

/// At most this many problems are listed; the rest are counted.
const MAX_PROBLEMS: usize = 100;

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

/// Parses and validates a scene from JSON bytes.
pub fn parse(bytes: &[u8], limits: &Limits) -> Result<Scene, SceneError> {
    // Fast path: a well-formed document deserialises straight into its types, without
    // building a JSON tree first (several times faster on large scenes). Any error sends
    // it through the slow path, which reads part by part to report every problem.
    if let Ok(doc) = serde_json::from_slice::<SceneDoc>(bytes) {
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
    let (value, duplicates) = match super::strict_json::deserialize(&mut de) {
        Ok(v) => v,
        Err(e) => {
            let at = Pointer::root().join_path(e.path());
            let inner = e.into_inner();
            // JSON has no NaN or infinity; a number too large for f64 is the one way to
            // write a non-finite value, and it is a problem of that field, not of syntax.
            if inner.to_string().starts_with("number out of range") {
                return Err(SceneError::Invalid(vec![Problem::new(
                    at.as_str(),
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
    super::strict_json::with_duplicates(duplicates, parse_value(value, limits))
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

#[derive(Default)]
struct Problems {
    list: Vec<Problem>,
    dropped: usize,
}

impl Problems {
    fn add(&mut self, at: &Pointer, message: impl Into<String>) {
        if self.list.len() < MAX_PROBLEMS {
            self.list.push(Problem::new(at.as_str(), message));
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
}

/// serde_json's messages end in "at line 1 column 5"; we report the position separately.
fn strip_position(msg: &str) -> String {
    match msg.rfind(" at line ") {
        Some(i) => msg[..i].to_string(),
        None => msg.to_string(),
    }
}

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
struct Failed {
    materials: bool,
    objects: HashSet<usize>,
    lights: HashSet<usize>,
}

fn read_document(value: Value, p: &mut Problems) -> Option<(SceneDoc, Failed)> {
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

/// Checks what the document means and builds the scene.
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

    // image
    let img = &doc.image;
    let at = root.key("image");
    if img.width == 0 {
        p.add(&at.key("width"), "must be at least 1");
    }
    if img.height == 0 {
        p.add(&at.key("height"), "must be at least 1");
    }
    let pixels = img.width as u64 * img.height as u64;
    if pixels > limits.max_pixels {
        p.add(
            &at,
            format!(
                "{} × {} is {pixels} pixels; the limit is {}",
                img.width, img.height, limits.max_pixels
            ),
        );
    }
    let samples = img.samples.unwrap_or(1);
    if samples == 0 {
        p.add(&at.key("samples"), "must be at least 1");
    } else if samples > limits.max_samples {
        p.add(
            &at.key("samples"),
            format!("{samples} is more than the limit of {}", limits.max_samples),
        );
    }
    if let Some(g) = img.gamma
        && g.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
    {
        p.add(&at.key("gamma"), "must be greater than 0");
    }

    // camera
    let cam_doc = doc.camera.clone().unwrap_or_default();
    let at = root.key("camera");
    let focal_length = cam_doc.focal_length.unwrap_or(1.0);
    if focal_length <= 0.0 {
        p.add(&at.key("focal_length"), "must be greater than 0");
    }
    let world_from_camera = match (&cam_doc.transform, &cam_doc.look_at) {
        (Some(_), Some(_)) => {
            p.add(&at, "give either `transform` or `look_at`, not both");
            None
        }
        (Some(steps), None) => transform_of(steps, &at.key("transform"), p),
        (None, Some(la)) => look_at(la, &at.key("look_at"), p),
        (None, None) => Some(Transform::IDENTITY),
    };

    let background = colour(doc.background, [0.0; 3], &root.key("background"), p);
    let ambient = colour(doc.ambient, [0.0; 3], &root.key("ambient"), p);
    let max_depth = doc.max_depth.unwrap_or(5);
    if max_depth > limits.max_depth {
        p.add(
            &root.key("max_depth"),
            format!("{max_depth} is more than the limit of {}", limits.max_depth),
        );
    }

    // materials
    let mut materials = Vec::new();
    let mut named = HashMap::new();
    for (name, m) in &doc.materials {
        if let Some(m) = material(m, &root.key("materials").key(name), p) {
            named.insert(name.as_str(), materials.len() as u32);
            materials.push(m);
        }
    }
    let mut default_material = None;

    // objects
    let at_objects = root.key("objects");
    if doc.objects.len() as u64 > limits.max_objects {
        p.add(
            &at_objects,
            format!(
                "{} objects is more than the limit of {}",
                doc.objects.len(),
                limits.max_objects
            ),
        );
    }
    let mut names: HashMap<&str, usize> = HashMap::new();
    let mut objects = Vec::with_capacity(doc.objects.len());
    let mut triangles = 0u64;
    for (i, o) in doc.objects.iter().enumerate() {
        if failed.objects.contains(&i) {
            continue;
        }
        let at = at_objects.index(i);
        if let Some(name) = &o.name
            && let Some(first) = names.insert(name, i)
        {
            p.add(
                &at.key("name"),
                format!("duplicate name `{name}`, already used by /objects/{first}"),
            );
            names.insert(name, first);
        }
        let material = match &o.material {
            None => Some(*default_material.get_or_insert_with(|| {
                materials.push(resolve_material(&MaterialDoc::default()));
                materials.len() as u32 - 1
            })),
            Some(MaterialRefDoc::Named(n)) => {
                let found = named.get(n.as_str()).copied();
                if found.is_none() && !doc.materials.contains_key(n) && !failed.materials {
                    p.add(
                        &at.key("material"),
                        format!("no material named `{n}` in /materials"),
                    );
                }
                found
            }
            Some(MaterialRefDoc::Inline(m)) => material(m, &at.key("material"), p).map(|m| {
                materials.push(m);
                materials.len() as u32 - 1
            }),
        };
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
            &at_objects,
            format!(
                "{triangles} triangles is more than the limit of {}",
                limits.max_triangles
            ),
        );
    }

    // lights
    let lights: Vec<Light> = doc
        .lights
        .iter()
        .enumerate()
        .filter(|(i, _)| !failed.lights.contains(i))
        .filter_map(|(i, l)| light(l, &root.key("lights").index(i), p))
        .collect();

    if !p.list.is_empty() {
        return None;
    }
    Some(Scene {
        width: img.width,
        height: img.height,
        samples,
        gamma: img.gamma,
        camera: Camera {
            world_from_camera: world_from_camera?,
            focal_length,
        },
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

fn colour(c: Option<Colour>, default: Colour, at: &Pointer, p: &mut Problems) -> DVec3 {
    let c = c.unwrap_or(default);
    for (i, x) in c.iter().enumerate() {
        if *x < 0.0 {
            p.add(&at.index(i), format!("colours cannot be negative ({x})"));
        }
    }
    vec3(c)
}

fn material(m: &MaterialDoc, at: &Pointer, p: &mut Problems) -> Option<Material> {
    let before = p.list.len() + p.dropped;
    for (k, c) in [
        ("ambient", m.ambient),
        ("diffuse", m.diffuse),
        ("specular", m.specular),
        ("mirror", m.mirror),
        ("transmission", m.transmission),
    ] {
        if c.is_some() {
            colour(c, [0.0; 3], &at.key(k), p);
        }
    }
    if m.shininess.is_some_and(|s| s < 0.0) {
        p.add(&at.key("shininess"), "must be at least 0");
    }
    if m.ior.is_some_and(|s| s <= 0.0) {
        p.add(&at.key("ior"), "must be greater than 0");
    }
    (p.list.len() + p.dropped == before).then(|| resolve_material(m))
}

/// SPEC §3's defaults.
fn resolve_material(m: &MaterialDoc) -> Material {
    let diffuse = vec3(m.diffuse.unwrap_or([0.8; 3]));
    Material {
        ambient: m.ambient.map_or(diffuse, vec3),
        diffuse,
        specular: vec3(m.specular.unwrap_or([0.0; 3])),
        shininess: m.shininess.unwrap_or(32.0),
        mirror: vec3(m.mirror.unwrap_or([0.0; 3])),
        transmission: vec3(m.transmission.unwrap_or([0.0; 3])),
        ior: m.ior.unwrap_or(1.5),
    }
}

/// Composes transform steps in the listed order.
fn transform_of(steps: &[StepDoc], at: &Pointer, p: &mut Problems) -> Option<Transform> {
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

/// camera z from eye to target, camera y along −up made orthogonal to z, x = y × z.
fn look_at(la: &LookAtDoc, at: &Pointer, p: &mut Problems) -> Option<Transform> {
    let (eye, target, up) = (vec3(la.eye), vec3(la.target), vec3(la.up));
    let Some(z) = unit(target - eye) else {
        p.add(
            &at.key("target"),
            "the target is the eye: there is no view direction",
        );
        return None;
    };
    let Some(up_dir) = unit(up) else {
        p.add(&at.key("up"), "the up vector has zero length");
        return None;
    };
    let ortho = up_dir - up_dir.dot(z) * z;
    if ortho.length() < 1e-9 {
        p.add(
            &at.key("up"),
            "the up vector is parallel to the view direction",
        );
        return None;
    }
    let y = -ortho.normalize();
    let x = y.cross(z);
    let m = DAffine3::from_mat3_translation(DMat3::from_cols(x, y, z), eye);
    // The inverse of a rotation is its transpose: exact, no general inversion.
    let rt = DMat3::from_cols(x, y, z).transpose();
    let inverse = DAffine3::from_mat3_translation(rt, -(rt * eye));
    let t = Transform {
        forward: m,
        inverse,
    };
    if !t.is_finite() {
        p.add(at, "the camera placement overflows");
        return None;
    }
    Some(t)
}

fn shape(o: &ObjectDoc, at: &Pointer, p: &mut Problems) -> Option<Shape> {
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

fn light(l: &LightDoc, at: &Pointer, p: &mut Problems) -> Option<Light> {
    let before = p.list.len() + p.dropped;
    let out = match l {
        LightDoc::Point {
            position,
            colour: c,
        } => Light::Point {
            position: vec3(*position),
            colour: colour(Some(*c), [0.0; 3], &at.key("colour"), p),
        },
        LightDoc::Directional {
            direction,
            colour: c,
        } => {
            let direction = unit(vec3(*direction));
            if direction.is_none() {
                p.add(&at.key("direction"), "the direction has zero length");
            }
            Light::Directional {
                direction: direction.unwrap_or(DVec3::Y),
                colour: colour(Some(*c), [0.0; 3], &at.key("colour"), p),
            }
        }
        LightDoc::Spot {
            position,
            direction,
            angle_degrees,
            colour: c,
        } => {
            let direction = unit(vec3(*direction));
            if direction.is_none() {
                p.add(&at.key("direction"), "the direction has zero length");
            }
            if !(*angle_degrees > 0.0 && *angle_degrees <= 180.0) {
                p.add(
                    &at.key("angle_degrees"),
                    "the half-angle must be in (0, 180]",
                );
            }
            Light::Spot {
                position: vec3(*position),
                direction: direction.unwrap_or(DVec3::Y),
                cos_angle: angle_degrees.to_radians().cos(),
                colour: colour(Some(*c), [0.0; 3], &at.key("colour"), p),
            }
        }
    };
    (p.list.len() + p.dropped == before).then_some(out)
}

/// The document with every default written out.
pub(crate) fn normalise(doc: &SceneDoc) -> SceneDoc {
    let full = |m: &MaterialDoc| {
        let r = resolve_material(m);
        MaterialDoc {
            ambient: Some(r.ambient.to_array()),
            diffuse: Some(r.diffuse.to_array()),
            specular: Some(r.specular.to_array()),
            shininess: Some(r.shininess),
            mirror: Some(r.mirror.to_array()),
            transmission: Some(r.transmission.to_array()),
            ior: Some(r.ior),
        }
    };
    let mut d = doc.clone();
    d.image.samples = Some(doc.image.samples.unwrap_or(1));
    let mut cam = doc.camera.clone().unwrap_or_default();
    cam.focal_length = Some(cam.focal_length.unwrap_or(1.0));
    if cam.transform.is_none() && cam.look_at.is_none() {
        cam.transform = Some(Vec::new());
    }
    d.camera = Some(cam);
    d.background = Some(doc.background.unwrap_or([0.0; 3]));
    d.ambient = Some(doc.ambient.unwrap_or([0.0; 3]));
    d.max_depth = Some(doc.max_depth.unwrap_or(5));
    d.materials = doc
        .materials
        .iter()
        .map(|(k, m)| (k.clone(), full(m)))
        .collect();
    for o in &mut d.objects {
        o.material = Some(match &o.material {
            None => MaterialRefDoc::Inline(full(&MaterialDoc::default())),
            Some(MaterialRefDoc::Inline(m)) => MaterialRefDoc::Inline(full(m)),
            Some(named) => named.clone(),
        });
        if o.transform.is_none() {
            o.transform = Some(Vec::new());
        }
    }
    d
}
