//! A bounding volume hierarchy: binned surface-area-heuristic build, collapsed into
//! 4-wide nodes whose four child boxes one SIMD slab test checks at once, nearest-child-
//! first traversal. Used over a scene's objects (world space) and over a mesh's
//! triangles (object space), so the cost of a ray grows with the logarithm of the number
//! of primitives.
//!
//! Boxes are padded by a tiny relative margin when built, rounded outward to single
//! precision in the wide nodes, and tested conservatively ([`SlabRay::enter4`]), so the
//! hierarchy never loses a hit that testing every primitive would find. Primitives
//! themselves are tested exactly, in `f64`, by the caller's leaf function, which also
//! resolves ties (nodes are entered when their entry `λ` is *at most* the best so far,
//! so a tie in a later node is still seen).

use arrayvec::ArrayVec;
use glam::DVec3;

use super::bounds::{Aabb, Boxes4, SlabRay};

/// Primitives per leaf at most, when the SAH would rather not split.
const MAX_LEAF_PRIMS: usize = 4;
/// SAH bins per axis.
const SAH_BINS: usize = 12;
/// Below this depth the SAH is used; deeper, a plain median split bounds the depth.
const SAH_MAX_DEPTH: usize = 48;
/// Traversal stack size: a wide node pushes at most three children, and the tree is no
/// deeper than the binary one it collapses, whose depth `SAH_MAX_DEPTH` plus a median
/// tree of 2³² leaves bounds.
const STACK_SIZE: usize = 3 * 96;

/// A node of the binary tree as built.
#[derive(Debug, Clone, Copy)]
struct Node {
    min: DVec3,
    max: DVec3,
    /// Leaf: first index into `order`. Interior: index of the second child (the first
    /// child follows the node).
    offset: u32,
    /// Leaf: primitive count (> 0). Interior: 0.
    count: u16,
}

/// A node for traversal: up to four children, their boxes side by side so that one
/// slab test checks them all. Two cache lines.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Wide {
    boxes: Boxes4,
    /// Each child: an index into `wide`, or `LEAF | index` into `leaves`; an unused lane
    /// holds the empty box, which no ray enters, so its reference is never read.
    child: [u32; 4],
}

/// Marks a child reference as a leaf.
const LEAF: u32 = 1 << 31;

/// A BVH over primitives given by their bounds.
#[derive(Debug, Clone)]
pub struct Bvh {
    /// The tree as traversed.
    wide: Vec<Wide>,
    /// Leaves: `(first, count)` into `order`.
    leaves: Vec<(u32, u32)>,
    /// The root: an index into `wide` or `LEAF | index` (when the tree is one leaf).
    root: u32,
    /// The bounds of everything held (padded).
    bounds: Aabb,
    /// Primitive indices in leaf order.
    order: Vec<u32>,
}

/// The binary tree being built, before it is collapsed.
struct Builder {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

struct BuildPrim {
    bounds: Aabb,
    centroid: DVec3,
    index: u32,
}

/// Splits `prims` at the median centroid along `axis`, ties broken by index so the tree
/// does not depend on the sort's order.
fn median_split(prims: &mut [BuildPrim], axis: usize) -> (usize, usize) {
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid[axis]
            .total_cmp(&b.centroid[axis])
            .then(a.index.cmp(&b.index))
    });
    (axis, mid)
}

impl Bvh {
    /// Builds over `bounds[i]` for every `i`; empty boxes are left out.
    pub fn build(bounds: &[Aabb]) -> Bvh {
        let mut prims: Vec<BuildPrim> = bounds
            .iter()
            .enumerate()
            .filter(|(_, b)| !b.is_empty())
            .map(|(i, b)| {
                let bounds = b.padded();
                BuildPrim {
                    bounds,
                    centroid: bounds.centroid(),
                    index: i as u32,
                }
            })
            .collect();
        let mut builder = Builder {
            nodes: Vec::with_capacity(2 * prims.len() / MAX_LEAF_PRIMS + 1),
            order: Vec::with_capacity(prims.len()),
        };
        let mut bvh = Bvh {
            wide: Vec::new(),
            leaves: Vec::new(),
            root: LEAF,
            bounds: Aabb::EMPTY,
            order: Vec::new(),
        };
        if !prims.is_empty() {
            builder.build_node(&mut prims, 0);
            bvh.bounds = Aabb {
                min: builder.nodes[0].min,
                max: builder.nodes[0].max,
            };
            bvh.root = bvh.collapse(&builder.nodes, 0);
        }
        bvh.order = builder.order;
        bvh
    }

