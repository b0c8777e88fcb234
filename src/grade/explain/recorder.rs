//! The recorder: a [`ShadingProbe`] that builds the ray tree while the tracer shades the
//! pixel. Every value it records is one the tracer computed (or, for a shape test's
//! details, one the shape test reported through [`Probe`]); it adds only what a reader
//! needs beyond the colour: every candidate object's test, and the state of shadow rays
//! the tracer had no need to cast.

use std::cell::Cell;

use glam::DVec3;

use super::model::{
    Blocker, FaceCheck, HitInfo, LightInfo, ObjectTest, Quadratic, RayNode, Role, Root, Secondary,
    Shading, TriangleCheck, point4, vector4,
};
use super::{Candidates, ExplainOptions};
use crate::geometry::hit::{FaceTest, Probe, QuadraticTest, TriangleTest};
use crate::geometry::{Hit, Ray, Shape, Surface, World};
use crate::render::Renderer;
use crate::render::shade::{
    Bounce, Branch, LightTerm, NoSecondary, SECONDARY_LAMBDA_MIN, ShadingProbe, surface_offset,
};
use crate::scene::{Light, Material};

/// Records what a shape test reports.
#[derive(Default)]
struct TestRecorder {
    object_ray: Option<Ray>,
    quadratics: Vec<QuadraticTest>,
    faces: Vec<FaceTest>,
    triangles: Vec<TriangleTest>,
}

impl Probe for TestRecorder {
    fn object(&mut self, _index: u32, object_ray: &Ray) {
        self.object_ray = Some(*object_ray);
    }
    fn quadratic(&mut self, q: &QuadraticTest) {
        self.quadratics.push(*q);
    }
    fn face(&mut self, f: &FaceTest) {
        self.faces.push(*f);
    }
    fn triangle(&mut self, t: &TriangleTest) {
        self.triangles.push(*t);
    }
    fn active(&self) -> bool {
        true
    }
}

/// The name of a part of a shape, as the shape files number them.
pub fn part_label(shape: &Shape, part: u32) -> String {
    shape.part_label(part).into_owned()
}

/// What every ray of one explanation shares: the scene, the options, and the budget of
/// rays still to break down.
pub(super) struct Explainer<'a> {
    r: &'a Renderer,
    opts: &'a ExplainOptions,
    mode: Candidates,
    rays_left: Cell<usize>,
    truncated: Cell<bool>,
}

impl<'a> Explainer<'a> {
    /// Lists each ray's tests by `mode` (`all` or `bvh`) and breaks down at most
    /// `opts.max_rays` rays (at least the primary one).
    pub(super) fn new(r: &'a Renderer, opts: &'a ExplainOptions, mode: Candidates) -> Self {
        Explainer {
            r,
            opts,
            mode,
            rays_left: Cell::new(opts.max_rays.max(1)),
            truncated: Cell::new(false),
        }
    }

    /// Whether some ray was left unexplained because the budget was spent.
    pub(super) fn truncated(&self) -> bool {
        self.truncated.get()
    }

    /// The tests of every candidate object, each searched over `(t_min, ∞)` on its own.
    fn object_tests(&self, ray: &Ray, t_min: f64, chosen: Option<u32>) -> Vec<ObjectTest> {
        let world: &World = &self.r.world;
        let list: Vec<u32> = match self.mode {
            Candidates::Bvh => world.candidates(ray, t_min, f64::INFINITY),
            _ => (0..world.len() as u32).collect(),
        };
        list.into_iter()
            .map(|i| self.object_test(i, ray, t_min, chosen == Some(i)))
            .collect()
    }

