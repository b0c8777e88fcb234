//! The scene: its JSON document ([`document`]), the checks that turn a document into a
//! [`Scene`] ([`validate`]), and what is wrong when they fail ([`problem`]).
//!
//! Parse, then validate into another type: a `Scene` is always traceable, with every
//! default filled in, every transform inverted and every material resolved.
//!
//! [`document`]: crate::scene::document
//! [`Scene`]: crate::scene::Scene
//! [`validate`]: crate::scene::validate
//! [`problem`]: crate::scene::problem

pub mod document;
pub mod footprint;
pub mod limits;
pub mod problem;
pub(crate) mod strict_json;
pub mod validate;

use std::sync::Arc;

use glam::DVec3;

use crate::geometry::{Shape, Transform, World};
pub use document::SceneDoc;
pub use limits::{DEEPEST, Limits};
pub use problem::{Problem, SceneError};
pub use validate::{parse, parse_value};

/// A validated scene, ready to trace.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Anti-aliasing: `samples × samples` rays per pixel.
    pub samples: u32,
    /// Gamma applied before quantising, if any.
    pub gamma: Option<f64>,
    /// The camera.
    pub camera: Camera,
    /// Colour of rays that hit nothing.
    pub background: DVec3,
    /// Ambient light.
    pub ambient: DVec3,
    /// Deepest recursion of reflection and refraction.
    pub max_depth: u32,
    /// The objects in document order.
    pub objects: Vec<Object>,
    /// Materials, one per distinct use; objects point into this list.
    pub materials: Vec<Material>,
    /// The lights.
    pub lights: Vec<Light>,
    /// The document as it was given.
    pub document: SceneDoc,
}

/// The anti-aliasing sample grid in the lecture's words, as every message that names it
/// writes it: `s × s samples per pixel`, and `1 sample per pixel` (the lecture's single
/// ray through the pixel's centre) for `s = 1`.
pub fn sample_grid(s: u32) -> String {
    if s == 1 {
        "1 sample per pixel".into()
    } else {
        format!("{s} × {s} samples per pixel")
    }
}

#[cfg(test)]
mod sample_grid_tests {
    #[test]
    fn the_grid_is_named_as_the_lecture_names_it() {
        assert_eq!(super::sample_grid(1), "1 sample per pixel");
        assert_eq!(super::sample_grid(2), "2 × 2 samples per pixel");
    }
}

impl Scene {
    /// Builds the acceleration structure over the objects.
    pub fn world(&self) -> World {
        World::new(self.objects.iter().map(|o| (&o.shape, &o.transform)))
    }

    /// Whether a hit can send a secondary ray: some material reflects or transmits
    /// ([`Material::sends_secondaries`]) and `max_depth` allows one. A scan of the
    /// materials, made once a render ([`crate::render::Renderer::new`]).
    pub fn sends_secondaries(&self) -> bool {
        self.max_depth > 0 && self.materials.iter().any(Material::sends_secondaries)
    }

    /// Total triangle count over all meshes.
    pub fn triangles(&self) -> u64 {
        self.objects
            .iter()
            .map(|o| match &o.shape {
                Shape::Mesh(m) => m.indices.len() as u64,
                _ => 0,
            })
            .sum()
    }

    /// The document with every default made explicit.
    pub fn normalised(&self) -> SceneDoc {
        validate::normalise(&self.document)
    }

    /// The name of object `i`, if it has one.
    pub fn object_name(&self, i: u32) -> Option<&str> {
        self.objects.get(i as usize).and_then(|o| o.name.as_deref())
    }
}

/// The camera: `world_from_camera` and the focal length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// camera → world.
    pub world_from_camera: Transform,
    /// Distance of the image plane `z = f`.
    pub focal_length: f64,
}

/// An object: a canonical shape, placed and coloured.
#[derive(Debug, Clone)]
pub struct Object {
    /// Its name, if any.
    pub name: Option<String>,
    /// The canonical shape.
    pub shape: Shape,
    /// object → world.
    pub transform: Transform,
    /// Index into [`Scene::materials`].
    pub material: u32,
}

/// A material with every default applied (`docs/spec/shading.md`, Materials).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Ambient reflectance.
    pub ambient: DVec3,
    /// Diffuse reflectance.
    pub diffuse: DVec3,
    /// Specular reflectance.
    pub specular: DVec3,
    /// Phong exponent.
    pub shininess: f64,
    /// Mirror reflectance.
    pub mirror: DVec3,
    /// Transmittance.
    pub transmission: DVec3,
    /// Index of refraction.
    pub ior: f64,
}

impl Material {
    /// Whether a hit on it sends secondary rays (below `max_depth`): it reflects
    /// (`mirror`) or transmits (`transmission`).
    #[inline(always)]
    pub fn sends_secondaries(&self) -> bool {
        // Written as the shader always tested it: as `≠ … || ≠ …` it compiled to more
        // instructions in the shader's test (render instructions +0.6 % on classic).
        !(self.mirror == DVec3::ZERO && self.transmission == DVec3::ZERO)
    }
}

/// A light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// Light from a point.
    Point {
        /// Where.
        position: DVec3,
        /// Its colour.
        colour: DVec3,
    },
    /// Parallel light.
    Directional {
        /// Unit vector the light travels along.
        direction: DVec3,
        /// Its colour.
        colour: DVec3,
    },
    /// A point light within a cone.
    Spot {
        /// Where.
        position: DVec3,
        /// Unit axis of the cone.
        direction: DVec3,
        /// Cosine of the half-angle: points with a smaller cosine are dark.
        cos_angle: f64,
        /// Its colour.
        colour: DVec3,
    },
}

/// A scene shared between the threads that trace it.
pub type SharedScene = Arc<Scene>;

#[cfg(test)]
mod secondaries_tests {
    use super::*;

    /// A scene of one sphere of `material` (JSON), `max_depth` as given.
    fn scene(material: serde_json::Value, max_depth: u32) -> Scene {
        let doc = serde_json::json!({
            "version": 1,
            "image": {"width": 2, "height": 2},
            "max_depth": max_depth,
            "materials": {"m": material, "plain": {"diffuse": [0.5, 0.5, 0.5]}},
            "objects": [
                {"shape": "sphere", "material": "plain"},
                {"shape": "sphere", "material": "m"}
            ],
            "lights": []
        });
        let bytes = serde_json::to_vec(&doc).unwrap();
        validate::parse(&bytes, &Limits::NONE).unwrap()
    }

    /// A scene sends secondary rays where one material reflects or transmits, in any
    /// channel, and `max_depth` lets a hit send one; a material that does neither
    /// (a zero of either sign) sends none.
    #[test]
    fn secondaries_are_sent_where_a_material_reflects_or_transmits_below_max_depth() {
        let mirror = serde_json::json!({"mirror": [0, 0, 0.25]});
        let glass = serde_json::json!({"transmission": [0.5, 0, 0], "ior": 1.5});
        let matte = serde_json::json!({"mirror": [-0.0, 0, 0], "transmission": [0, 0, 0]});
        assert!(scene(mirror.clone(), 5).sends_secondaries());
        assert!(scene(glass.clone(), 1).sends_secondaries());
        assert!(!scene(matte, 5).sends_secondaries());
        assert!(!scene(mirror, 0).sends_secondaries());
        assert!(!scene(glass, 0).sends_secondaries());
    }
}
