//! `materials` and each object's `material`: non-negative colours, a non-negative
//! shininess, a positive index of refraction, names that exist, and the defaults of
//! `docs/spec/shading.md#materials`.
//!
//! ```json
//! "materials": { "red": { "diffuse": [0.8, 0.1, 0.1], "specular": [0.5, 0.5, 0.5], "shininess": 50 } }
//! ```

use std::collections::{BTreeMap, HashMap};

use super::{Problems, colour, vec3};
use crate::scene::Material;
use crate::scene::document::{MaterialDoc, MaterialRefDoc};
use crate::scene::problem::Pointer;

/// The scene's list of resolved materials as it is built: the named ones first (in
/// name order), then the default and the inline ones, each where an object first needs it.
pub(super) struct Materials<'a> {
    /// `materials` as written.
    doc: &'a BTreeMap<String, MaterialDoc>,
    /// Some entry of `materials` could not be read, so a name not found may be its.
    unreadable: bool,
    list: Vec<Material>,
    /// Index in `list` of each named material that passed its checks.
    named: HashMap<&'a str, u32>,
    /// Index in `list` of the default material, once an object has needed it.
    default: Option<u32>,
}

impl<'a> Materials<'a> {
    /// Checks every entry of `materials` (at `at`).
    pub(super) fn check(
        doc: &'a BTreeMap<String, MaterialDoc>,
        unreadable: bool,
        at: &Pointer,
        p: &mut Problems,
    ) -> Self {
        let mut list = Vec::new();
        let mut named = HashMap::new();
        for (name, m) in doc {
            if let Some(m) = material(m, &at.key(name), p) {
                named.insert(name.as_str(), list.len() as u32);
                list.push(m);
            }
        }
        Materials {
            doc,
            unreadable,
            list,
            named,
            default: None,
        }
    }

    /// The material of an object whose `material` field (at `at`) is `r`, or `None` when
    /// it is at fault.
    pub(super) fn of_object(
        &mut self,
        r: Option<&MaterialRefDoc>,
        at: &Pointer,
        p: &mut Problems,
    ) -> Option<u32> {
        match r {
            None => Some(*self.default.get_or_insert_with(|| {
                self.list.push(resolve_material(&MaterialDoc::default()));
                self.list.len() as u32 - 1
            })),
            Some(MaterialRefDoc::Named(n)) => {
                let found = self.named.get(n.as_str()).copied();
                // A material that exists but failed its own checks has been reported
                // already; reporting its users too would only repeat it.
                if found.is_none() && !self.doc.contains_key(n) && !self.unreadable {
                    p.add(at, format!("no material named `{n}` in /materials"));
                }
                found
            }
            Some(MaterialRefDoc::Inline(m)) => material(m, at, p).map(|m| {
                self.list.push(m);
                self.list.len() as u32 - 1
            }),
        }
    }

    /// The resolved materials, which objects index.
    pub(super) fn into_list(self) -> Vec<Material> {
        self.list
    }
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

/// The defaults of `docs/spec/shading.md#materials`.
pub(super) fn resolve_material(m: &MaterialDoc) -> Material {
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

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use serde_json::json;

    use super::*;

    fn map(v: serde_json::Value) -> BTreeMap<String, MaterialDoc> {
        serde_json::from_value(v).expect("a materials map")
    }

    fn reference(v: serde_json::Value) -> MaterialRefDoc {
        serde_json::from_value(v).expect("a material reference")
    }

    fn at() -> Pointer<'static> {
        Pointer::root().key("materials").owned()
    }