    fn object_test(&self, i: u32, ray: &Ray, t_min: f64, chosen: bool) -> ObjectTest {
        let world = &self.r.world;
        let object = &self.r.scene.objects[i as usize];
        let shape = &object.shape;
        let mut rec = TestRecorder::default();
        let result = world.intersect_object(i, ray, t_min, f64::INFINITY, &mut rec);
        let object_ray = rec
            .object_ray
            .unwrap_or_else(|| ray.transformed(&world.transform(i).inverse));
        let hit_part = result.map(|(_, p)| part_label(shape, p));
        let side_hit = result.filter(|&(_, p)| p == 0).map(|(t, _)| t);
        let bounded_height = shape.bounded_quadric();

        let quadratics = rec
            .quadratics
            .iter()
            .map(|q| Quadratic {
                surface: q.surface,
                a: q.a,
                b: q.b,
                c: q.c,
                discriminant: q.discriminant,
                roots: q
                    .roots
                    .iter()
                    .flatten()
                    .map(|&t| {
                        let p = object_ray.at(t);
                        let counts = side_hit == Some(t);
                        let why = if counts {
                            "the object's first hit"
                        } else if t <= t_min {
                            "behind the ray's start (λ ≤ λmin)"
                        } else if bounded_height && !(-1.0..=1.0).contains(&p.y) {
                            "outside −1 ≤ y ≤ 1"
                        } else {
                            "farther than the object's first hit"
                        };
                        Root {
                            lambda: t,
                            point: point4(p),
                            counts,
                            why,
                        }
                    })
                    .collect(),
            })
            .collect();

        let faces = rec
            .faces
            .iter()
            .map(|f| {
                let counts = match (result, &hit_part) {
                    (Some((t, _)), Some(label)) => {
                        f.within && f.lambda == Some(t) && f.face == label
                    }
                    _ => false,
                };
                let why = match f.lambda {
                    None => "parallel to the face (|Δ| < 1e-12): skipped",
                    Some(_) if counts => "the object's first hit",
                    Some(_) if !f.within => "outside the face",
                    Some(t) if t <= t_min => "behind the ray's start (λ ≤ λmin)",
                    Some(_) => "farther than the object's first hit",
                };
                FaceCheck {
                    face: f.face,
                    lambda: f.lambda,
                    point: f.point.map(point4),
                    within: f.within,
                    counts,
                    why,
                }
            })
            .collect();

        let mut triangles = Vec::new();
        let mut unlisted = 0;
        let mut misses_listed = 0;
        for t in &rec.triangles {
            let counts = t.hit && result.is_some_and(|(_, p)| p == t.triangle);
            if !t.hit && misses_listed >= self.opts.max_triangles {
                unlisted += 1;
                continue;
            }
            if !t.hit {
                misses_listed += 1;
            }
            let why = match t.uvt {
                None => "parallel to the triangle's plane",
                Some(_) if counts => "the object's first hit",
                Some([a, b, _]) if a < 0.0 || b < 0.0 || a + b > 1.0 => {
                    "outside the triangle (u, v ≥ 0 and u + v ≤ 1 fail)"
                }
                Some([_, _, l]) if l <= t_min => "behind the ray's start (λ ≤ λmin)",
                Some(_) => "farther than the object's first hit",
            };
            triangles.push(TriangleCheck {
                triangle: t.triangle,
                barycentric: t.uvt.map(|[a, b, _]| [a, b]),
                lambda: t.uvt.map(|[_, _, l]| l),
                hit: t.hit,
                counts,
                why,
            });
        }

        ObjectTest {
            object: i,
            name: object.name.clone(),
            shape: shape.name(),
            inverse_transform: world.transform(i).inverse_rows(),
            object_ray: (&object_ray).into(),
            quadratics,
            faces,
            triangles,
            triangles_unlisted: unlisted,
            linear_side: shape.linear_side() && rec.quadratics.is_empty(),
            lambda: result.map(|(t, _)| t),
            part: hit_part,
            chosen,
        }
    }
}
/// How much of its ray a [`Recorder`] writes down.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Detail {
    /// Everything.
    Full,
    /// The ray and its colour only: the budget was spent when it began.
    Truncated,
    /// Nothing: a ray below a truncated one.
    Ignored,
}

/// Records one ray of the tree (and, through the recorders it hands out for its
/// secondary rays, the tree below it).
pub(super) struct Recorder<'e> {
    ex: &'e Explainer<'e>,
    role: Role,
    detail: Detail,
    ray: Ray,
    depth: u32,
    t_min: f64,
    tests: Vec<ObjectTest>,
    hit: Option<HitInfo>,
    shading: Option<Shading>,
}

impl<'e> Recorder<'e> {
    /// The recorder of the pixel's primary ray.
    pub(super) fn primary(ex: &'e Explainer<'e>) -> Self {
        Recorder::with_role(ex, Role::Primary, Detail::Full)
    }

    fn with_role(ex: &'e Explainer<'e>, role: Role, detail: Detail) -> Self {
        Recorder {
            ex,
            role,
            detail,
            // Set when the tracer begins the ray, before anything else is recorded.
            ray: Ray::new(DVec3::ZERO, DVec3::ZERO),
            depth: 0,
            t_min: 0.0,
            tests: Vec::new(),
            hit: None,
            shading: None,
        }
    }