    /// Converts node `i` of the binary tree `nodes` (and its subtree) to wide nodes;
    /// returns its reference. An interior node takes up to four descendants as its
    /// children: its two, then repeatedly the two of the interior child with the
    /// largest surface area in place of that child (the one most rays enter).
    fn collapse(&mut self, nodes: &[Node], i: usize) -> u32 {
        let n = nodes[i];
        if n.count > 0 {
            self.leaves.push((n.offset, n.count as u32));
            return LEAF | (self.leaves.len() as u32 - 1);
        }
        let area = |k: usize| {
            Aabb {
                min: nodes[k].min,
                max: nodes[k].max,
            }
            .half_area()
        };
        let mut kids: ArrayVec<usize, 4> = ArrayVec::new();
        kids.push(i + 1);
        kids.push(n.offset as usize);
        while kids.len() < 4 {
            let open = (0..kids.len())
                .filter(|&j| nodes[kids[j]].count == 0)
                .max_by(|&x, &y| area(kids[x]).total_cmp(&area(kids[y])));
            let Some(j) = open else { break };
            let k = kids[j];
            kids[j] = k + 1;
            kids.push(nodes[k].offset as usize);
        }
        let me = self.wide.len();
        let mut node = Wide {
            boxes: Boxes4::EMPTY,
            child: [0; 4],
        };
        for (lane, &k) in kids.iter().enumerate() {
            node.boxes.set(
                lane,
                &Aabb {
                    min: nodes[k].min,
                    max: nodes[k].max,
                },
            );
        }
        self.wide.push(node);
        for (lane, &k) in kids.iter().enumerate() {
            let c = self.collapse(nodes, k);
            self.wide[me].child[lane] = c;
        }
        me as u32
    }

    /// Number of primitives held.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Primitive indices in leaf order.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// The same tree with its leaves naming positions in [`Bvh::order`] instead of
    /// primitive indices, for callers that store their primitives in leaf order.
    pub fn into_leaf_order(mut self) -> Bvh {
        for (k, p) in self.order.iter_mut().enumerate() {
            *p = k as u32;
        }
        self
    }

    /// The bounds of everything held.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Whether a ray can reach anything at all: false for an empty tree, and for a
    /// tree of one leaf whose box the ray misses (a wide root tests its children's
    /// boxes itself).
    #[inline(always)]
    fn reachable(&self, ray: &SlabRay, t_min: f64, t_max: f64) -> bool {
        !self.order.is_empty()
            && (self.root & LEAF == 0
                || ray
                    .enter(self.bounds.min, self.bounds.max, t_min, t_max)
                    .is_some())
    }

    /// The primitives of leaf reference `r`.
    #[inline(always)]
    fn leaf(&self, r: u32) -> &[u32] {
        let (start, count) = self.leaves[(r & !LEAF) as usize];
        &self.order[start as usize..(start + count) as usize]
    }

