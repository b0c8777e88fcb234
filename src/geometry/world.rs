//! The traceable world: every object prepared for intersection, a BVH over the bounded
//! ones, and the unbounded ones (planes) kept aside and tested for every ray.
//!
//! `closest` finds the first hit with the cheap record only; `surface` then computes
//! the point, object point, normal and face of that one hit.

use std::num::NonZeroU32;
use std::sync::Arc;

use glam::{DAffine3, DVec3};
use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
use super::bounds::x86::Avx2;
use super::{
    arith::{Arith, Eight, Lanes4, One, Portable},
    bounds::{Aabb, SlabRay, SlabRay4, SlabRays8, WideTest, lanes_of, lanes_where},
    bvh::{Bvh, TreeRay},
    hit::{Hit, Probe, Surface},
    ray::{Ray, Rays8},
    shapes::{Shape, plane},
    transform::Transform,
};

/// What testing a ray against an object costs, in tests of a BVH node's boxes (see
/// [`Bvh::build`]): its ray carried into object space, then the shape's own test, about
/// two. Against the one a triangle is given, this took the instructions of tracing
/// `cubes-10k` down 11 %, `spheres-1k` 4 % and `spheres-100k` 3 %; four bought a
/// further 0.5 % at most.
const OBJECT_TEST_COST: f64 = 2.0;

/// How many parts a shape's flat parts are looked for among (a cube's six faces).
const FLAT_PARTS: usize = 6;

/// The unit world normal of the object-space normal `n` of an object carried by
/// `object_from_world`: `(M⁻¹)ᵀ n`, normalised.
#[inline(always)]
fn world_normal(object_from_world: &DAffine3, n: DVec3) -> DVec3 {
    // `(M⁻¹)ᵀ`: the transpose is a reading order, not arithmetic.
    object_from_world
        .matrix3
        .transpose()
        .mul_vec3(n)
        .normalize()
}

/// The world normals of an object's flat parts ([`Shape::flat_normal`]), by part:
/// found once, so that a hit there takes its normal without a product and a square
/// root, which the shading of the hit waited on (three of four of `classic`'s primary
/// rays hit its floor). Boxed: most objects of a large scene have none.
#[derive(Debug, Clone)]
struct FlatNormals(Box<[Option<DVec3>; FLAT_PARTS]>);

impl FlatNormals {
    /// Those of `shape` carried by `object_from_world`, if it has flat parts.
    fn of(shape: &Shape, object_from_world: &DAffine3) -> Option<FlatNormals> {
        let normals: [Option<DVec3>; FLAT_PARTS] = std::array::from_fn(|part| {
            let n = shape.flat_normal(part as u32)?;
            Some(world_normal(object_from_world, n))
        });
        normals
            .iter()
            .any(Option::is_some)
            .then(|| FlatNormals(Box::new(normals)))
    }
}

/// What every ray test of an object reads (kept small: it is the hot data).
#[derive(Debug, Clone)]
struct Solid {
    /// `object_from_world`, the map every ray takes into object space.
    object_from_world: DAffine3,
    /// The viewpoint in object space (see [`World::set_viewpoint`]).
    view_origin: DVec3,
    /// Prepared (see [`Shape::prepare`]) before the first ray.
    shape: Shape,
    /// Its flat parts' world normals, if it has flat parts: here, where a hit's
    /// record has just read the object's map, not in a list of their own, which cost
    /// a scene of 100 000 spheres a cache miss a hit (1 % more render time).
    flat: Option<FlatNormals>,
}

impl Solid {
    /// `ray` in object space; `from_view` says it starts at the viewpoint.
    #[inline(always)]
    fn object_ray(&self, ray: &Ray, from_view: bool) -> Ray {
        if from_view {
            let m = &self.object_from_world.matrix3;
            Ray {
                origin: self.view_origin,
                dir: DVec3::from_array(One.carry_vector(m, ray.dir.to_array())),
            }
        } else {
            ray.transformed(&self.object_from_world)
        }
    }

    /// A packet's rays carried into object space in lanes (origins, then directions),
    /// as [`Solid::object_ray`] carries each (so the same bits); `view` says that every
    /// ray the answer is read for starts at the viewpoint. A test that reads only some
    /// coordinates (a plane's height and climb) leaves the others to be dropped by the
    /// compiler, since all of it is inlined.
    #[allow(clippy::type_complexity)]
    #[inline(always)]
    fn object_rays8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: &Rays8,
        view: bool,
    ) -> ([[L::V; 2]; 3], [[L::V; 2]; 3]) {
        let m = &self.object_from_world;
        let dir = n.carry_vector(&m.matrix3, n.load3(&rays.dir));
        let origin = if view {
            n.splat3(self.view_origin)
        } else {
            n.carry_point(m, n.load3(&rays.origin))
        };
        (origin, dir)
    }

    /// The packet's rays tested in lanes, for a shape that has a test in lanes
    /// ([`Shape::intersect_in_lanes8`]): the lanes that hit, and each one's `λ` and
    /// part; `None` for other shapes, whose rays are then not carried (`view` as for
    /// [`Solid::object_rays8`]).
    #[allow(clippy::type_complexity)]
    #[inline(always)]
    fn intersect_in_lanes8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: &[Ray; 8],
        view: bool,
        t_min: f64,
        t_max: &[f64; 8],
    ) -> Option<(u32, [f64; 8], [u32; 8])> {
        self.shape.intersect_in_lanes8(
            n,
            #[inline(always)]
            || self.object_rays8(n, &Rays8::from_rays(rays), view),
            t_min,
            t_max,
        )
    }

    /// A plane's test ([`plane::lambdas_from_y`]) of a packet's rays, from their
    /// heights and climbs in object space (`view` as for [`Solid::object_rays8`]).
    #[inline(always)]
    fn plane8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: &Rays8,
        view: bool,
        t_min: f64,
        t_max: &[f64; 8],
    ) -> (u32, [f64; 8]) {
        let (origin, dir) = self.object_rays8(n, rays, view);
        let (hit, lambda) = plane::lambdas_from_y(n, origin[1], dir[1], t_min, n.load(t_max));
        (hit, n.store(lambda))
    }

    /// The y components of [`Solid::object_ray`]'s origin and direction, computed
    /// alone in the same order (so bit for bit the same): all a plane's test reads.
    #[inline(always)]
    fn object_y(&self, ray: &Ray, from_view: bool) -> (f64, f64) {
        let m = &self.object_from_world;
        let origin = if from_view {
            self.view_origin.y
        } else {
            One.carry_coordinate(&m.matrix3, 1, ray.origin.to_array()) + m.translation.y
        };
        (
            origin,
            One.carry_coordinate(&m.matrix3, 1, ray.dir.to_array()),
        )
    }
}

