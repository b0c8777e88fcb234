//! Triangle meshes given inline in object space, with their own BVH over triangles.
//!
//! The ray is tested with Möller–Trumbore in object space, edges included; a triangle
//! whose determinant is exactly zero (the ray lies in its plane, or it has no area) is
//! not hit. The normal is the triangle's geometric normal `(v₁ − v₀) × (v₂ − v₀)`.
//! Parts are triangles, numbered as the scene lists them.

use std::borrow::Cow;
use std::fmt;
use std::sync::OnceLock;

use glam::DVec3;
use rayon::prelude::*;

use super::CanonicalShape;
use crate::geometry::{
    bounds::{Aabb, SlabRay, SlabRay4, lanes_of, lanes_where, per_lane},
    bvh::Bvh,
    hit::{Probe, TriangleTest},
    ray::Ray,
    transform::Transform,
};
use group::{Group, LANES};

mod group;

/// A mesh as the scene gives it; the BVH over its triangles is built once, by
/// [`CanonicalShape::prepare`] or the first ray, and kept with it.
#[derive(Default)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<DVec3>,
    /// Triangles as vertex indices (validated to be in range).
    pub indices: Vec<[u32; 3]>,
    accel: OnceLock<MeshAccel>,
}

impl Mesh {
    /// A mesh of `positions` and the triangles `indices`, every index in range.
    pub fn new(positions: Vec<DVec3>, indices: Vec<[u32; 3]>) -> Mesh {
        Mesh {
            positions,
            indices,
            accel: OnceLock::new(),
        }
    }

    /// The corners of triangle `i`.
    pub fn corners(&self, i: usize) -> [DVec3; 3] {
        let [a, b, c] = self.indices[i];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// The triangles' BVH, built on this thread by the first caller if
    /// [`CanonicalShape::prepare`] has not built it.
    #[inline(always)]
    fn accel(&self) -> &MeshAccel {
        self.accel.get_or_init(|| MeshAccel::new(self, false))
    }
}

/// Two meshes are equal when the scene gave the same triangles; the BVH follows.
impl PartialEq for Mesh {
    fn eq(&self, other: &Mesh) -> bool {
        self.positions == other.positions && self.indices == other.indices
    }
}

impl fmt::Debug for Mesh {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Mesh")
            .field("positions", &self.positions)
            .field("indices", &self.indices)
            .finish_non_exhaustive()
    }
}

impl CanonicalShape for Mesh {
    const NAME: &'static str = "mesh";
    const CLOSED: bool = false;

    /// The bounds of its vertices that some triangle uses.
    fn bounds(&self) -> Option<Aabb> {
        Some(
            self.indices
                .iter()
                .flatten()
                .fold(Aabb::EMPTY, |b, &i| b.grow(self.positions[i as usize])),
        )
    }

    /// The bounds of its transformed vertices (tighter than its box's corners).
    fn world_bounds(&self, world_from_object: &Transform) -> Option<Aabb> {
        Some(self.indices.iter().flatten().fold(Aabb::EMPTY, |b, &i| {
            b.grow(
                world_from_object
                    .forward
                    .transform_point3(self.positions[i as usize]),
            )
        }))
    }

    /// Builds the triangles' BVH on every worker of the current rayon pool, outside the
    /// mesh's lock, and keeps it unless another caller's got there first (then it is
    /// dropped: the same BVH). Built inside the lock, it had to be on one thread: a
    /// worker waiting there for its other half could run a job that waits for the
    /// lock it holds (another render of the same scene). On two threads, mesh-100k's
    /// build takes about 60 % of the time it takes on one.
    fn prepare(&self) {
        if self.accel.get().is_none() {
            let _ = self.accel.set(MeshAccel::new(self, true));
        }
    }