    /// Visits, near first, every primitive whose box the ray enters before the best
    /// `λ` so far. `leaf(prim, t_max)` tests one primitive and returns the new best `λ`
    /// (or `t_max` unchanged). `t_min` is not negative.
    #[inline]
    pub fn closest<F: FnMut(u32, f64) -> f64>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        mut t_max: f64,
        mut leaf: F,
    ) -> f64 {
        if !self.reachable(ray, t_min, t_max) {
            return t_max;
        }
        // ArrayVec: a fixed stack that is not zeroed on every call (this runs per ray).
        let mut stack: ArrayVec<(u32, f32), STACK_SIZE> = ArrayVec::new();
        let mut cur = self.root;
        loop {
            if cur & LEAF != 0 {
                for &p in self.leaf(cur) {
                    t_max = leaf(p, t_max);
                }
            } else {
                let n = &self.wide[cur as usize];
                let (mut mask, near) = ray.enter4(&n.boxes, t_min, t_max);
                if mask != 0 {
                    if mask & (mask - 1) == 0 {
                        cur = n.child[mask.trailing_zeros() as usize];
                        continue;
                    }
                    let first = mask.trailing_zeros() as usize;
                    let rest = mask & (mask - 1);
                    if rest & (rest - 1) == 0 {
                        // Two entered (the commonest case): the nearer next.
                        let second = rest.trailing_zeros() as usize;
                        let (a, b) = if near[second] < near[first] {
                            (second, first)
                        } else {
                            (first, second)
                        };
                        let _ = stack.try_push((n.child[b], near[b]));
                        cur = n.child[a];
                        continue;
                    }
                    // Three or four: the nearest next, the others onto the stack, the
                    // farthest deepest.
                    let mut hit: ArrayVec<(f32, u32), 4> = ArrayVec::new();
                    while mask != 0 {
                        let lane = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        hit.push((near[lane], n.child[lane]));
                    }
                    for i in 1..hit.len() {
                        let mut j = i;
                        while j > 0 && hit[j - 1].0 < hit[j].0 {
                            hit.swap(j - 1, j);
                            j -= 1;
                        }
                    }
                    if let Some((_, nearest)) = hit.pop() {
                        for &(t, c) in &hit {
                            // A full stack drops the subtree: unreachable within the
                            // depth bound the build guarantees.
                            let _ = stack.try_push((c, t));
                        }
                        cur = nearest;
                        continue;
                    }
                }
            }
            // Pop the next subtree that may still hold something nearer (or tied).
            loop {
                let Some((node, t)) = stack.pop() else {
                    return t_max;
                };
                if t as f64 <= t_max {
                    cur = node;
                    break;
                }
            }
        }
    }

    /// Whether `leaf(prim)` is true for some primitive whose box the ray enters within
    /// `(t_min, t_max)`; stops at the first. `t_min` is not negative.
    #[inline]
    pub fn any<F: FnMut(u32) -> bool>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        t_max: f64,
        mut leaf: F,
    ) -> bool {
        if !self.reachable(ray, t_min, t_max) {
            return false;
        }
        let mut stack: ArrayVec<u32, STACK_SIZE> = ArrayVec::new();
        let mut cur = self.root;
        loop {
            if cur & LEAF != 0 {
                if self.leaf(cur).iter().any(|&p| leaf(p)) {
                    return true;
                }
            } else {
                let n = &self.wide[cur as usize];
                let (mut mask, _) = ray.enter4(&n.boxes, t_min, t_max);
                if mask != 0 {
                    cur = n.child[mask.trailing_zeros() as usize];
                    mask &= mask - 1;
                    while mask != 0 {
                        let _ = stack.try_push(n.child[mask.trailing_zeros() as usize]);
                        mask &= mask - 1;
                    }
                    continue;
                }
            }
            match stack.pop() {
                Some(c) => cur = c,
                None => return false,
            }
        }
    }

    /// Primitives whose box the ray enters within `(t_min, t_max)`, in leaf order: the
    /// candidates a ray is tested against (for explaining a pixel).
    pub fn candidates(&self, ray: &SlabRay, t_min: f64, t_max: f64) -> Vec<u32> {
        let mut out = Vec::new();
        self.any(ray, t_min, t_max, |p| {
            out.push(p);
            false
        });
        out
    }
}

impl Builder {
    fn build_node(&mut self, prims: &mut [BuildPrim], depth: usize) {
        let bounds = prims.iter().fold(Aabb::EMPTY, |b, p| b.union(&p.bounds));
        let me = self.nodes.len();
        self.nodes.push(Node {
            min: bounds.min,
            max: bounds.max,
            offset: 0,
            count: 0,
        });
        let split = if prims.len() <= 1 {
            None
        } else {
            self.choose_split(prims, &bounds, depth)
        };
        match split {
            None => {
                self.nodes[me].offset = self.order.len() as u32;
                self.nodes[me].count = prims.len() as u16;
                self.order.extend(prims.iter().map(|p| p.index));
            }
            Some((_axis, mid)) => {
                let (left, right) = prims.split_at_mut(mid);
                self.build_node(left, depth + 1);
                self.nodes[me].offset = self.nodes.len() as u32;
                self.build_node(right, depth + 1);
            }
        }
    }