/// The objects of a scene, prepared and indexed. Their `world_from_object` transforms
/// stay in the scene: only a hit's record needs more than `object_from_world`, and that
/// record's normal map `(M⁻¹)ᵀ` is the solid's matrix read transposed.
#[derive(Debug, Clone)]
pub struct World {
    solids: Vec<Solid>,
    bvh: Bvh,
    /// Objects without bounds (planes), in scene order.
    unbounded: Vec<u32>,
    /// A point many rays start from (the camera), carried into every object's space once.
    viewpoint: Option<DVec3>,
}

/// `$body` with `$n` the widest lanes of [`Eight`] this processor has: AVX2 where it
/// has them, else SSE2. The AVX2 lanes are single instructions only where the caller
/// is compiled for AVX2 (inside [`with_avx2`] or the tree's traversal): a `run` of
/// their own stayed a call (3 % more instructions in `spheres-1k`'s hit data).
macro_rules! in_lanes {
    ($n:ident => $body:expr) => {{
        #[cfg(target_arch = "x86_64")]
        let found = match Avx2::detect() {
            Some(avx2) => {
                let $n = Eight(avx2);
                $body
            }
            None => {
                let $n = Eight(Portable);
                $body
            }
        };
        #[cfg(not(target_arch = "x86_64"))]
        let found = {
            let $n = Eight(Portable);
            $body
        };
        found
    }};
}

/// `f()`, inlined into code compiled for AVX2 where the processor has it.
#[inline(always)]
fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = Avx2::detect() {
        return avx2.run(f);
    }
    f()
}

/// Takes what object `i`'s test `found` (`λ`, part) as the best hit when it is nearer
/// than `limit`, or ties the best so far and ranks before it ([`Hit::before`]); returns
/// the new limit. What a ray finds does not depend on the order objects are tested in.
#[inline(always)]
fn keep_first(best: &mut Option<Hit>, i: u32, found: Option<(f64, u32)>, limit: f64) -> f64 {
    if let Some((lambda, part)) = found {
        let h = Hit {
            lambda,
            object: i,
            part,
        };
        if lambda < limit || best.is_some_and(|b| h.before(&b)) {
            *best = Some(h);
            return lambda;
        }
    }
    limit
}

/// A packet's first hits so far ([`World::closest8`]), and the limit each lane's next
/// test takes: `next_up` of the lane's limit (which lets an equal λ through, so the
/// tie rule can see it), kept beside it and computed again only where a hit lowers
/// it, not before every test.
struct Best8 {
    hit: [Option<Hit>; 8],
    below: [f64; 8],
}

impl Best8 {
    /// No hit yet, each lane to `t_max`.
    #[inline(always)]
    fn new(t_max: f64) -> Best8 {
        Best8 {
            hit: [None; 8],
            below: [t_max.next_up(); 8],
        }
    }

    /// Takes what object `i`'s test `found` for `lane` by [`keep_first`], `limit` the
    /// lane's.
    #[inline(always)]
    fn keep(&mut self, lane: usize, i: u32, found: Option<(f64, u32)>, limit: &mut f64) {
        if found.is_some() {
            *limit = keep_first(&mut self.hit[lane], i, found, *limit);
            self.below[lane] = limit.next_up();
        }
    }
}