    /// The closest triangle hit in `(t_min, t_max)`: `λ` and the triangle's index.
    #[inline(always)]
    fn intersect<P: Probe>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        self.accel().intersect(ray, t_min, t_max, probe)
    }

    /// The rays of `active` traverse the triangles' BVH together (a lone ray goes on
    /// its own), each tested and ranked as `MeshAccel::intersect` does.
    fn intersect8(
        &self,
        rays: &[Ray; 8],
        shared: bool,
        active: u32,
        t_min: f64,
        t_max: [f64; 8],
    ) -> [Option<(f64, u32)>; 8] {
        let a = self.accel();
        let Some(slab) = packet(rays, shared, active) else {
            return per_lane(active, |lane| {
                a.intersect(&rays[lane], t_min, t_max[lane], &mut ())
            });
        };
        let mut best: [Option<(f64, u32)>; 8] = [None; 8];
        let mut limits = t_max;
        a.bvh.closest8::<false, _>(
            &slab,
            t_min,
            &mut limits,
            active,
            // Inlined into each traversal that calls it (the BVH has one per lane width).
            #[inline(always)]
            |slots, rays_in, limits| {
                for lane in lanes_of(rays_in) {
                    limits[lane] =
                        a.closest_in_leaf(slots, &rays[lane], t_min, limits[lane], &mut best[lane]);
                }
            },
        );
        best
    }

    #[inline(always)]
    fn occludes(&self, ray: &Ray, t_min: f64, t_max: f64) -> bool {
        self.accel().occludes(ray, t_min, t_max)
    }

    /// The rays of `active` traverse the triangles' BVH together (a lone ray goes on
    /// its own), each occluded as `MeshAccel::occludes` finds it.
    fn occludes8(&self, rays: &[Ray; 8], active: u32, t_min: f64, t_max: [f64; 8]) -> u32 {
        let a = self.accel();
        let Some(slab) = packet(rays, false, active) else {
            return lanes_where(active, |lane| a.occludes(&rays[lane], t_min, t_max[lane]));
        };
        a.bvh.any8(
            &slab,
            t_min,
            t_max,
            active,
            #[inline(always)]
            |slots, rays_in| {
                lanes_where(
                    rays_in,
                    // Left to itself, the compiler called this closure out of line,
                    // compiled for no wider lanes, and the group's test from there.
                    #[inline(always)]
                    |lane| a.occludes_in_leaf(slots, &rays[lane], t_min, t_max[lane]),
                )
            },
        )
    }

    /// The geometric normal of triangle `part`, from its prepared edges (`e₁ × e₂`,
    /// the same numbers as from its corners): one read where the corners take four,
    /// scattered through the vertices.
    fn normal(&self, _object_point: DVec3, part: u32) -> DVec3 {
        let a = self.accel();
        let tri = a.tri(a.slot[part as usize]);
        tri.e1.cross(tri.e2)
    }

    fn part_label(&self, part: u32) -> Cow<'static, str> {
        Cow::Owned(format!("triangle {part}"))
    }
}

/// What testing a ray against a group of up to four triangles costs (one pass of
/// [`Group::hits`]), in tests of a BVH node's boxes (see [`Bvh::build_in_groups`]):
/// about two. Counted in groups, the heuristic fills a leaf to four triangles where
/// it used to split them apart: `mesh-100k`'s 100 352 triangles lie in 26 848 leaves,
/// 3.7 a leaf, in 106 112 slots (about 55 000 leaves, 1.8 a leaf, when each triangle
/// was priced alone, at one node test). Priced at 1 or 3, its trace took the same time
/// (eleven alternating runs of each, hits and render).
const GROUP_TEST_COST: f64 = 2.0;

/// A triangle prepared for Möller–Trumbore.
#[derive(Debug, Clone, Copy)]
struct Tri {
    v0: DVec3,
    e1: DVec3,
    e2: DVec3,
}

/// A mesh ready to trace: triangles in BVH leaf order, in groups of [`LANES`], each
/// leaf's in one group (see [`Bvh::into_slots`]), so that a ray tests a leaf's
/// triangles in one pass ([`Group::hits`]).
#[derive(Debug)]
struct MeshAccel {
    /// Slot `k` is lane `k % LANES` of group `k / LANES`.
    groups: Vec<Group>,
    /// For each slot, the index in the scene's `indices` of the triangle there
    /// (`u32::MAX` for an empty slot).
    ids: Vec<u32>,
    /// For each triangle of the scene's `indices`, its slot.
    slot: Vec<u32>,
    bvh: Bvh,
}