    /// Partitions `prims` and returns the axis and the split index, or `None` for a leaf.
    fn choose_split(
        &self,
        prims: &mut [BuildPrim],
        bounds: &Aabb,
        depth: usize,
    ) -> Option<(usize, usize)> {
        let cb = prims.iter().fold(Aabb::EMPTY, |b, p| b.grow(p.centroid));
        let extent = cb.max - cb.min;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let n = prims.len();
        if extent[axis] <= 0.0 || depth >= SAH_MAX_DEPTH {
            if n <= MAX_LEAF_PRIMS && extent[axis] <= 0.0 {
                return None;
            }
            // All centroids coincide, or the tree is deep: split at the median index.
            return Some(median_split(prims, axis));
        }
        let bin_of = |c: f64| {
            (((c - cb.min[axis]) / extent[axis] * SAH_BINS as f64) as usize).min(SAH_BINS - 1)
        };
        let mut counts = [0usize; SAH_BINS];
        let mut boxes = [Aabb::EMPTY; SAH_BINS];
        for p in prims.iter() {
            let b = bin_of(p.centroid[axis]);
            counts[b] += 1;
            boxes[b] = boxes[b].union(&p.bounds);
        }
        let mut right_area = [0.0; SAH_BINS];
        let (mut acc, mut acc_n) = (Aabb::EMPTY, 0);
        let mut right_n = [0usize; SAH_BINS];
        for i in (1..SAH_BINS).rev() {
            acc = acc.union(&boxes[i]);
            acc_n += counts[i];
            right_area[i] = acc.half_area();
            right_n[i] = acc_n;
        }
        let (mut best_cost, mut best_bin) = (f64::INFINITY, 0);
        let (mut left, mut left_n) = (Aabb::EMPTY, 0);
        for i in 1..SAH_BINS {
            left = left.union(&boxes[i - 1]);
            left_n += counts[i - 1];
            if left_n == 0 || right_n[i] == 0 {
                continue;
            }
            let cost = left.half_area() * left_n as f64 + right_area[i] * right_n[i] as f64;
            if cost < best_cost {
                best_cost = cost;
                best_bin = i;
            }
        }
        // Traversal costs about as much as one primitive test.
        let leaf_cost = bounds.half_area() * n as f64;
        let split_cost = bounds.half_area() + best_cost;
        if best_bin == 0 || (n <= MAX_LEAF_PRIMS && leaf_cost <= split_cost) {
            if n <= MAX_LEAF_PRIMS {
                return None;
            }
            return Some(median_split(prims, axis));
        }
        let mut mid = 0;
        for i in 0..n {
            if bin_of(prims[i].centroid[axis]) < best_bin {
                prims.swap(i, mid);
                mid += 1;
            }
        }
        Some((axis, mid))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box(c: DVec3) -> Aabb {
        Aabb {
            min: c - 0.5,
            max: c + 0.5,
        }
    }

    #[test]
    fn closest_box_along_a_line() {
        let boxes: Vec<Aabb> = (0..100)
            .map(|i| unit_box(DVec3::new(0.0, 0.0, i as f64 * 2.0)))
            .collect();
        let bvh = Bvh::build(&boxes);
        assert_eq!(bvh.len(), 100);
        let ray = SlabRay::new(DVec3::new(0.0, 0.0, -10.0), DVec3::Z);
        let mut tested = 0;
        let t = bvh.closest(&ray, 0.0, f64::INFINITY, |p, t_max| {
            tested += 1;
            let t = (p as f64 * 2.0 - 0.5) + 10.0;
            if t < t_max { t } else { t_max }
        });
        assert_eq!(t, 9.5);
        assert!(
            tested < 20,
            "near-first traversal should prune, tested {tested}"
        );
    }

    #[test]
    fn identical_boxes_do_not_recurse_forever() {
        let boxes = vec![unit_box(DVec3::ZERO); 1000];
        let bvh = Bvh::build(&boxes);
        let ray = SlabRay::new(DVec3::new(0.0, 0.0, -10.0), DVec3::Z);
        assert_eq!(bvh.candidates(&ray, 0.0, f64::INFINITY).len(), 1000);
    }

    #[test]
    fn any_stops_early_and_misses() {
        let boxes: Vec<Aabb> = (0..10)
            .map(|i| unit_box(DVec3::new(i as f64 * 3.0, 0.0, 0.0)))
            .collect();
        let bvh = Bvh::build(&boxes);
        let up = SlabRay::new(DVec3::new(9.0, -5.0, 0.0), DVec3::Y);
        assert!(bvh.any(&up, 0.0, f64::INFINITY, |p| p == 3));
        assert!(!bvh.any(&up, 0.0, 1.0, |_| true));
    }

    /// The surface of box `b` (closed, faces included): the first `λ` in
    /// `(t_min, t_max]` where the ray meets it, divided exactly rather than by the slab
    /// test's reciprocal, so it is a reference independent of the BVH's arithmetic.
    fn box_surface(b: &Aabb, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<f64> {
        let (mut near, mut far) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            if d[a] == 0.0 {
                if o[a] < b.min[a] || o[a] > b.max[a] {
                    return None;
                }
            } else {
                let (t0, t1) = ((b.min[a] - o[a]) / d[a], (b.max[a] - o[a]) / d[a]);
                near = near.max(t0.min(t1));
                far = far.min(t0.max(t1));
            }
        }
        if near > far {
            return None;
        }
        [near, far].into_iter().find(|&t| t > t_min && t <= t_max)
    }

    /// The closest box surface and its index, ties to the lower index, as the world's
    /// leaf function resolves them.
    fn closest_of(
        boxes: &[Aabb],
        o: DVec3,
        d: DVec3,
        visit: impl FnOnce(&mut dyn FnMut(u32, f64) -> f64),
    ) -> Option<(f64, u32)> {
        let mut best: Option<(f64, u32)> = None;
        visit(
            &mut |i, limit| match box_surface(&boxes[i as usize], o, d, 1e-9, limit) {
                Some(t) if t < limit || best.is_some_and(|(bt, bi)| t == bt && i < bi) => {
                    best = Some((t, i));
                    t
                }
                _ => limit,
            },
        );
        best
    }

    /// Boxes on a half-unit grid, so that many share faces, edges and corners.
    fn grid_box() -> impl Strategy<Value = Aabb> {
        (
            prop::array::uniform3(-8i32..8),
            prop::array::uniform3(1i32..6),
        )
            .prop_map(|(c, e)| {
                let min = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * 0.5;
                let ext = DVec3::new(e[0] as f64, e[1] as f64, e[2] as f64) * 0.5;
                Aabb {
                    min,
                    max: min + ext,
                }
            })
    }

    /// Rays that graze: origins on grid points (so on faces, edges and corners),
    /// directions along the axes or the grid's diagonals (so along face planes), and
    /// some arbitrary ones.
    fn grazing_ray() -> impl Strategy<Value = (DVec3, DVec3)> {
        let grid = prop::array::uniform3(-12i32..12)
            .prop_map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * 0.5);
        let free = prop::array::uniform3(-6.0f64..6.0).prop_map(DVec3::from);
        let origin = prop_oneof![3 => grid, 1 => free];
        let steps = prop::array::uniform3(-1i32..=1)
            .prop_filter("a direction", |d| d != &[0, 0, 0])
            .prop_map(|d| DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64));
        let any = prop::array::uniform3(-1.0f64..1.0)
            .prop_filter("a direction", |d| d != &[0.0; 3])
            .prop_map(DVec3::from);
        let dir = prop_oneof![3 => steps, 1 => any];
        (origin, dir)
    }

    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn tree_finds_what_every_box_finds(
            boxes in prop::collection::vec(grid_box(), 1..80),
            rays in prop::collection::vec(grazing_ray(), 1..40),
        ) {
            let bvh = Bvh::build(&boxes);
            for (o, d) in rays {
                let ray = SlabRay::new(o, d);
                let fast = closest_of(&boxes, o, d, |leaf| {
                    bvh.closest(&ray, 1e-9, f64::INFINITY, leaf);
                });
                let slow = closest_of(&boxes, o, d, |leaf| {
                    let mut limit = f64::INFINITY;
                    for i in 0..boxes.len() as u32 {
                        limit = leaf(i, limit);
                    }
                });
                prop_assert_eq!(fast, slow, "ray {:?} + λ {:?}", o, d);
                let t_max = slow.map_or(3.0, |(t, _)| t);
                let blocked = |i: u32| box_surface(&boxes[i as usize], o, d, 1e-9, t_max).is_some();
                prop_assert_eq!(
                    bvh.any(&ray, 1e-9, t_max, blocked),
                    (0..boxes.len() as u32).any(blocked)
                );
            }
        }
    }
}