impl World {
    /// Prepares `(shape, world_from_object)` pairs, in scene order, and builds the BVH.
    pub fn new<'a>(objects: impl IntoIterator<Item = (&'a Shape, &'a Transform)>) -> World {
        let objects: Vec<(&Shape, &Transform)> = objects.into_iter().collect();
        // Meshes build their BVH here, one after another, each on every worker and
        // outside its lock (`CanonicalShape::prepare`).
        for (shape, _) in &objects {
            shape.prepare();
        }
        // The rest is object by object, on every worker, collected in place: most of
        // it is page faults of the new vectors (100 000 spheres: the build went from
        // 0.092 to 0.078 s on two threads).
        let (bounds, solids): (Vec<_>, Vec<_>) = objects
            .par_iter()
            .map(|&(shape, t)| {
                let solid = Solid {
                    object_from_world: t.inverse,
                    view_origin: DVec3::ZERO,
                    shape: shape.clone(),
                    flat: FlatNormals::of(shape, &t.inverse),
                };
                (shape.world_bounds(t), solid)
            })
            .unzip();
        let mut unbounded = Vec::new();
        let bounds: Vec<Aabb> = (0..)
            .zip(bounds)
            .map(|(i, b)| {
                b.unwrap_or_else(|| {
                    unbounded.push(i);
                    Aabb::EMPTY
                })
            })
            .collect();
        World {
            // No lock is held here.
            bvh: Bvh::build_in_parallel(&bounds, OBJECT_TEST_COST),
            solids,
            unbounded,
            viewpoint: None,
        }
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        self.solids.len()
    }

    /// Whether there are no objects.
    pub fn is_empty(&self) -> bool {
        self.solids.is_empty()
    }

    /// A box around every bounded object (every object but the planes): a ray that
    /// misses it can meet only the unbounded ones.
    pub fn bounds(&self) -> Aabb {
        self.bvh.bounds()
    }

    /// Declares the point most rays start from (the camera). Each object keeps it in
    /// object space, so a ray from there is carried into the object by its direction
    /// alone; the origin is the same `object_from_world · o` either way, bit for bit.
    pub fn set_viewpoint(&mut self, o: DVec3) {
        for s in &mut self.solids {
            s.view_origin = DVec3::from_array(One.carry_point(&s.object_from_world, o.to_array()));
        }
        self.viewpoint = Some(o);
    }

    /// Tests object `i` alone: `λ` in `(t_min, t_max)` and the part hit.
    #[inline]
    pub fn intersect_object<P: Probe>(
        &self,
        i: u32,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        self.intersect_object_from(
            i,
            ray,
            self.viewpoint == Some(ray.origin),
            t_min,
            t_max,
            probe,
        )
    }

    #[inline(always)]
    fn intersect_object_from<P: Probe>(
        &self,
        i: u32,
        ray: &Ray,
        from_view: bool,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        let s = &self.solids[i as usize];
        let r = s.object_ray(ray, from_view);
        if probe.active() {
            probe.object(i, &r);
        }
        s.shape.intersect(&r, t_min, t_max, probe)
    }

    /// [`World::intersect_object_from`] for an unbounded object, which every ray meets:
    /// a plane's test from the ray's height alone (a third of carrying the whole ray
    /// into its space), unless a probe wants the object's ray.
    #[inline(always)]
    fn intersect_unbounded<P: Probe>(
        &self,
        i: u32,
        ray: &Ray,
        from_view: bool,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        let s = &self.solids[i as usize];
        if matches!(s.shape, Shape::Plane) && !probe.active() {
            let (y0, dy) = s.object_y(ray, from_view);
            return plane::lambda_from_y(y0, dy, t_min, t_max).map(|t| (t, 0));
        }
        self.intersect_object_from(i, ray, from_view, t_min, t_max, probe)
    }

    /// The first hit in `(t_min, t_max)`; ties go to the object listed first.
    #[inline]
    pub fn closest(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        self.closest_probed(ray, t_min, t_max, &mut ())
    }

    /// [`World::closest`], reporting every test to `probe`.
    #[inline]
    pub fn closest_probed<P: Probe>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let from_view = self.viewpoint == Some(ray.origin);
        let mut limit = t_max;
        // `next_up` lets an equal λ through, so the tie rule can see it.
        for &i in &self.unbounded {
            let found = self.intersect_unbounded(i, ray, from_view, t_min, limit.next_up(), probe);
            limit = keep_first(&mut best, i, found, limit);
        }
        let mut consider = |i: u32, limit: f64, probe: &mut P| -> f64 {
            let found =
                self.intersect_object_from(i, ray, from_view, t_min, limit.next_up(), probe);
            keep_first(&mut best, i, found, limit)
        };
        let slab = SlabRay::new(ray.origin, ray.dir);
        self.bvh
            .closest(&slab, t_min, limit, |i, limit| consider(i, limit, probe));
        best
    }

    /// [`World::closest`] for eight rays at once, traversing the BVH with them as a
    /// packet (neighbouring primary rays take much the same path): each ray's hit is
    /// the one it finds alone, bit for bit. Rays whose numbers the packet's
    /// single-precision test does not take are traced one at a time.
    ///
    /// Only the rays of `active` (a bit a lane) are traced; the others find `None`. They
    /// still go into the packet's box test, so a copy of an active ray serves best
    /// there: a ray that test does not take sends the whole packet one ray at a time.
    /// `bounded` false says the caller knows that no ray of the packet meets
    /// [`World::bounds`]: only the unbounded objects are tested.
    ///
    /// `view` says that the caller knows every ray to start at the viewpoint (a
    /// packet of primary rays): each object then takes its rays from the viewpoint's
    /// origin in its space, carried once ([`World::set_viewpoint`]). Else none is
    /// taken to, and each ray's origin is carried into each object's space, by the
    /// same arithmetic: the same numbers for a ray that does start there. Told rather
    /// than found by comparing every ray's origin with the viewpoint: with the
    /// records' comparisons ([`World::view_surface`]), they were 6 % of `spheres-1k`'s
    /// hit data instructions and 8 % of `classic`'s.
    pub fn closest8(
        &self,
        rays: &[Ray; 8],
        view: bool,
        active: u32,
        t_min: f64,
        t_max: f64,
        bounded: bool,
    ) -> [Option<Hit>; 8] {
        if active == 0 || !bounded && self.unbounded.is_empty() {
            return [None; 8];
        }
        let (lone, slab) = match self.lone() {
            _ if !bounded => (None, None),
            Some(i) => (Some(i), None),
            None => match SlabRay4::pair_from(rays, view) {
                Some(slab) => (None, Some(slab)),
                None => {
                    let mut best = [None; 8];
                    for lane in lanes_of(active) {
                        best[lane] = self.closest(&rays[lane], t_min, t_max);
                    }
                    return best;
                }
            },
        };
        debug_assert!(!view || rays.iter().all(|r| self.is_viewpoint(r)));
        let mut best = Best8::new(t_max);
        let mut limit = [t_max; 8];
        if !self.unbounded.is_empty() {
            with_avx2(
                #[inline(always)]
                || self.unbounded8(rays, view, t_min, active, &mut limit, &mut best),
            );
        }
        if let Some(i) = lone {
            // Compiled for AVX2 where the processor has it, as the traversal's leaves
            // are, so that a sphere's lanes (`consider8`) inline.
            with_avx2(
                #[inline(always)]
                || self.consider8(i, rays, view, t_min, active, &mut limit, &mut best),
            );
        }
        if let Some(slab) = slab {
            self.bvh.closest8::<false, _>(
                &slab,
                t_min,
                &mut limit,
                active,
                // Inlined into each traversal that calls it (the BVH has one per lane
                // width).
                #[inline(always)]
                |objects, active, limit| {
                    for &i in objects {
                        self.consider8(i, rays, view, t_min, active, limit, &mut best);
                    }
                },
            );
        }
        best.hit
    }

    /// The unbounded objects for the rays of `active` (of [`World::closest8`], `view`
    /// as there), each taken by the rule of `closest_probed`: a plane tests the eight
    /// in lanes ([`Solid::plane8`]), anything else one ray at a time.
    #[inline(always)]
    fn unbounded8(
        &self,
        rays: &[Ray; 8],
        view: bool,
        t_min: f64,
        active: u32,
        limit: &mut [f64; 8],
        best: &mut Best8,
    ) {
        for &i in &self.unbounded {
            let s = &self.solids[i as usize];
            if let Shape::Plane = s.shape {
                let below = &best.below;
                let (hit, lambda) =
                    in_lanes!(n => s.plane8(n, &Rays8::from_rays(rays), view, t_min, below));
                for lane in lanes_of(active & hit) {
                    best.keep(lane, i, Some((lambda[lane], 0)), &mut limit[lane]);
                }
                continue;
            }
            for lane in lanes_of(active) {
                let (r, below) = (&rays[lane], best.below[lane]);
                let found = self.intersect_unbounded(i, r, view, t_min, below, &mut ());
                best.keep(lane, i, found, &mut limit[lane]);
            }
        }
    }

    /// Object `i` for the rays of `active` (of [`World::closest8`], `view` as there),
    /// each taken by the rule of `closest_probed`, so the same hits. `next_up` lets an
    /// equal λ through.
    /// Spheres, cubes, cylinders, cones and disks take the eight rays in lanes
    /// ([`Solid::intersect_in_lanes8`]), other shapes one at a time unless they have a
    /// packet test of their own.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn consider8(
        &self,
        i: u32,
        rays: &[Ray; 8],
        view: bool,
        t_min: f64,
        active: u32,
        limit: &mut [f64; 8],
        best: &mut Best8,
    ) {
        let s = &self.solids[i as usize];
        let below = &best.below;
        let in_lanes = in_lanes!(n => s.intersect_in_lanes8(n, rays, view, t_min, below));
        if let Some((hit, lambda, part)) = in_lanes {
            for lane in lanes_of(active & hit) {
                best.keep(lane, i, Some((lambda[lane], part[lane])), &mut limit[lane]);
            }
            return;
        }
        // Told that every ray starts at the viewpoint, inactive lanes too, each lane is
        // carried, so that the shape may take the object rays' one origin as told.
        let carried = if view { 0xff } else { active };
        let mut object = *rays;
        for lane in lanes_of(carried) {
            object[lane] = s.object_ray(&rays[lane], view);
        }
        let found = s.shape.intersect8(&object, view, active, t_min, *below);
        for lane in lanes_of(active) {
            best.keep(lane, i, found[lane], &mut limit[lane]);
        }
    }

    /// Whether object `i` is hit in `(t_min, t_max)`; `from_view` says `ray` starts at
    /// the viewpoint.
    #[inline(always)]
    fn occludes_object(&self, i: u32, ray: &Ray, from_view: bool, t_min: f64, t_max: f64) -> bool {
        let s = &self.solids[i as usize];
        s.shape
            .occludes(&s.object_ray(ray, from_view), t_min, t_max)
    }

    /// Whether anything is hit in `(t_min, t_max)` (shadow rays).
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_min: f64, t_max: f64) -> bool {
        self.occluded_hinted(ray, t_min, t_max, &mut ShadowHint::default())
    }

    /// [`World::occluded`], object `hint` tested first, then set to the object found
    /// to block the ray (none if nothing does). A shadow cache: the object that
    /// blocked a neighbouring pixel's ray toward the same light most often blocks this
    /// one too, and is then the only test. The answer is the same either way: an
    /// object that blocks the ray is found whether or not it is tested first.
    #[inline]
    pub fn occluded_hinted(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        hint: &mut ShadowHint,
    ) -> bool {
        self.occluded_through(Dispatched, ray, t_min, t_max, hint, || {
            self.blocking_plane(ray, t_min, t_max)
        })
    }

    /// The first plane (of the unbounded objects) hit within `(t_min, t_max)`, if any.
    #[inline(always)]
    fn blocking_plane(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<u32> {
        // Off a surface (see `World::occluded_through`).
        self.unbounded.iter().copied().find(|&i| {
            self.intersect_unbounded(i, ray, false, t_min, t_max, &mut ())
                .is_some()
        })
    }

    /// [`World::occluded_hinted`] for the shadow rays of `lanes` (lanes of a packet),
    /// one after another, each within `(t_min, t_max[lane])`, `hint` carried from each
    /// to the next as from call to call: the bit set of those blocked.
    ///
    /// On x86-64 with AVX2 the loop is one function compiled for it, each ray's tests
    /// and the tree's traversal inlined into it: a light's shadow rays of a packet
    /// make one call, where each ray made two (the world's test, then the traversal's
    /// AVX2 code), each saving and restoring registers and setting up its frame. What
    /// does not depend on the hint is done for the eight rays at once, in lanes: the
    /// planes' tests (`Solid::plane8`) and the rays' numbers for the tree: for the
    /// wide tree its lanes ([`Avx2::wide_rays`]), for a tree too small to have one the
    /// reciprocals and the test of the tree's box (`SlabRays8`, `Bvh::enters8`).
    pub fn occluded_each(
        &self,
        rays: &Rays8,
        lanes: u32,
        t_min: f64,
        t_max: &[f64; 8],
        hint: &mut ShadowHint,
    ) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect() {
            return avx2.run(
                #[inline(always)]
                || {
                    let (planes, plane) =
                        self.blocking_planes8(Eight(avx2), rays, lanes, t_min, t_max);
                    let planes = (planes, plane);
                    let tree = self.lone().is_none();
                    // A loop for each kind of tree, so that each ray takes its numbers
                    // for the tree without asking which kind it is (one loop asking
                    // cost 13 % more of `occluded_each`'s instructions on spheres-1k).
                    if tree && self.bvh.is_wide() {
                        let wide = avx2.wide_rays(rays);
                        return self.occluded_lanes(
                            rays,
                            (lanes, t_min, t_max),
                            hint,
                            planes,
                            #[inline(always)]
                            |k, _| wide.lane(k).map_or(TreeRay::Unmade, TreeRay::Wide),
                        );
                    }
                    let exact = tree.then(|| {
                        let slabs = SlabRays8::new(Eight(avx2), rays);
                        let enters = self.bvh.enters8(Eight(avx2), rays, &slabs, t_min, t_max);
                        (slabs, enters)
                    });
                    self.occluded_lanes(
                        rays,
                        (lanes, t_min, t_max),
                        hint,
                        planes,
                        #[inline(always)]
                        |k, origin| match &exact {
                            Some((slabs, enters)) => TreeRay::<SlabRay4>::Exact(
                                slabs.lane(k, origin),
                                enters >> k & 1 == 1,
                            ),
                            None => TreeRay::Unmade,
                        },
                    )
                },
            );
        }
        lanes_where(lanes, |k| {
            self.occluded_hinted(&rays.ray(k), t_min, t_max[k], hint)
        })
    }

    /// [`World::occluded_each`]'s loop over the rays of `lanes` (each within
    /// `(t_min, t_max[lane])`), `planes` the planes that block them (as
    /// [`World::blocking_planes8`] gives them), each ray's numbers for the tree made by
    /// `made(lane, origin)`.
    #[inline(always)]
    fn occluded_lanes<W: WideTest>(
        &self,
        rays: &Rays8,
        (lanes, t_min, t_max): (u32, f64, &[f64; 8]),
        hint: &mut ShadowHint,
        (planes, plane): (u32, [u32; 8]),
        made: impl Fn(usize, DVec3) -> TreeRay<W> + Copy,
    ) -> u32 {
        lanes_where(
            lanes,
            #[inline(always)]
            |k| {
                let ray = rays.ray(k);
                self.occluded_through(
                    Prepared(
                        #[inline(always)]
                        || made(k, ray.origin),
                    ),
                    &ray,
                    t_min,
                    t_max[k],
                    hint,
                    #[inline(always)]
                    || (planes >> k & 1 == 1).then_some(plane[k]),
                )
            },
        )
    }

    /// [`World::blocking_plane`] of each of the rays of `lanes` (off a surface), the
    /// planes tested in lanes: the bit set of the lanes a plane blocks, and each one's
    /// first.
    #[inline(always)]
    fn blocking_planes8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: &Rays8,
        lanes: u32,
        t_min: f64,
        t_max: &[f64; 8],
    ) -> (u32, [u32; 8]) {
        let (mut blocked, mut first) = (0, [0; 8]);
        for &i in &self.unbounded {
            let open = lanes & !blocked;
            if open == 0 {
                break;
            }
            let s = &self.solids[i as usize];
            let hit = open
                & if matches!(s.shape, Shape::Plane) {
                    s.plane8(n, rays, false, t_min, t_max).0
                } else {
                    lanes_where(open, |k| {
                        let r = &rays.ray(k);
                        self.intersect_unbounded(i, r, false, t_min, t_max[k], &mut ())
                            .is_some()
                    })
                };
            for k in lanes_of(hit) {
                first[k] = i;
            }
            blocked |= hit;
        }
        (blocked, first)
    }

    /// [`World::occluded_hinted`], reaching the tree by `tree`, with `plane()` the
    /// first plane that blocks the ray ([`World::blocking_plane`]).
    #[inline(always)]
    fn occluded_through<W: TreeAny>(
        &self,
        tree: W,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        hint: &mut ShadowHint,
        plane: impl FnOnce() -> Option<u32>,
    ) -> bool {
        // A shadow ray starts off a surface: its origin is carried into each object's
        // space, not compared with the viewpoint first (see `World::closest8`'s
        // `view`): render instructions −0.5 % on spheres-1k and spheres-100k.
        let from_view = false;
        if let Some(i) = hint.object()
            && self.occludes_object(i, ray, from_view, t_min, t_max)
        {
            return true;
        }
        let plane = plane();
        if plane.is_some() {
            *hint = ShadowHint::new(plane);
            return true;
        }
        let found = match self.lone() {
            Some(i) => self
                .occludes_object(i, ray, from_view, t_min, t_max)
                .then_some(i),
            // Always inlined: left a call (the three uses of the test were too many
            // for the inliner), each primitive tested paid for it. Render instructions
            // −2.4 % on spheres-1k, −3.4 % on cubes-10k; trace −2.6 % on spheres-100k.
            None => tree.any(
                &self.bvh,
                ray,
                t_min,
                t_max,
                #[inline(always)]
                move |i| self.occludes_object(i, ray, from_view, t_min, t_max),
            ),
        };
        *hint = ShadowHint::new(found);
        found.is_some()
    }

    /// [`World::occluded`] for the shadow rays of `active` (lanes of a packet), each
    /// within `(t_min, t_max[lane])`: the bit set of those blocked, each as it is alone.
    ///
    /// A lone object's own hierarchy (a mesh's) is traversed once for all of them
    /// ([`World::traces_shadow_packets`]). Over a tree of objects each ray goes alone:
    /// shadow rays of neighbouring pixels part ways there, and as packets they made
    /// renders of `classic` and `cubes-10k` 6–7 % slower (`spheres-1k` 3 % faster),
    /// while `mesh-100k`'s were 11 % faster.
    pub fn occluded8(&self, rays: &Rays8, active: u32, t_min: f64, t_max: &[f64; 8]) -> u32 {
        if active == 0 {
            return 0;
        }
        let Some(mesh) = self.shadow_packet_object() else {
            return lanes_where(active, |lane| {
                self.occluded(&rays.ray(lane), t_min, t_max[lane])
            });
        };
        let (blocked, _) = self.blocking_planes8(Eight(Portable), rays, active, t_min, t_max);
        let open = active & !blocked;
        let Some(first) = lanes_of(open).next() else {
            return blocked;
        };
        let s = &self.solids[mesh as usize];
        // Lanes without a ray carry the first one's, so that the packet's test takes
        // them (what they find is not asked).
        let object = std::array::from_fn(|k| {
            let lane = if open >> k & 1 == 1 { k } else { first };
            s.object_ray(&rays.ray(lane), false)
        });
        blocked | s.shape.occludes8(&object, open, t_min, *t_max)
    }

    /// Whether [`World::occluded8`] traces a packet's shadow rays together, not one
    /// at a time: where the tree holds one object with a hierarchy of its own (a mesh,
    /// beside planes or not).
    pub fn traces_shadow_packets(&self) -> bool {
        self.shadow_packet_object().is_some()
    }

    /// The mesh that a packet's shadow rays traverse together, if the tree holds one
    /// and nothing else.
    #[inline(always)]
    fn shadow_packet_object(&self) -> Option<u32> {
        self.lone()
            .filter(|&i| matches!(self.solids[i as usize].shape, Shape::Mesh(_)))
    }

    /// The object of a tree that holds one (a scene of one mesh, say): its own test is
    /// the tree's, so a packet or a shadow ray goes to it directly, without setting up
    /// the tree's test of the same bounds (for `mesh-100k`, a packet's second
    /// single-precision set-up).
    #[inline(always)]
    fn lone(&self) -> Option<u32> {
        match self.bvh.order() {
            &[i] => Some(i),
            _ => None,
        }
    }

    /// The first hit found by testing every object in order, without the BVH: the
    /// reference the BVH is checked against.
    pub fn closest_brute_force(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for i in 0..self.solids.len() as u32 {
            let limit = best.map_or(t_max, |b| b.lambda);
            if let Some((lambda, part)) = self.intersect_object(i, ray, t_min, limit, &mut ()) {
                best = Some(Hit {
                    lambda,
                    object: i,
                    part,
                });
            }
        }
        best
    }

    /// Objects whose bounds the ray enters, in the order the BVH visits them, then the
    /// unbounded ones: the candidates of a pixel's explanation.
    pub fn candidates(&self, ray: &Ray, t_min: f64, t_max: f64) -> Vec<u32> {
        let mut c = self
            .bvh
            .candidates(&SlabRay::new(ray.origin, ray.dir), t_min, t_max);
        c.extend_from_slice(&self.unbounded);
        c.sort_unstable();
        c
    }

    /// The world normal of part `part` of object `i`, found by [`World::new`], where
    /// that part is flat.
    #[inline(always)]
    fn flat_normal(&self, i: u32, part: u32) -> Option<DVec3> {
        let FlatNormals(normals) = self.solids.get(i as usize)?.flat.as_ref()?;
        *normals.get(part as usize)?
    }

    /// Whether `ray` starts at the viewpoint ([`Ray::starts_at`]): what a caller that
    /// says its rays start there claims.
    fn is_viewpoint(&self, ray: &Ray) -> bool {
        self.viewpoint.is_some_and(|v| ray.starts_at(v))
    }

    /// The full record of a hit found on `ray`.
    pub fn surface(&self, ray: &Ray, hit: &Hit) -> Surface {
        self.record(ray, hit, self.viewpoint == Some(ray.origin))
    }

    /// [`World::surface`] of a ray the caller knows to start at the viewpoint (a
    /// primary ray), its origin not compared (see [`World::closest8`]'s `view`).
    // Always inlined: left a call, each primary hit's record (about 100 bytes) was
    // written to memory by it and read back by the shader, which waited on it. Render
    // instructions −2.7 % on classic and spheres-1k, −2.1 % on cubes-10k.
    #[inline(always)]
    pub fn view_surface(&self, ray: &Ray, hit: &Hit) -> Surface {
        debug_assert!(self.is_viewpoint(ray));
        self.record(ray, hit, true)
    }

    /// [`World::view_surface`] written into `out`, field by field, rather than
    /// returned to be copied there (see `Renderer::put_hit_record`).
    pub fn put_view_surface(&self, ray: &Ray, hit: &Hit, out: &mut Option<Surface>) {
        debug_assert!(self.is_viewpoint(ray));
        *out = Some(self.record(ray, hit, true));
    }

    /// What [`World::surface`] and [`World::put_view_surface`] compute, inlined into
    /// each; `from_view` as for [`Solid::object_ray`].
    #[inline(always)]
    fn record(&self, ray: &Ray, hit: &Hit, from_view: bool) -> Surface {
        let s = &self.solids[hit.object as usize];
        let r = s.object_ray(ray, from_view);
        let object_point = r.at(hit.lambda);
        let face = s.shape.face(hit.part);
        let mut normal = match self.flat_normal(hit.object, hit.part) {
            Some(n) => n,
            None => world_normal(&s.object_from_world, s.shape.normal(object_point, hit.part)),
        };
        let front = normal.dot(ray.dir) < 0.0;
        if !s.shape.is_closed() && !front {
            normal = -normal;
        }
        Surface {
            lambda: hit.lambda,
            object: hit.object,
            point: ray.at(hit.lambda),
            object_point,
            normal,
            front,
            face,
        }
    }
}

