//! A bounding volume hierarchy: binned surface-area-heuristic build, flat node array,
//! near-child-first traversal. Used over a scene's objects (world space) and over a
//! mesh's triangles (object space), so the cost of a ray grows with the logarithm of the
//! number of primitives.
//!
//! Boxes are padded by a tiny relative margin and the slab test rounds its far distance
//! up, so the hierarchy never loses a hit that testing every primitive would find; ties
//! are resolved by the caller's leaf function (nodes are entered when their entry `λ`
//! is *at most* the best so far, so a tie in a later node is still seen).

use glam::DVec3;

use super::bounds::{Aabb, SlabRay};

/// Primitives per leaf at most, when the SAH would rather not split.
const MAX_LEAF_PRIMS: usize = 4;
/// SAH bins per axis.
const SAH_BINS: usize = 12;
/// Below this depth the SAH is used; deeper, a plain median split bounds the depth.
const SAH_MAX_DEPTH: usize = 48;
/// Traversal stack size: enough for `SAH_MAX_DEPTH` plus a median tree of 2³² leaves.
const STACK_SIZE: usize = 96;

#[derive(Debug, Clone, Copy)]
struct Node {
    min: DVec3,
    max: DVec3,
    /// Leaf: first index into `order`. Interior: index of the second child (the first
    /// child follows the node).
    offset: u32,
    /// Leaf: primitive count (> 0). Interior: 0.
    count: u16,
    /// Interior: the split axis, for near-child-first traversal.
    axis: u16,
}

/// A BVH over primitives given by their bounds.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Primitive indices in leaf order.
    order: Vec<u32>,
}

struct BuildPrim {
    bounds: Aabb,
    centroid: DVec3,
    index: u32,
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
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * prims.len() / MAX_LEAF_PRIMS + 1),
            order: Vec::with_capacity(prims.len()),
        };
        if !prims.is_empty() {
            bvh.build_node(&mut prims, 0);
        }
        bvh
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
        self.nodes.first().map_or(Aabb::EMPTY, |n| Aabb {
            min: n.min,
            max: n.max,
        })
    }

    fn build_node(&mut self, prims: &mut [BuildPrim], depth: usize) {
        let bounds = prims.iter().fold(Aabb::EMPTY, |b, p| b.union(&p.bounds));
        let me = self.nodes.len();
        self.nodes.push(Node {
            min: bounds.min,
            max: bounds.max,
            offset: 0,
            count: 0,
            axis: 0,
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
            Some((axis, mid)) => {
                let (left, right) = prims.split_at_mut(mid);
                self.nodes[me].axis = axis as u16;
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
            let mid = n / 2;
            prims.select_nth_unstable_by(mid, |a, b| {
                a.centroid[axis]
                    .total_cmp(&b.centroid[axis])
                    .then(a.index.cmp(&b.index))
            });
            return Some((axis, mid));
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
            let mid = n / 2;
            prims.select_nth_unstable_by(mid, |a, b| {
                a.centroid[axis]
                    .total_cmp(&b.centroid[axis])
                    .then(a.index.cmp(&b.index))
            });
            return Some((axis, mid));
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

    /// Visits, near first, every primitive whose box the ray enters before the best
    /// `λ` so far. `leaf(prim, t_max)` tests one primitive and returns the new best `λ`
    /// (or `t_max` unchanged).
    #[inline]
    pub fn closest<F: FnMut(u32, f64) -> f64>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        mut t_max: f64,
        mut leaf: F,
    ) -> f64 {
        if self.nodes.is_empty() {
            return t_max;
        }
        let mut stack = [0u32; STACK_SIZE];
        let mut sp = 0usize;
        let mut i = 0usize;
        loop {
            let node = &self.nodes[i];
            if ray.enter(node.min, node.max, t_min, t_max).is_some() {
                if node.count > 0 {
                    let start = node.offset as usize;
                    for &p in &self.order[start..start + node.count as usize] {
                        t_max = leaf(p, t_max);
                    }
                } else {
                    let (near, far) = if ray.negative(node.axis as usize) {
                        (node.offset as usize, i + 1)
                    } else {
                        (i + 1, node.offset as usize)
                    };
                    if sp < STACK_SIZE {
                        stack[sp] = far as u32;
                        sp += 1;
                    }
                    i = near;
                    continue;
                }
            }
            if sp == 0 {
                return t_max;
            }
            sp -= 1;
            i = stack[sp] as usize;
        }
    }

    /// Whether `leaf(prim)` is true for some primitive whose box the ray enters within
    /// `(t_min, t_max)`; stops at the first.
    #[inline]
    pub fn any<F: FnMut(u32) -> bool>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        t_max: f64,
        mut leaf: F,
    ) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let mut stack = [0u32; STACK_SIZE];
        let mut sp = 0usize;
        let mut i = 0usize;
        loop {
            let node = &self.nodes[i];
            if ray.enter(node.min, node.max, t_min, t_max).is_some() {
                if node.count > 0 {
                    let start = node.offset as usize;
                    if self.order[start..start + node.count as usize]
                        .iter()
                        .any(|&p| leaf(p))
                    {
                        return true;
                    }
                } else {
                    if sp < STACK_SIZE {
                        stack[sp] = node.offset;
                        sp += 1;
                    }
                    i += 1;
                    continue;
                }
            }
            if sp == 0 {
                return false;
            }
            sp -= 1;
            i = stack[sp] as usize;
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
}