    /// The recorded ray, which returned `colour`.
    pub(super) fn finish(self, colour: DVec3) -> RayNode {
        RayNode {
            role: self.role,
            depth: self.depth,
            ray: (&self.ray).into(),
            lambda_min: self.t_min,
            tested: self.tests.len(),
            objects: self.ex.r.world.len(),
            tests: self.tests,
            hit: self.hit,
            shading: self.shading,
            colour: colour.to_array(),
            truncated: self.detail == Detail::Truncated,
        }
    }

    fn full(&self) -> bool {
        self.detail == Detail::Full
    }
}

impl ShadingProbe for Recorder<'_> {
    fn ray(&mut self, ray: &Ray, depth: u32, t_min: f64) {
        self.ray = *ray;
        self.depth = depth;
        self.t_min = t_min;
        if self.detail == Detail::Full {
            let left = self.ex.rays_left.get();
            if left == 0 {
                self.detail = Detail::Truncated;
                self.ex.truncated.set(true);
            } else {
                self.ex.rays_left.set(left - 1);
            }
        }
    }

    fn closest(&mut self, hit: Option<&Hit>) {
        if self.full() {
            self.tests = self
                .ex
                .object_tests(&self.ray, self.t_min, hit.map(|h| h.object));
        }
    }

    fn surface(&mut self, hit: &Hit, s: &Surface, n: DVec3, m: &Material, ambient: DVec3) {
        if !self.full() {
            return;
        }
        let scene = &self.ex.r.scene;
        let object = &scene.objects[hit.object as usize];
        let shape = &object.shape;
        self.hit = Some(HitInfo {
            object: hit.object,
            name: object.name.clone(),
            shape: shape.name(),
            lambda: s.lambda,
            part: part_label(shape, hit.part),
            face: s.face.map(|f| f.label()),
            object_point: point4(s.object_point),
            point: point4(s.point),
            normal: vector4(s.normal),
            front: s.front,
        });
        self.shading = Some(Shading {
            material: m.into(),
            n: n.to_array(),
            v: (-self.ray.dir.normalize()).to_array(),
            offset: surface_offset(s.point),
            ambient: ambient.to_array(),
            lights: Vec::with_capacity(scene.lights.len()),
            reflection: None,
            refraction: None,
            no_secondary: None,
        });
    }

    fn light(&mut self, index: usize, light: &Light, term: &LightTerm, blocked: Option<bool>) {
        if !self.full() {
            return;
        }
        let Some(shading) = &mut self.shading else {
            return;
        };
        let scene = &self.ex.r.scene;
        let world = &self.ex.r.world;
        // The tracer skips the shadow ray of a light that adds nothing; the reader is
        // still told whether it is blocked.
        let blocked = blocked.unwrap_or_else(|| {
            !term.outside_cone
                && world.occluded(&term.shadow_ray, SECONDARY_LAMBDA_MIN, term.shadow_t_max)
        });
        let t = term.shadowed(blocked);
        // `occluded` only says whether; the first blocker is found here, for the reader.
        let blocker = if t.blocked {
            world
                .closest(&t.shadow_ray, SECONDARY_LAMBDA_MIN, t.shadow_t_max)
                .map(|b| Blocker {
                    object: b.object,
                    name: scene.object_name(b.object).map(str::to_owned),
                    lambda: b.lambda,
                })
        } else {
            None
        };
        let (kind, colour) = match *light {
            Light::Point { colour, .. } => ("point", colour),
            Light::Directional { colour, .. } => ("directional", colour),
            Light::Spot { colour, .. } => ("spot", colour),
        };
        shading.lights.push(LightInfo {
            light: index,
            kind,
            colour: colour.to_array(),
            shadow_ray: (&t.shadow_ray).into(),
            lambda_min: SECONDARY_LAMBDA_MIN,
            lambda_max: t.shadow_t_max.is_finite().then_some(t.shadow_t_max),
            outside_cone: t.outside_cone,
            blocked: t.blocked,
            blocker,
            l: t.l.to_array(),
            n_dot_l: t.n_dot_l,
            r_dot_v: t.r_dot_v,
            diffuse: t.diffuse.to_array(),
            specular: t.specular.to_array(),
        });
    }

    fn no_secondary(&mut self, why: NoSecondary) {
        if !self.full() {
            return;
        }
        let Some(shading) = &mut self.shading else {
            return;
        };
        shading.no_secondary = Some(match why {
            NoSecondary::Material => "the material has neither mirror nor transmission".to_owned(),
            NoSecondary::MaxDepth => format!(
                "depth {} reached max_depth {}: no further rays",
                self.depth, self.ex.r.scene.max_depth
            ),
        });
    }

    fn secondary(&mut self, branch: Branch, bounce: &Bounce) -> Self {
        let role = match branch {
            Branch::Reflection => Role::Reflected,
            Branch::Refraction if bounce.total_internal_reflection => Role::TotalInternalReflection,
            Branch::Refraction => Role::Refracted,
        };
        let detail = if self.full() {
            Detail::Full
        } else {
            Detail::Ignored
        };
        Recorder::with_role(self.ex, role, detail)
    }

    fn secondary_done(
        &mut self,
        branch: Branch,
        child: Self,
        coefficient: DVec3,
        colour: DVec3,
        contribution: DVec3,
    ) {
        if !self.full() {
            return;
        }
        let Some(shading) = &mut self.shading else {
            return;
        };
        let secondary = Some(Box::new(Secondary {
            coefficient: coefficient.to_array(),
            ray: child.finish(colour),
            contribution: contribution.to_array(),
        }));
        match branch {
            Branch::Reflection => shading.reflection = secondary,
            Branch::Refraction => shading.refraction = secondary,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grade::explain::tests::{SHAPE_SCENES, bits, renderer};
    use crate::grade::explain::{ExplainOptions, explain};

    /// Adds up a node's recorded terms in the tracer's order (a light the tracer skips
    /// adds nothing) and checks they give the node's colour exactly, down the tree.
    fn assert_sums(node: &RayNode, background: DVec3, at: &str) {
        if node.truncated {
            return;
        }
        let Some(s) = &node.shading else {
            assert_eq!(
                node.colour,
                background.to_array(),
                "{at}: a miss is the background"
            );
            return;
        };
        let mut c = DVec3::from_array(s.ambient);
        for l in &s.lights {
            let lit = DVec3::from_array(l.diffuse) + DVec3::from_array(l.specular);
            if !l.outside_cone && !l.blocked && lit != DVec3::ZERO {
                c += lit;
            }
        }
        for sec in [&s.reflection, &s.refraction].into_iter().flatten() {
            let add = DVec3::from_array(sec.coefficient) * DVec3::from_array(sec.ray.colour);
            assert_eq!(bits(sec.contribution), bits(add.to_array()), "{at}");
            c += add;
            assert_sums(&sec.ray, background, at);
        }
        assert_eq!(bits(node.colour), bits(c.to_array()), "{at}");
    }

    /// The recorded terms are the ones the tracer summed: every node of every tree of
    /// small scenes of every shape (and of the showcase, which has every light and
    /// material) adds up to its colour bit for bit.
    #[test]
    fn every_shape_tree_sums_like_the_tracer() {
        for name in SHAPE_SCENES.into_iter().chain(["showcase.json"]) {
            let r = renderer(name);
            let step = (r.scene.width / 40).max(7) as usize;
            for v in (0..r.scene.height).step_by(step) {
                for u in (0..r.scene.width).step_by(step) {
                    let e = explain(&r, u, v, &ExplainOptions::default());
                    assert_sums(&e.tree, r.scene.background, &format!("{name} ({u}, {v})"));
                }
            }
        }
    }

    /// A ray past the budget keeps its place and colour; the rays below it are traced
    /// (their colours count) but not recorded, and take no budget from their siblings.
    #[test]
    fn the_budget_is_spent_in_the_order_rays_are_traced() {
        let r = renderer("showcase.json");
        // The glass ball: a reflected and a refracted ray below the primary one.
        let opts = ExplainOptions {
            max_rays: 2,
            ..Default::default()
        };
        let e = explain(&r, 640, 470, &opts);
        let s = e.tree.shading.as_ref().unwrap();
        let reflected = &s.reflection.as_ref().unwrap().ray;
        let refracted = &s.refraction.as_ref().unwrap().ray;
        assert_eq!(reflected.role, Role::Reflected);
        assert!(!reflected.truncated);
        assert!(refracted.truncated);
        assert!(refracted.tests.is_empty() && refracted.shading.is_none());
        let full = explain(&r, 640, 470, &ExplainOptions::default());
        let whole = &full
            .tree
            .shading
            .as_ref()
            .unwrap()
            .refraction
            .as_ref()
            .unwrap()
            .ray;
        assert_eq!(bits(refracted.colour), bits(whole.colour));
        assert_eq!(refracted.ray, whole.ray);
        assert_eq!(refracted.role, whole.role);
    }
}