/// A shared handle, as renders hold it.
pub type SharedWorld = Arc<World>;

/// How a shadow test reaches the world's tree: through [`Bvh::any`] ([`Dispatched`]),
/// which makes the ray's lanes for the wide tree itself (in code compiled for AVX2,
/// where the processor has it), or with lanes the caller made ([`Prepared`]).
trait TreeAny: Copy {
    /// The first primitive found that `leaf` says blocks the ray ([`Bvh::any`]).
    fn any<F: FnMut(u32) -> bool>(
        self,
        bvh: &Bvh,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        leaf: F,
    ) -> Option<u32>;
}

/// [`Bvh::any`], the ray's lanes made there.
#[derive(Debug, Clone, Copy)]
struct Dispatched;

impl TreeAny for Dispatched {
    #[inline(always)]
    fn any<F: FnMut(u32) -> bool>(
        self,
        bvh: &Bvh,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        leaf: F,
    ) -> Option<u32> {
        bvh.any(ray, t_min, t_max, leaf)
    }
}

/// [`Bvh::any_prepared`] with the ray's numbers for the tree made by the caller, when
/// the tree asks for them.
#[derive(Clone, Copy)]
struct Prepared<L>(L);

impl<W: WideTest, L: FnOnce() -> TreeRay<W> + Copy> TreeAny for Prepared<L> {
    #[inline(always)]
    fn any<F: FnMut(u32) -> bool>(
        self,
        bvh: &Bvh,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        leaf: F,
    ) -> Option<u32> {
        bvh.any_prepared(self.0, ray, t_min, t_max, leaf)
    }
}

