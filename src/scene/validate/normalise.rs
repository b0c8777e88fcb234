//! The document with every default written out, as `raytile validate --normalised` and
//! `POST /v1/validate` return it: what a document leaves out is exactly what these fill in.

use super::materials::resolve_material;
use crate::scene::document::*;

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
            None => MaterialRefDoc::Inline(Box::new(full(&MaterialDoc::default()))),
            Some(MaterialRefDoc::Inline(m)) => MaterialRefDoc::Inline(Box::new(full(m))),
            Some(named) => named.clone(),
        });
        if o.transform.is_none() {
            o.transform = Some(Vec::new());
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    #[test]
    fn every_default_is_written_out_and_what_was_given_is_kept() {
        let doc: SceneDoc = serde_json::from_value(json!({
            "version": 1,
            "image": {"width": 4, "height": 2, "gamma": 2.2},
            "camera": {"look_at": {"eye": [0, 0, 0], "target": [0, 0, 1], "up": [0, 1, 0]}},
            "materials": {"red": {"diffuse": [1, 0, 0]}},
            "objects": [
                {"shape": "sphere", "material": "red"},
                {"shape": "cube", "transform": [{"translate": [1, 0, 0]}]}
            ]
        }))
        .expect("a document");
        let n = serde_json::to_value(normalise(&doc)).expect("serialisable");
        assert_eq!(
            n,
            json!({
                "version": 1,
                "image": {"width": 4, "height": 2, "samples": 1, "gamma": 2.2},
                "camera": {
                    "focal_length": 1.0,
                    "look_at": {"eye": [0.0, 0.0, 0.0], "target": [0.0, 0.0, 1.0], "up": [0.0, 1.0, 0.0]}
                },
                "background": [0.0, 0.0, 0.0],
                "ambient": [0.0, 0.0, 0.0],
                "max_depth": 5,
                "materials": {"red": {
                    "ambient": [1.0, 0.0, 0.0], "diffuse": [1.0, 0.0, 0.0], "specular": [0.0, 0.0, 0.0],
                    "shininess": 32.0, "mirror": [0.0, 0.0, 0.0], "transmission": [0.0, 0.0, 0.0], "ior": 1.5
                }},
                "objects": [
                    {"shape": "sphere", "material": "red", "transform": []},
                    {"shape": "cube", "transform": [{"translate": [1.0, 0.0, 0.0]}], "material": {
                        "ambient": [0.8, 0.8, 0.8], "diffuse": [0.8, 0.8, 0.8], "specular": [0.0, 0.0, 0.0],
                        "shininess": 32.0, "mirror": [0.0, 0.0, 0.0], "transmission": [0.0, 0.0, 0.0], "ior": 1.5
                    }}
                ],
                "lights": []
            })
        );
    }

    #[test]
    fn a_camera_with_no_placement_gets_an_empty_transform() {
        let doc: SceneDoc = serde_json::from_value(json!({
            "version": 1, "image": {"width": 1, "height": 1}, "objects": []
        }))
        .expect("a document");
        let cam = normalise(&doc).camera.expect("a camera");
        assert_eq!(cam.transform, Some(vec![]));
        assert_eq!(cam.look_at, None);
    }
}
