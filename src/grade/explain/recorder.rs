//! The recorder: a [`ShadingProbe`] that builds the ray tree while the tracer shades the
//! pixel. Every value it records is one the tracer computed (or, for a shape test's
//! details, one the shape test reported through [`Probe`]); it adds only what a reader
//! needs beyond the colour: every candidate object's test, and the state of shadow rays
//! the tracer had no need to cast.

use std::cell::{Cell, RefCell};

use glam::DVec3;

use super::model::{
    Blocker, FaceCheck, HitInfo, LightInfo, ObjectTest, Quadratic, RayNode, Role, Root, Secondary,
    Shading, SpentAt, TriangleCheck, point4, vector4,
};
use super::{Candidates, ExplainOptions, MAX_ANSWER_BYTES, MAX_LIGHTS_LISTED};
use crate::geometry::hit::{FaceTest, Probe, QuadraticTest, TriangleTest};
use crate::geometry::{Hit, Ray, Shape, Surface, World};
use crate::render::Renderer;
use crate::render::shade::{
    Branch, LightTerm, NoSecondary, SECONDARY_LAMBDA_MIN, ShadingProbe, surface_offset,
};
use crate::scene::{Light, Material};

/// Records what a shape test reports. Triangle tests are kept only up to `cap` misses
/// and `cap` hits (a mesh of a million coincident triangles reports a million hits), plus
/// the best hit past the cap, which may be the one that counts.
#[derive(Default)]
struct TestRecorder {
    object_ray: Option<Ray>,
    quadratics: Vec<QuadraticTest>,
    faces: Vec<FaceTest>,
    triangles: Vec<TriangleTest>,
    cap: usize,
    misses_kept: usize,
    hits_kept: usize,
    unlisted: usize,
    best_unlisted: Option<TriangleTest>,
}

impl TestRecorder {
    fn new(cap: usize) -> Self {
        TestRecorder {
            cap,
            ..Default::default()
        }
    }

    /// The mesh's rule for its hit: the smallest `λ`, a tie to the triangle listed first.
    fn better(t: &TriangleTest, than: &TriangleTest) -> bool {
        let key = |t: &TriangleTest| (t.uvt.map_or(f64::INFINITY, |[_, _, l]| l), t.triangle);
        let (a, b) = (key(t), key(than));
        a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
    }
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
        let kept = if t.hit {
            &mut self.hits_kept
        } else {
            &mut self.misses_kept
        };
        if *kept < self.cap {
            *kept += 1;
            self.triangles.push(*t);
            return;
        }
        self.unlisted += 1;
        if t.hit
            && self
                .best_unlisted
                .as_ref()
                .is_none_or(|b| Self::better(t, b))
        {
            self.best_unlisted = Some(*t);
        }
    }
    fn active(&self) -> bool {
        true
    }
}

/// The name of a part of a shape, as the shape files number them.
pub fn part_label(shape: &Shape, part: u32) -> String {
    shape.part_label(part).into_owned()
}

/// What every ray of one explanation shares: the scene, the options, the budgets of rays
/// still to break down and of answer bytes still to write, and what was left out.
pub(super) struct Explainer<'a> {
    r: &'a Renderer,
    opts: &'a ExplainOptions,
    mode: Candidates,
    rays_left: Cell<usize>,
    truncated: Cell<bool>,
    bytes_left: Cell<usize>,
    /// Rays numbered as the text numbers them: from 1, in the order they are traced.
    rays_numbered: Cell<usize>,
    spent_at: RefCell<Option<SpentAt>>,
    rays_not_broken_down: Cell<usize>,
    tests_unlisted: Cell<usize>,
    triangles_unlisted: Cell<usize>,
    lights_unlisted: Cell<usize>,
}