/// The object that blocked the last of a run of shadow rays, if one did, for
/// [`World::occluded_hinted`] to test first; the default is none.
///
/// One 32-bit word, the object's index plus one (0 for none). As an `Option<u32>`,
/// written by the world in two stores (its tag, then the index) and read back by the
/// shader in one load, every shadow ray's return waited until both stores were written
/// out: 13 % of the samples of `Shader::shade8` in a profile of `classic`'s render.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ShadowHint(Option<NonZeroU32>);

impl ShadowHint {
    /// A hint of object `object`, or none. (Object `u32::MAX`, which no world holds,
    /// gives none.)
    #[inline(always)]
    pub fn new(object: Option<u32>) -> ShadowHint {
        ShadowHint(object.and_then(|i| NonZeroU32::new(i.wrapping_add(1))))
    }

    /// The object hinted at, if any.
    #[inline(always)]
    pub fn object(self) -> Option<u32> {
        self.0.map(|n| n.get() - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_shadow_hint_is_one_word_and_gives_back_the_object_it_was_made_of() {
        // One word, so that writing it and reading it back are one store and one load.
        assert_eq!(std::mem::size_of::<ShadowHint>(), 4);
        assert_eq!(ShadowHint::default().object(), None);
        assert_eq!(ShadowHint::new(None).object(), None);
        for i in [0, 1, 7, 65_535, u32::MAX - 1] {
            assert_eq!(ShadowHint::new(Some(i)).object(), Some(i), "object {i}");
        }
        assert_eq!(ShadowHint::new(Some(u32::MAX)).object(), None);
    }

    /// A packet's shadow rays tested one after another leave the hint each leaves alone:
    /// a ray that planes block names the first listed of them, whichever the loop over
    /// the planes in lanes meets last.
    #[test]
    fn a_ray_blocked_by_planes_leaves_the_first_listed_as_its_hint() {
        // Two floors, y = 0 and y = −1, and a sphere off to the side: a ray down from
        // above crosses both floors, a ray up nothing.
        let (floor, lower, ball) = (
            Transform::default(),
            Transform::translate(DVec3::new(0.0, -1.0, 0.0)),
            Transform::translate(DVec3::new(10.0, 0.0, 0.0)),
        );
        let world = World::new([
            (&Shape::Plane, &floor),
            (&Shape::Plane, &lower),
            (&Shape::Sphere, &ball),
        ]);
        let (up, down) = (
            Ray::new(DVec3::Y, DVec3::Y),
            Ray::new(DVec3::Y, DVec3::NEG_Y),
        );
        let reach = [10.0; 8];
        for (rays, blocked) in [([up, down], 0b10), ([down, up], 0b01), ([down, down], 0b11)] {
            let mut packet = [up; 8];
            packet[..2].copy_from_slice(&rays);
            let packet = Rays8::from_rays(&packet);
            let mut hint = ShadowHint::default();
            assert_eq!(
                world.occluded_each(&packet, 0b11, 1e-9, &reach, &mut hint),
                blocked
            );
            let mut alone = ShadowHint::default();
            for ray in &rays {
                world.occluded_hinted(ray, 1e-9, 10.0, &mut alone);
            }
            assert_eq!(hint, alone, "{blocked:#b}");
        }
        let mut hint = ShadowHint::default();
        world.occluded_each(
            &Rays8::from_rays(&[up, down, up, up, up, up, up, up]),
            0b11,
            1e-9,
            &reach,
            &mut hint,
        );
        assert_eq!(hint.object(), Some(0), "the first floor listed");
    }

    proptest! {
        /// A hit on a flat part (a cube's face, a cap, a base, a plane, a disk) takes
        /// the world normal found when the world was built: it must be the one the
        /// shape's normal at the hit's own point gives, bit for bit, under any
        /// placement; and a curved part has none found beforehand.
        #[test]
        fn a_flat_parts_normal_found_once_is_the_one_found_at_each_hit(
            shape in prop::sample::select(vec![
                Shape::Sphere, Shape::Cube, Shape::Plane, Shape::Disk, Shape::Cylinder, Shape::Cone,
            ]),
            scale in prop::array::uniform3(0.1f64..5.0),
            axis in prop::array::uniform3(-1.0f64..1.0),
            degrees in 0.0f64..360.0,
            shift in prop::array::uniform3(-50.0f64..50.0),
            from in prop::array::uniform3(-1.0f64..1.0),
            aim in prop::array::uniform3(-1.2f64..1.2),
        ) {
            let axis = DVec3::from(axis);
            prop_assume!(axis.length() > 1e-3);
            let t = Transform::scale(scale.into())
                .then(&Transform::rotate(axis, degrees))
                .then(&Transform::translate(shift.into()));
            let world = World::new([(&shape, &t)]);
            let s = &world.solids[0];
            // From a point well outside the shape toward one near it, both given in
            // object space and carried out.
            let (from, aim) = (DVec3::from(from), DVec3::from(aim));
            prop_assume!(from.length() > 1e-3);
            let origin = t.forward.transform_point3(from.normalize() * 10.0);
            let ray = Ray::new(origin, t.forward.transform_point3(aim) - origin);
            let Some(hit) = world.closest(&ray, 1e-9, f64::INFINITY) else {
                return Ok(());
            };
            let object_point = s.object_ray(&ray, false).at(hit.lambda);
            let found = world_normal(&s.object_from_world, s.shape.normal(object_point, hit.part));
            match world.flat_normal(hit.object, hit.part) {
                Some(n) => prop_assert_eq!(n.to_array().map(f64::to_bits), found.to_array().map(f64::to_bits)),
                None => prop_assert!(s.shape.flat_normal(hit.part).is_none(), "part {}", hit.part),
            }
            let record = world.surface(&ray, &hit).normal;
            let facing = if s.shape.is_closed() || found.dot(ray.dir) < 0.0 { found } else { -found };
            prop_assert_eq!(record.to_array().map(f64::to_bits), facing.to_array().map(f64::to_bits));
        }

        /// A plane's test reads the object ray's y components computed alone: they must
        /// be the whole ray's, bit for bit, under any placement and from any origin.
        #[test]
        fn a_rays_height_alone_is_the_whole_rays(
            scale in prop::array::uniform3(0.1f64..5.0),
            axis in prop::array::uniform3(-1.0f64..1.0),
            degrees in 0.0f64..360.0,
            shift in prop::array::uniform3(-50.0f64..50.0),
            o in prop::array::uniform3(-20.0f64..20.0),
            d in prop::array::uniform3(-1.0f64..1.0),
            t_max in prop_oneof![Just(f64::INFINITY), 0.0f64..40.0],
        ) {
            let axis = DVec3::from(axis);
            prop_assume!(axis.length() > 1e-3);
            let t = Transform::scale(scale.into())
                .then(&Transform::rotate(axis, degrees))
                .then(&Transform::translate(shift.into()));
            let ray = Ray::new(o.into(), d.into());
            let mut world = World::new([(&Shape::Plane, &t)]);
            for view in [None, Some(ray.origin)] {
                if let Some(v) = view {
                    world.set_viewpoint(v);
                }
                let s = &world.solids[0];
                let from_view = view.is_some();
                let whole = s.object_ray(&ray, from_view);
                let (y0, dy) = s.object_y(&ray, from_view);
                prop_assert_eq!((y0.to_bits(), dy.to_bits()), (whole.origin.y.to_bits(), whole.dir.y.to_bits()));
                // And the world's answers are the shape's own.
                let own = world.closest_brute_force(&ray, 1e-9, t_max);
                prop_assert_eq!(world.closest(&ray, 1e-9, t_max), own);
                prop_assert_eq!(world.occluded(&ray, 1e-9, t_max), own.is_some());
            }
        }
    }
}