impl MeshAccel {
    /// Builds the triangle BVH, on every worker of the current rayon pool where
    /// `parallel` (never inside the mesh's lock: see [`Bvh::build_in_parallel`]); the
    /// same BVH either way.
    fn new(mesh: &Mesh, parallel: bool) -> MeshAccel {
        let bound = |i: usize| {
            let [a, b, c] = mesh.corners(i);
            Aabb::EMPTY.grow(a).grow(b).grow(c)
        };
        let bounds: Vec<Aabb> = if parallel {
            (0..mesh.indices.len()).into_par_iter().map(bound).collect()
        } else {
            (0..mesh.indices.len()).map(bound).collect()
        };
        let bvh = Bvh::build_in_groups(&bounds, GROUP_TEST_COST, LANES, parallel);
        // The BVH's leaves name triangles in scene order; store them in leaf order so a
        // leaf's triangles sit together in memory, and remap the leaves to slots.
        let (bvh, held) = bvh.into_slots(LANES);
        let mut slot = vec![0; mesh.indices.len()];
        let tri = |i: u32| {
            let [v0, v1, v2] = mesh.corners(i as usize);
            Tri {
                v0,
                e1: v1 - v0,
                e2: v2 - v0,
            }
        };
        let group = |lanes: &[Option<u32>]| {
            Group::new(std::array::from_fn(|j| {
                lanes.get(j).copied().flatten().map(tri)
            }))
        };
        let groups: Vec<Group> = if parallel {
            held.par_chunks(LANES).map(group).collect()
        } else {
            held.chunks(LANES).map(group).collect()
        };
        let ids = held
            .iter()
            .enumerate()
            .map(|(k, i)| match *i {
                Some(i) => {
                    slot[i as usize] = k as u32;
                    i
                }
                None => u32::MAX,
            })
            .collect();
        MeshAccel {
            groups,
            ids,
            slot,
            bvh,
        }
    }

    /// The triangle in slot `k`.
    #[inline(always)]
    fn tri(&self, k: u32) -> Tri {
        self.groups[k as usize / LANES].tri(k as usize % LANES)
    }

    /// The groups that hold a leaf's triangles (its `slots`, consecutive; in one group
    /// unless the leaf has more than [`LANES`]): each with the bit set of the leaf's
    /// lanes in it, and the slot of its first lane.
    #[inline(always)]
    fn groups_of(&self, slots: &[u32]) -> impl Iterator<Item = (&Group, u32, usize)> {
        let first = slots.first().map_or(0, |&k| k as usize);
        let end = first + slots.len();
        (first / LANES..end.div_ceil(LANES)).map(move |g| {
            let base = g * LANES;
            let (lo, hi) = (first.max(base) - base, end.min(base + LANES) - base);
            (&self.groups[g], (1 << hi) - (1 << lo), base)
        })
    }