/// What an explanation left out, as [`Explainer::left_out`] reports it.
pub(super) struct LeftOut {
    pub(super) bytes: usize,
    pub(super) spent_at: Option<SpentAt>,
    pub(super) rays_not_broken_down: usize,
    pub(super) tests_unlisted: usize,
    pub(super) triangles_unlisted: usize,
    pub(super) lights_unlisted: usize,
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
            bytes_left: Cell::new(MAX_ANSWER_BYTES),
            rays_numbered: Cell::new(0),
            spent_at: RefCell::new(None),
            rays_not_broken_down: Cell::new(0),
            tests_unlisted: Cell::new(0),
            triangles_unlisted: Cell::new(0),
            lights_unlisted: Cell::new(0),
        }
    }

    /// Whether some ray was left unexplained because the ray budget was spent.
    pub(super) fn truncated(&self) -> bool {
        self.truncated.get()
    }

    /// What was left out, once the tracer is done.
    pub(super) fn left_out(&self) -> LeftOut {
        LeftOut {
            bytes: MAX_ANSWER_BYTES - self.bytes_left.get(),
            spent_at: self.spent_at.borrow().clone(),
            rays_not_broken_down: self.rays_not_broken_down.get(),
            tests_unlisted: self.tests_unlisted.get(),
            triangles_unlisted: self.triangles_unlisted.get(),
            lights_unlisted: self.lights_unlisted.get(),
        }
    }

    /// Whether the size budget is spent: nothing more is written but what keeps the tree
    /// whole (a ray's place and colour, its chosen hit).
    fn spent(&self) -> bool {
        self.bytes_left.get() == 0
    }

    /// Charges `n` bytes to the budget; the first charge it cannot pay in full marks where
    /// the budget ran out.
    fn spend(&self, n: usize, at: &Place) {
        let left = self.bytes_left.get();
        self.bytes_left.set(left.saturating_sub(n));
        if n >= left && left > 0 {
            *self.spent_at.borrow_mut() = Some(SpentAt {
                ray: at.number,
                pointer: at.pointer.clone(),
            });
        }
    }

    fn count(cell: &Cell<usize>, n: usize) {
        cell.set(cell.get().saturating_add(n));
    }

    /// The tests of the candidate objects, each searched over `(t_min, ∞)` on its own:
    /// at most `max_tests` of them and the chosen one, while the budget lasts. Returns
    /// them with the number of candidates (listed or not).
    fn object_tests(
        &self,
        ray: &Ray,
        t_min: f64,
        chosen: Option<u32>,
        at: &Place,
    ) -> (Vec<ObjectTest>, usize) {
        let world: &World = &self.r.world;
        let bvh;
        let list: &mut dyn Iterator<Item = u32> = match self.mode {
            Candidates::Bvh => {
                bvh = world.candidates(ray, t_min, f64::INFINITY);
                &mut bvh.iter().copied()
            }
            _ => &mut (0..world.len() as u32),
        };
        let mut all = 0;
        let mut tests = Vec::new();
        for i in list {
            all += 1;
            let is_chosen = chosen == Some(i);
            if !is_chosen && (tests.len() >= self.opts.max_tests || self.spent()) {
                continue;
            }
            let t = self.object_test(i, ray, t_min, is_chosen);
            // Within the answer: tree, tests, the test; three more levels a depth.
            self.spend(pretty_size(&t, 3 + 3 * at.depth), at);
            tests.push(t);
        }
        Self::count(&self.tests_unlisted, all - tests.len());
        (tests, all)
    }

    fn object_test(&self, i: u32, ray: &Ray, t_min: f64, chosen: bool) -> ObjectTest {
        let world = &self.r.world;
        let object = &self.r.scene.objects[i as usize];
        let shape = &object.shape;
        let mut rec = TestRecorder::new(self.opts.max_triangles);
        let result = world.intersect_object(i, ray, t_min, f64::INFINITY, &mut rec);
        let object_ray = rec
            .object_ray
            .unwrap_or_else(|| ray.transformed(&object.transform.inverse));
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

        // The tests past the cap were not kept, but the one that counts always is.
        if let (Some(b), Some((_, part))) = (rec.best_unlisted, result)
            && b.triangle == part
        {
            rec.triangles.push(b);
            rec.unlisted -= 1;
        }
        Self::count(&self.triangles_unlisted, rec.unlisted);
        let mut triangles = Vec::with_capacity(rec.triangles.len());
        for t in &rec.triangles {
            let counts = t.hit && result.is_some_and(|(_, p)| p == t.triangle);
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
            inverse_transform: object.transform.inverse_rows(),
            object_ray: (&object_ray).into(),
            quadratics,
            faces,
            triangles,
            triangles_unlisted: rec.unlisted,
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

/// Where a ray sits in the answer: its number as the text gives it, and its JSON pointer.
pub(super) struct Place {
    number: usize,
    depth: usize,
    pointer: String,
}

/// Counts what is written to it: the size of a piece of the answer.
#[derive(Default)]
struct Measure {
    bytes: usize,
    lines: usize,
}

impl std::io::Write for Measure {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.bytes += b.len();
        self.lines += b.iter().filter(|&&c| c == b'\n').count();
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The bytes `v` takes in the pretty-printed answer, `level` objects deep (two spaces
/// a level on each of its lines).
fn pretty_size<T: serde::Serialize>(v: &T, level: usize) -> usize {
    let mut m = Measure::default();
    // Writing to a counter cannot fail, and these types always serialise.
    let _ = serde_json::to_writer_pretty(&mut m, v);
    m.bytes + (m.lines + 1) * 2 * level
}

/// A ray's own fields (its ray, hit, material, terms), about 60 lines of the answer at
/// `level`: charged when it begins, before they are known.
fn node_size(level: usize) -> usize {
    60 * (24 + 2 * level)
}

/// Records one ray of the tree (and, through the recorders it hands out for its
/// secondary rays, the tree below it).
pub(super) struct Recorder<'e> {
    ex: &'e Explainer<'e>,
    role: Role,
    detail: Detail,
    place: Place,
    ray: Ray,
    depth: u32,
    t_min: f64,
    tested: usize,
    tests: Vec<ObjectTest>,
    hit: Option<HitInfo>,
    shading: Option<Shading>,
}

impl<'e> Recorder<'e> {
    /// The recorder of the pixel's primary ray.
    pub(super) fn primary(ex: &'e Explainer<'e>) -> Self {
        Recorder::with_role(ex, Role::Primary, Detail::Full, "/tree".to_owned())
    }

    fn with_role(ex: &'e Explainer<'e>, role: Role, detail: Detail, pointer: String) -> Self {
        Recorder {
            ex,
            role,
            detail,
            // Numbered when the tracer begins the ray.
            place: Place {
                number: 0,
                depth: 0,
                pointer,
            },
            // Set when the tracer begins the ray, before anything else is recorded.
            ray: Ray::new(DVec3::ZERO, DVec3::ZERO),
            depth: 0,
            t_min: 0.0,
            tested: 0,
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
            tested: self.tested,
            objects: self.ex.r.world.len(),
            tests_unlisted: self.tested - self.tests.len(),
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
        if self.detail == Detail::Ignored {
            return;
        }
        self.place.depth = depth as usize;
        let ex = self.ex;
        ex.rays_numbered.set(ex.rays_numbered.get() + 1);
        self.place.number = ex.rays_numbered.get();
        let left = ex.rays_left.get();
        if left == 0 {
            self.detail = Detail::Truncated;
            ex.truncated.set(true);
        } else if ex.spent() {
            self.detail = Detail::Truncated;
        } else {
            ex.rays_left.set(left - 1);
        }
        if self.detail == Detail::Truncated {
            Explainer::count(&ex.rays_not_broken_down, 1);
        }
        ex.spend(node_size(2 + 3 * self.place.depth), &self.place);
    }

    fn closest(&mut self, hit: Option<&Hit>) {
        if self.full() {
            (self.tests, self.tested) =
                self.ex
                    .object_tests(&self.ray, self.t_min, hit.map(|h| h.object), &self.place);
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
            lights: Vec::with_capacity(scene.lights.len().min(MAX_LIGHTS_LISTED)),
            lights_unlisted: 0,
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
        if shading.lights.len() >= MAX_LIGHTS_LISTED || self.ex.spent() {
            shading.lights_unlisted += 1;
            Explainer::count(&self.ex.lights_unlisted, 1);
            return;
        }
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
        let info = LightInfo {
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
        };
        // Within the answer: tree, shading, lights, the light; three more levels a depth.
        self.ex
            .spend(pretty_size(&info, 4 + 3 * self.place.depth), &self.place);
        shading.lights.push(info);
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

    fn secondary(&mut self, branch: Branch, total_internal_reflection: bool) -> Self {
        let role = match branch {
            Branch::Reflection => Role::Reflected,
            Branch::Refraction if total_internal_reflection => Role::TotalInternalReflection,
            Branch::Refraction => Role::Refracted,
        };
        if !self.full() {
            return Recorder::with_role(self.ex, role, Detail::Ignored, String::new());
        }
        let field = match branch {
            Branch::Reflection => "reflection",
            Branch::Refraction => "refraction",
        };
        let pointer = format!("{}/shading/{field}/ray", self.place.pointer);
        Recorder::with_role(self.ex, role, Detail::Full, pointer)
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

    /// A mesh of a thousand coincident triangles reports a thousand hits: at most
    /// `max_triangles` misses and as many other hits are listed, and the one that counts.
    #[test]
    fn coincident_triangles_are_listed_up_to_the_cap() {
        let k = 1000;
        let scene = serde_json::json!({
            "version": 1,
            "image": {"width": 5, "height": 5},
            "camera": {"focal_length": 1},
            "objects": [{
                "shape": "mesh",
                "positions": [[-1, -1, 3], [1, -1, 3], [0, 1, 3]],
                "indices": vec![[0, 1, 2]; k]
            }],
            "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]
        });
        let bytes = serde_json::to_vec(&scene).unwrap();
        let r = Renderer::new(std::sync::Arc::new(
            crate::scene::parse(&bytes, &crate::scene::Limits::NONE).unwrap(),
        ));
        let opts = ExplainOptions::default();
        let e = explain(&r, 2, 2, &opts);
        let t = &e.tree.tests[0];
        let part = e.tree.hit.as_ref().unwrap().part.clone();
        assert!(t.triangles.len() <= 2 * opts.max_triangles + 1);
        assert_eq!(t.triangles.len() + t.triangles_unlisted, k);
        let counting: Vec<_> = t.triangles.iter().filter(|c| c.counts).collect();
        assert_eq!(counting.len(), 1);
        assert_eq!(
            part_label(&r.scene.objects[0].shape, counting[0].triangle),
            part
        );
        assert_eq!(e.truncation.triangles_unlisted, t.triangles_unlisted);
        assert!(e.truncated);
    }
}