    fn object_at() -> Pointer<'static> {
        Pointer::root()
            .key("objects")
            .index(0)
            .key("material")
            .owned()
    }

    #[test]
    fn an_empty_material_takes_every_default() {
        assert_eq!(
            resolve_material(&MaterialDoc::default()),
            Material {
                ambient: DVec3::splat(0.8),
                diffuse: DVec3::splat(0.8),
                specular: DVec3::ZERO,
                shininess: 32.0,
                mirror: DVec3::ZERO,
                transmission: DVec3::ZERO,
                ior: 1.5,
            }
        );
    }

    #[test]
    fn ambient_defaults_to_the_diffuse_colour_given() {
        let m = resolve_material(&MaterialDoc {
            diffuse: Some([0.1, 0.2, 0.3]),
            ..MaterialDoc::default()
        });
        assert_eq!(m.ambient, DVec3::new(0.1, 0.2, 0.3));
    }

    #[test]
    fn good_named_materials_have_no_problem_and_are_listed_in_name_order() {
        let doc = map(json!({
            "red": {"diffuse": [0.8, 0.1, 0.1], "shininess": 0, "ior": 1},
            "blue": {"diffuse": [0.1, 0.1, 0.8]}
        }));
        let mut p = Problems::default();
        let mut m = Materials::check(&doc, false, &at(), &mut p);
        assert_eq!(
            m.of_object(Some(&reference(json!("red"))), &object_at(), &mut p),
            Some(1)
        );
        assert_eq!(
            m.of_object(Some(&reference(json!("blue"))), &object_at(), &mut p),
            Some(0)
        );
        assert_eq!(p.pairs(), []);
        assert_eq!(m.into_list()[1].diffuse, DVec3::new(0.8, 0.1, 0.1));
    }

    #[test]
    fn each_negative_colour_channel_is_reported_at_its_index() {
        let doc = map(json!({"odd": {"ambient": [0, -1, 0], "transmission": [-0.5, 0, -2]}}));
        let mut p = Problems::default();
        let mut m = Materials::check(&doc, false, &at(), &mut p);
        assert_eq!(
            p.pairs(),
            [
                (
                    "/materials/odd/ambient/1".into(),
                    "colours cannot be negative (-1)".into()
                ),
                (
                    "/materials/odd/transmission/0".into(),
                    "colours cannot be negative (-0.5)".into()
                ),
                (
                    "/materials/odd/transmission/2".into(),
                    "colours cannot be negative (-2)".into()
                ),
            ]
        );
        // Its users are not blamed for it.
        assert_eq!(
            m.of_object(Some(&reference(json!("odd"))), &object_at(), &mut p),
            None
        );
        assert_eq!(p.pairs().len(), 3);
    }

    #[test]
    fn shininess_must_be_at_least_0_and_ior_greater_than_0() {
        let doc = map(json!({"m": {"shininess": -1, "ior": 0}}));
        let mut p = Problems::default();
        Materials::check(&doc, false, &at(), &mut p);
        assert_eq!(
            p.pairs(),
            [
                ("/materials/m/shininess".into(), "must be at least 0".into()),
                ("/materials/m/ior".into(), "must be greater than 0".into()),
            ]
        );
    }

    #[test]
    fn an_unknown_name_is_a_problem_of_the_object() {
        let doc = map(json!({}));
        let mut p = Problems::default();
        let mut m = Materials::check(&doc, false, &at(), &mut p);
        assert_eq!(
            m.of_object(Some(&reference(json!("blue"))), &object_at(), &mut p),
            None
        );
        assert_eq!(
            p.pairs(),
            [(
                "/objects/0/material".into(),
                "no material named `blue` in /materials".into()
            )]
        );
    }

    #[test]
    fn an_unknown_name_is_not_reported_when_some_material_could_not_be_read() {
        let doc = map(json!({}));
        let mut p = Problems::default();
        let mut m = Materials::check(&doc, true, &at(), &mut p);
        assert_eq!(
            m.of_object(Some(&reference(json!("blue"))), &object_at(), &mut p),
            None
        );
        assert_eq!(p.pairs(), []);
    }

    #[test]
    fn a_bad_inline_material_is_reported_under_the_object() {
        let doc = map(json!({}));
        let mut p = Problems::default();
        let mut m = Materials::check(&doc, false, &at(), &mut p);
        let inline = reference(json!({"mirror": [0, 0, -1]}));
        assert_eq!(m.of_object(Some(&inline), &object_at(), &mut p), None);
        assert_eq!(
            p.pairs(),
            [(
                "/objects/0/material/mirror/2".into(),
                "colours cannot be negative (-1)".into()
            )]
        );
    }

    #[test]
    fn the_default_material_is_added_once_when_first_needed() {
        let doc = map(json!({"red": {"diffuse": [1, 0, 0]}}));
        let mut p = Problems::default();
        let mut m = Materials::check(&doc, false, &at(), &mut p);
        assert_eq!(m.of_object(None, &object_at(), &mut p), Some(1));
        let inline = reference(json!({"diffuse": [0, 1, 0]}));
        assert_eq!(m.of_object(Some(&inline), &object_at(), &mut p), Some(2));
        assert_eq!(m.of_object(None, &object_at(), &mut p), Some(1));
        assert_eq!(p.pairs(), []);
        let list = m.into_list();
        assert_eq!(list.len(), 3);
        assert_eq!(list[1], resolve_material(&MaterialDoc::default()));
    }
}