    /// The closest triangle hit in `(t_min, t_max)`: `λ` and the triangle's index. A
    /// leaf's triangles are tested together ([`MeshAccel::closest_in_leaf`]), or one
    /// by one where `probe` records each test.
    #[inline]
    fn intersect<P: Probe>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)> {
        let slab = SlabRay::new(ray.origin, ray.dir);
        let mut best: Option<(f64, u32)> = None;
        if probe.active() {
            self.bvh.closest(&slab, t_min, t_max, |k, limit| {
                let id = self.ids[k as usize];
                let hit = moller_trumbore(&self.tri(k), ray, t_min, limit, id, probe);
                keep_first(&mut best, hit, id, limit)
            });
        } else {
            self.bvh
                .closest_by_leaf(&slab, t_min, t_max, |slots, limit| {
                    self.closest_in_leaf(slots, ray, t_min, limit, &mut best)
                });
        }
        best
    }

    /// The triangles of a leaf (its `slots`) for `ray`, each taken by [`keep_first`]
    /// into `best` in slot order, as one at a time: the new limit.
    #[inline(always)]
    fn closest_in_leaf(
        &self,
        slots: &[u32],
        ray: &Ray,
        t_min: f64,
        mut limit: f64,
        best: &mut Option<(f64, u32)>,
    ) -> f64 {
        for (group, leaf_lanes, base) in self.groups_of(slots) {
            let (hits, t) = group.hits(ray, t_min);
            for j in lanes_of(hits & leaf_lanes) {
                let hit = Some(t[j]).filter(|&t| t <= limit);
                limit = keep_first(best, hit, self.ids[base + j], limit);
            }
        }
        limit
    }

    /// Whether any triangle is hit in `(t_min, t_max)`.
    #[inline]
    fn occludes(&self, ray: &Ray, t_min: f64, t_max: f64) -> bool {
        self.bvh
            .any_by_leaf(
                ray,
                t_min,
                t_max,
                #[inline(always)]
                |slots| {
                    self.occludes_in_leaf(slots, ray, t_min, t_max)
                        .then_some(())
                },
            )
            .is_some()
    }

    /// Whether some triangle of a leaf (its `slots`) is hit in `(t_min, t_max)`.
    #[inline(always)]
    fn occludes_in_leaf(&self, slots: &[u32], ray: &Ray, t_min: f64, t_max: f64) -> bool {
        // Plain loops: through `Iterator::any` the compiler left a call to a `try_fold`
        // compiled for no wider lanes than the release's, so the group's test behind it
        // could not be inlined into a packet's traversal and was called out of line.
        for (group, leaf_lanes, _) in self.groups_of(slots) {
            let (hits, t) = group.hits(ray, t_min);
            for j in lanes_of(hits & leaf_lanes) {
                if t[j] <= t_max {
                    return true;
                }
            }
        }
        false
    }
}

/// The rays of `active` prepared as a packet for the triangles' BVH, or `None` where
/// they go one at a time: a lone ray (a packet pays for more than one ray only), or
/// rays the packet's test refuses ([`SlabRay4::new`]). `shared` as for
/// [`CanonicalShape::intersect8`]: the origins are then taken as one, not compared.
#[inline(always)]
fn packet(rays: &[Ray; 8], shared: bool, active: u32) -> Option<[SlabRay4; 2]> {
    debug_assert!(!shared || rays.iter().all(|r| r.starts_at(rays[0].origin)));
    if active.count_ones() < 2 {
        None
    } else if shared {
        SlabRay4::pair_from(rays, true)
    } else {
        SlabRay4::pair(rays)
    }
}

/// Takes triangle `id`'s hit `λ` as the best when it is nearer than `limit`, or ties
/// the best so far and is listed before it; returns the new limit. What a ray finds
/// does not depend on the order triangles are tested in.
#[inline(always)]
fn keep_first(best: &mut Option<(f64, u32)>, hit: Option<f64>, id: u32, limit: f64) -> f64 {
    match hit {
        Some(t) if t < limit || best.is_some_and(|(bt, bid)| t == bt && id < bid) => {
            *best = Some((t, id));
            t
        }
        _ => limit,
    }
}

#[inline(always)]
fn moller_trumbore<P: Probe>(
    tri: &Tri,
    ray: &Ray,
    t_min: f64,
    t_max: f64,
    id: u32,
    probe: &mut P,
) -> Option<f64> {
    let p = ray.dir.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det == 0.0 {
        if probe.active() {
            probe.triangle(&TriangleTest {
                triangle: id,
                uvt: None,
                hit: false,
            });
        }
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.origin - tri.v0;
    let u = s.dot(p) * inv;
    let q = s.cross(tri.e1);
    let v = ray.dir.dot(q) * inv;
    let t = tri.e2.dot(q) * inv;
    let hit = u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > t_min && t <= t_max;
    if probe.active() {
        probe.triangle(&TriangleTest {
            triangle: id,
            uvt: Some([u, v, t]),
            hit,
        });
    }
    hit.then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> Mesh {
        // Two triangles making the square [-1,1]² in the z = 0 plane.
        Mesh::new(
            vec![
                DVec3::new(-1.0, -1.0, 0.0),
                DVec3::new(1.0, -1.0, 0.0),
                DVec3::new(1.0, 1.0, 0.0),
                DVec3::new(-1.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn hits_each_triangle_and_the_shared_edge() {
        let m = quad();
        let at = |x: f64, y: f64| {
            m.intersect(
                &Ray::new(DVec3::new(x, y, -2.0), DVec3::Z),
                1e-9,
                f64::INFINITY,
                &mut (),
            )
        };
        assert_eq!(at(0.5, -0.5), Some((2.0, 0)));
        assert_eq!(at(-0.5, 0.5), Some((2.0, 1)));
        // On the diagonal both triangles are hit at the same λ: the first listed wins.
        assert_eq!(at(0.25, 0.25), Some((2.0, 0)));
        assert_eq!(at(1.5, 0.0), None);
    }

    #[test]
    fn normal_follows_winding() {
        let m = quad();
        assert_eq!(m.normal(DVec3::ZERO, 0).normalize(), DVec3::Z);
    }

    #[test]
    fn each_triangle_s_normal_is_the_cross_product_of_its_own_corners() {
        // Scattered triangles, so that the BVH stores them out of scene order.
        let positions: Vec<DVec3> = (0..300)
            .map(|i| {
                let k = i as f64;
                DVec3::new((k * 0.37).sin(), (k * 0.61).cos(), (k * 1.3).sin()) * (1.0 + k)
            })
            .collect();
        let indices: Vec<[u32; 3]> = (0..100).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let m = Mesh::new(positions, indices);
        let a = m.accel();
        assert!(
            a.ids.windows(2).any(|w| w[0] > w[1]),
            "stored in scene order"
        );
        for part in 0..100 {
            let [p, q, r] = m.corners(part as usize);
            let n = m.normal(DVec3::ZERO, part);
            assert_eq!(
                n.to_array().map(f64::to_bits),
                (q - p).cross(r - p).to_array().map(f64::to_bits)
            );
        }
    }

    /// A mesh large enough that its subtrees are built on several workers
    /// (`Bvh::build_in_groups`'s `parallel`) stores its triangles in the same slots
    /// built either way, and what `prepare` builds is what the mesh then traces with.
    #[test]
    fn built_on_every_worker_or_on_one_thread_a_mesh_keeps_the_same_slots() {
        let positions: Vec<DVec3> = (0..60_000)
            .map(|i| {
                let k = i as f64;
                DVec3::new((k * 0.37).sin(), (k * 0.61).cos(), (k * 1.3).sin()) * 50.0
                    + DVec3::splat((i % 3) as f64 * 0.2)
            })
            .collect();
        let indices: Vec<[u32; 3]> = (0..20_000).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let m = Mesh::new(positions, indices);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(4)
            .build()
            .unwrap();
        let many = pool.install(|| MeshAccel::new(&m, true));
        let one = MeshAccel::new(&m, false);
        assert_eq!(many.ids, one.ids);
        assert_eq!(many.slot, one.slot);
        assert_eq!(many.groups.len(), one.groups.len());
        let bits = |t: Tri| [t.v0, t.e1, t.e2].map(|v| v.to_array().map(f64::to_bits));
        for k in 0..one.ids.len() as u32 {
            assert_eq!(bits(many.tri(k)), bits(one.tri(k)), "slot {k}");
        }
        pool.install(|| m.prepare());
        let prepared = m.accel.get().expect("prepare builds the BVH");
        assert_eq!(prepared.ids, one.ids);
        // Prepared again, it is kept, not built anew.
        m.prepare();
        assert!(std::ptr::eq(m.accel(), prepared));
    }
}
