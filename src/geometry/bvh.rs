//! A bounding volume hierarchy: binned surface-area-heuristic build, flat node arrays
//! whose interior nodes hold both children's boxes, nearer-child-first traversal, and
//! for rays that ask only whether anything blocks them, the same tree collapsed to eight
//! children a node. Used over a scene's objects (world space) and over a mesh's
//! triangles (object space), so the cost of a ray grows with the logarithm of the
//! number of primitives.
//!
//! Boxes are padded by a tiny relative margin and the slab test rounds its far distance
//! up, so the hierarchy never loses a hit that testing every primitive would find; ties
//! are resolved by the caller's leaf function (nodes are entered when their entry `λ`
//! is *at most* the best so far, so a tie in a later node is still seen).

use arrayvec::ArrayVec;
use glam::DVec3;
use rayon::prelude::*;

use super::arith::{Eight, Lanes4};
#[cfg(target_arch = "x86_64")]
use super::bounds::x86::{Avx2, Avx512};
use super::bounds::{
    Aabb, Box32, BoxPair32, PairTest8, SlabRay, SlabRay4, SlabRays8, WideTest, box32, lanes_of,
    lanes8, within8,
};
use super::ray::{Ray, Rays8};
use wide::{f32x4, f32x8};

/// Primitives per leaf at most, when the SAH would rather not split.
const MAX_LEAF_PRIMS: usize = 4;
/// SAH bins per axis.
const SAH_BINS: usize = 12;
/// Below this depth the SAH is used; deeper, a plain median split bounds the depth.
const SAH_MAX_DEPTH: usize = 48;
/// Subtrees of at least this many primitives have their two halves built in parallel
/// (the tree is the same): below it, a task would cost more than it saves.
const PARALLEL_PRIMS: usize = 8192;
/// Trees of at least this many inner nodes are also collapsed to wide nodes for
/// [`Bvh::any`]. A smaller tree is crossed in a few binary steps, and a ray's set-up
/// for the single-precision test costs more than the wide nodes save: `classic`'s
/// nine objects (three inner nodes) rendered with 5 % more instructions through them,
/// and 3.5 % slower, even with the ray's lanes made in AVX2 (`Avx2::wide_ray`).
const WIDE_FROM: usize = 16;
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
}

impl Node {
    /// A node over `side`'s box, its references (a leaf's primitives, an inner node's
    /// second child) set once known.
    fn over(side: &Side) -> Node {
        Node {
            min: side.bounds.min,
            max: side.bounds.max,
            offset: 0,
            count: 0,
        }
    }
}

/// An interior node for traversal: the boxes of both children, so one visit tests
/// both and goes to the nearer first (and skips a child the ray misses without
/// pushing it).
///
/// Boxes are stored axis by axis with the two children side by side, so that both slab
/// tests run as two-lane vector operations.
#[derive(Debug, Clone, Copy)]
struct Inner {
    /// `min[axis][child]`.
    min: [[f64; 2]; 3],
    /// `max[axis][child]`.
    max: [[f64; 2]; 3],
    /// Each child: an index into `inner`, or `LEAF | index` into `leaves`.
    child: [u32; 2],
}

/// An inner node as packets of rays traverse it: its children's boxes in single
/// precision and their references, in one cache line, so that a packet reads one line
/// a node and none of [`Inner`] (for 100 000 triangles, a third fewer first-level
/// cache misses than with the boxes and the children in two arrays).
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
struct PacketNode {
    boxes: BoxPair32,
    /// As [`Inner::child`].
    child: [u32; 2],
}

/// Children of a node of the wide tree ([`WideNode`]).
pub(super) const WIDE: usize = 8;

/// A node of the wide tree that a lone ray looking for any hit traverses
/// ([`Bvh::any`]): up to eight subtrees of the binary tree, collapsed, with their boxes
/// in single precision lane by lane, so that one pass of eight lanes tests them all
/// ([`WideTest`]). A shadow ray visits about a third as many of them as of binary
/// nodes, and needs no order among the children it enters.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct WideNode {
    /// `planes[k][c]`: coordinate `k` of child `c`'s box, in [`Box32`]'s order.
    planes: [[f32; WIDE]; 6],
    /// Each child: an index into `wide`, or `LEAF | index` into `leaves`.
    child: [u32; WIDE],
    /// A bit per lane that holds a child.
    used: u32,
}

/// The surface of a single-precision box (in f64, so that no product overflows).
fn surface32(b: &Box32) -> f64 {
    let d = [0, 1, 2].map(|a| f64::from(b[a + 3]) - f64::from(b[a]));
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

/// Marks a child reference as a leaf.
const LEAF: u32 = 1 << 31;

/// A BVH over primitives given by their bounds.
#[derive(Debug, Clone)]
pub struct Bvh {
    /// The tree as built, each node with its own box (kept for its bounds and shape).
    nodes: Vec<Node>,
    /// The tree as traversed.
    inner: Vec<Inner>,
    /// Each of `inner` as packets of rays traverse it ([`Bvh::closest8`]).
    packet: Vec<PacketNode>,
    /// The root's box in single precision.
    root32: Box32,
    /// The tree collapsed to eight children a node ([`Bvh::any`]).
    wide: Vec<WideNode>,
    /// Its root: an index into `wide` or `LEAF | index`.
    wide_root: u32,
    /// Leaves: `(first, count)` into `order`.
    leaves: Vec<(u32, u32)>,
    /// The root: an index into `inner` or `LEAF | index` (when the tree is one leaf).
    root: u32,
    /// Primitive indices in leaf order.
    order: Vec<u32>,
}

struct BuildPrim {
    bounds: Aabb,
    centroid: DVec3,
    index: u32,
    /// The SAH bin of the centroid, set while binning the node being split, so that
    /// the partition does not compute it again (in what would be padding).
    bin: u32,
}

/// One side of a split as the build needs it: the union of its primitives' boxes (the
/// node's box) and of their centroids (what its own split bins).
#[derive(Clone, Copy)]
struct Side {
    bounds: Aabb,
    centroids: Aabb,
}

impl Side {
    const EMPTY: Side = Side {
        bounds: Aabb::EMPTY,
        centroids: Aabb::EMPTY,
    };

    /// Both unions, in one pass over `prims`.
    fn of(prims: &[BuildPrim]) -> Side {
        prims.iter().fold(Side::EMPTY, |s, p| s.with(p))
    }

    /// The side with `p` added.
    fn with(&self, p: &BuildPrim) -> Side {
        Side {
            bounds: self.bounds.union(&p.bounds),
            centroids: self.centroids.grow(p.centroid),
        }
    }

    /// The side holding both.
    fn join(&self, o: &Side) -> Side {
        Side {
            bounds: self.bounds.union(&o.bounds),
            centroids: self.centroids.union(&o.centroids),
        }
    }
}

/// `prims` cut at `mid` into a split's two halves, each with its [`Side`]: the SAH's
/// bins give both (`sides`), a median split's are folded from its halves.
// Inlined: left a call, it returned the halves through memory, 30 instructions a node.
#[inline(always)]
fn cut(
    prims: &mut [BuildPrim],
    mid: usize,
    sides: Option<[Side; 2]>,
) -> [(&mut [BuildPrim], Side); 2] {
    let (left, right) = prims.split_at_mut(mid);
    let [l, r] = sides.unwrap_or_else(|| [Side::of(left), Side::of(right)]);
    [(left, l), (right, r)]
}

/// Splits `prims` at the median centroid along `axis`, ties broken by index so the tree
/// does not depend on the sort's order.
fn median_split(prims: &mut [BuildPrim], axis: usize) -> usize {
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid[axis]
            .total_cmp(&b.centroid[axis])
            .then(a.index.cmp(&b.index))
    });
    mid
}

impl Bvh {
    /// Builds over `bounds[i]` for every `i`, on the calling thread; empty boxes are
    /// left out. `test_cost` is what testing a ray against one primitive costs, in
    /// tests of a node's boxes: the surface area heuristic splits a few primitives
    /// further, rather than leaving them in one leaf, the more a primitive costs.
    pub fn build(bounds: &[Aabb], test_cost: f64) -> Bvh {
        Bvh::build_from(bounds, test_cost, 1, usize::MAX)
    }

    /// [`Bvh::build`] for a caller that tests a leaf's primitives `lanes` at a time
    /// (see [`Bvh::into_slots`]): `group_cost` is what testing a ray against a group of
    /// up to `lanes` costs, and the surface area heuristic counts a leaf's cost, and
    /// each side's of a split, in groups. `parallel` builds as
    /// [`Bvh::build_in_parallel`] does (the same tree), under the same condition.
    pub fn build_in_groups(bounds: &[Aabb], group_cost: f64, lanes: usize, parallel: bool) -> Bvh {
        let parallel_from = if parallel { PARALLEL_PRIMS } else { usize::MAX };
        Bvh::build_from(bounds, group_cost, lanes.max(1), parallel_from)
    }

    /// [`Bvh::build`], the two halves of every subtree of 8192 (`PARALLEL_PRIMS`) or more
    /// primitives built in parallel on the current rayon pool: the same tree. Not for a
    /// caller holding a lock that another job on the pool may ask for (a mesh building
    /// inside its `OnceLock`): while it waits for a half, a rayon thread runs other jobs,
    /// and one of them could wait for that lock, on the very thread that holds it. (A
    /// mesh builds before it takes its lock, [`CanonicalShape::prepare`].)
    ///
    /// [`CanonicalShape::prepare`]: super::shapes::CanonicalShape::prepare
    pub fn build_in_parallel(bounds: &[Aabb], test_cost: f64) -> Bvh {
        Bvh::build_from(bounds, test_cost, 1, PARALLEL_PRIMS)
    }

    fn build_from(bounds: &[Aabb], test_cost: f64, lanes: usize, parallel_from: usize) -> Bvh {
        let parallel = parallel_from != usize::MAX;
        let prim = |(i, b): (usize, &Aabb)| {
            let bounds = b.padded();
            BuildPrim {
                bounds,
                centroid: bounds.centroid(),
                index: i as u32,
                bin: 0,
            }
        };
        // Made in place, one per box (on every worker when building in parallel: for
        // 100 000 objects 5.5 ms on one thread, most of it the new vector's page
        // faults); the empty boxes (objects without bounds), rare, are then dropped.
        let mut prims: Vec<BuildPrim> = if parallel {
            bounds.par_iter().enumerate().map(prim).collect()
        } else {
            bounds.iter().enumerate().map(prim).collect()
        };
        prims.retain(|p| !bounds[p.index as usize].is_empty());
        let built = if prims.is_empty() {
            Builder::default()
        } else {
            let split = Split {
                test_cost,
                lanes,
                parallel_from,
            };
            Builder::tree(&mut prims, split)
        };
        let mut bvh = Bvh {
            nodes: built.nodes,
            inner: Vec::new(),
            packet: Vec::new(),
            wide: Vec::new(),
            wide_root: LEAF,
            root32: box32(&Aabb::EMPTY),
            leaves: Vec::new(),
            root: LEAF,
            order: built.order,
        };
        if !bvh.nodes.is_empty() {
            bvh.flatten(parallel);
            bvh.root32 = box32(&bvh.bounds());
        }
        bvh
    }

    /// Converts the built tree to the traversal layout. `nodes` lists the tree depth
    /// first (a node, its first subtree, its second), so numbering its inner nodes and
    /// its leaves apart, in that order, numbers them depth first too; each inner node
    /// then takes its children's boxes, f64 and f32, on its own (on every worker when
    /// `parallel`, where for 100 000 objects it was 14 ms on one thread).
    fn flatten(&mut self, parallel: bool) {
        let nodes = &self.nodes;
        // Each node's reference (`LEAF | its leaf number`, or its inner node number),
        // the leaves, and the inner nodes' places in `nodes`, in one pass: a binary
        // tree of n nodes has (n + 1) / 2 leaves.
        let mut refs = Vec::with_capacity(nodes.len());
        let mut leaves = Vec::with_capacity(nodes.len().div_ceil(2));
        let mut interior = Vec::with_capacity(nodes.len() / 2);
        for (i, n) in (0..).zip(nodes) {
            if n.count > 0 {
                refs.push(LEAF | leaves.len() as u32);
                leaves.push((n.offset, n.count as u32));
            } else {
                refs.push(interior.len() as u32);
                interior.push(i);
            }
        }
        let node = |&i: &u32| {
            let (l, r) = (i as usize + 1, nodes[i as usize].offset as usize);
            let (a, b) = (nodes[l], nodes[r]);
            let [ba, bb] = [a, b].map(|c| Aabb {
                min: c.min,
                max: c.max,
            });
            let boxes = BoxPair32::new(&ba, &bb);
            let child = [refs[l], refs[r]];
            let node = Inner {
                min: [[a.min.x, b.min.x], [a.min.y, b.min.y], [a.min.z, b.min.z]],
                max: [[a.max.x, b.max.x], [a.max.y, b.max.y], [a.max.z, b.max.z]],
                child,
            };
            (node, PacketNode { boxes, child })
        };
        (self.inner, self.packet) = if parallel {
            interior.par_iter().map(node).unzip()
        } else {
            interior.iter().map(node).unzip()
        };
        self.leaves = leaves;
        self.root = refs[0];
        self.wide_root = self.root;
        if self.inner.len() >= WIDE_FROM {
            let mut wide = Vec::with_capacity(self.packet.len() / 2 + 1);
            self.wide_root = self.collapse(self.root, &mut wide);
            self.wide = wide;
        }
    }

    /// Collapses the binary subtree at inner node `node` into wide nodes appended to
    /// `wide`, returning its index: a node takes its two children, then splits the
    /// inner child of largest surface into its own two while it has fewer than
    /// [`WIDE`] (the children a ray most likely enters are opened first).
    fn collapse(&self, node: u32, wide: &mut Vec<WideNode>) -> u32 {
        let two = |i: u32| {
            let n = &self.packet[i as usize];
            [0, 1].map(|c| (n.child[c], n.boxes.child(c)))
        };
        let mut slots: ArrayVec<(u32, Box32), WIDE> = two(node).into_iter().collect();
        while slots.len() < WIDE {
            let widest = slots
                .iter()
                .enumerate()
                .filter(|(_, (r, _))| r & LEAF == 0)
                .map(|(k, (_, b))| (k, surface32(b)))
                .reduce(|a, b| if b.1 > a.1 { b } else { a });
            let Some((k, _)) = widest else { break };
            let [a, b] = two(slots[k].0);
            slots[k] = a;
            slots.insert(k + 1, b);
        }
        // The node's place first, so that its subtrees follow it (depth first).
        let at = wide.len();
        let mut n = WideNode {
            planes: [[0.0; WIDE]; 6],
            child: [LEAF; WIDE],
            used: (1 << slots.len()) - 1,
        };
        wide.push(n);
        for (c, &(r, b)) in slots.iter().enumerate() {
            n.child[c] = if r & LEAF != 0 {
                r
            } else {
                self.collapse(r, wide)
            };
            for (k, &x) in b.iter().enumerate() {
                n.planes[k][c] = x;
            }
        }
        wide[at] = n;
        at as u32
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

    /// The same tree with its leaves naming slots instead of primitive indices, for a
    /// caller that stores its primitives leaf by leaf in groups of `lanes` slots, to
    /// test a leaf's primitives together: each leaf's primitives take consecutive
    /// slots, in one group where they fit in one. A group's last slots are left empty
    /// only where the next leaf would not fit in them, so a leaf of `k ≤ lanes`
    /// primitives leaves at most `k − 1` empty before it: at most 1.75 slots a
    /// primitive for groups of four. Also, for each slot, the primitive stored there
    /// (`None`: an empty slot).
    pub fn into_slots(mut self, lanes: usize) -> (Bvh, Vec<Option<u32>>) {
        let lanes = lanes.max(1);
        let mut held = Vec::with_capacity(self.order.len());
        for &(first, count) in &self.leaves {
            let used = held.len() % lanes;
            if used != 0 && used + count as usize > lanes {
                held.resize(held.len().next_multiple_of(lanes), None);
            }
            for k in first as usize..(first + count) as usize {
                let prim = self.order[k];
                self.order[k] = held.len() as u32;
                held.push(Some(prim));
            }
        }
        (self, held)
    }

    /// The bounds of everything held.
    pub fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, |n| Aabb {
            min: n.min,
            max: n.max,
        })
    }

    /// Visits, near first, every primitive whose box the ray enters before the best
    /// `λ` so far. `leaf(prim, t_max)` tests one primitive and returns the new best `λ`
    /// (or `t_max` unchanged).
    #[inline]
    pub fn closest<F: FnMut(u32, f64) -> f64>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        t_max: f64,
        mut leaf: F,
    ) -> f64 {
        self.closest_by_leaf(
            ray,
            t_min,
            t_max,
            #[inline(always)]
            |prims, mut t_max| {
                for &p in prims {
                    t_max = leaf(p, t_max);
                }
                t_max
            },
        )
    }

    /// [`Bvh::closest`], a leaf at a time: `leaf(prims, t_max)` tests the primitives
    /// of a leaf and returns the new best `λ` (or `t_max` unchanged).
    #[inline]
    pub fn closest_by_leaf<F: FnMut(&[u32], f64) -> f64>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        mut t_max: f64,
        mut leaf: F,
    ) -> f64 {
        let Some(root) = self.nodes.first() else {
            return t_max;
        };
        if ray.enter(root.min, root.max, t_min, t_max).is_none() {
            return t_max;
        }
        // ArrayVec: a fixed stack that is not zeroed on every call (this runs per ray).
        let mut stack: ArrayVec<(u32, f64), STACK_SIZE> = ArrayVec::new();
        let mut cur = self.root;
        loop {
            if cur & LEAF != 0 {
                let (start, count) = self.leaves[(cur & !LEAF) as usize];
                t_max = leaf(&self.order[start as usize..(start + count) as usize], t_max);
            } else {
                let n = &self.inner[cur as usize];
                let (h0, h1) = ray.enter2(&n.min, &n.max, t_min, t_max);
                match (h0, h1) {
                    (Some(a), Some(b)) => {
                        let (near, far, t_far) = if a <= b {
                            (n.child[0], n.child[1], b)
                        } else {
                            (n.child[1], n.child[0], a)
                        };
                        // A full stack drops the far subtree: unreachable within the
                        // depth bound the build guarantees.
                        let _ = stack.try_push((far, t_far));
                        cur = near;
                        continue;
                    }
                    (Some(_), None) => {
                        cur = n.child[0];
                        continue;
                    }
                    (None, Some(_)) => {
                        cur = n.child[1];
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next subtree that may still hold something nearer (or tied).
            loop {
                let Some((node, t)) = stack.pop() else {
                    return t_max;
                };
                if t <= t_max {
                    cur = node;
                    break;
                }
            }
        }
    }

    /// [`Bvh::closest`] for eight rays at once (a packet, given as two of four), the
    /// lanes of `active`: the tree is traversed once, each node's boxes tested for all
    /// eight rays, while a subtree that some active ray enters remains.
    /// `leaf(prims, rays, t_max)` tests a leaf's primitives for the rays of the bit set
    /// `rays` (those that entered the leaf) and lowers their `t_max`. A ray is given every
    /// primitive [`Bvh::closest`] would give it, and maybe others, so a leaf function
    /// whose result does not depend on the order it sees primitives in (the closest
    /// hit, ties to the lowest index) finds for each ray what it finds alone. `t_min`
    /// is not negative.
    ///
    /// Each node's two boxes are tested for the eight rays in one pass of sixteen lanes
    /// where the processor has AVX-512 ([`SlabRay16`](super::bounds::x86::SlabRay16)),
    /// in two passes of eight where it has AVX2, else in four of four: the same
    /// operations each way, so the traversal and its results are the same.
    ///
    /// Of two children that some ray enters both of, the traversal goes first to the
    /// one that ray enters first, or, with `FAR_FIRST`, to the other (for
    /// [`Bvh::any8`]).
    #[inline]
    pub fn closest8<const FAR_FIRST: bool, F: FnMut(&[u32], u32, &mut [f64; 8])>(
        &self,
        rays: &[SlabRay4; 2],
        t_min: f64,
        t_max: &mut [f64; 8],
        active: u32,
        leaf: F,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            if let Some(avx512) = Avx512::detect() {
                // Always inlined into `run`'s function, so that the whole traversal (its
                // leaves' tests too) is compiled for these instruction sets.
                return avx512.run(
                    #[inline(always)]
                    || {
                        let sixteen = avx512.widen(rays);
                        self.traverse8::<FAR_FIRST, _, _>(
                            rays, &sixteen, t_min, t_max, active, leaf,
                        )
                    },
                );
            }
            if let Some(avx2) = Avx2::detect() {
                return avx2.run(
                    #[inline(always)]
                    || {
                        let eight = [avx2.widen(&rays[0]), avx2.widen(&rays[1])];
                        self.traverse8::<FAR_FIRST, _, _>(rays, &eight, t_min, t_max, active, leaf)
                    },
                );
            }
        }
        self.traverse8::<FAR_FIRST, _, _>(rays, rays, t_min, t_max, active, leaf)
    }

    /// Which of eight rays (the lanes of `active`, a packet given as two of four) some
    /// primitive occludes within `(t_min, t_max[lane])`: the bit set of those.
    /// `leaf(prims, rays)` tests a leaf's primitives for the rays of the bit set `rays`
    /// (those that entered the leaf and are not yet occluded) and returns those some
    /// primitive occludes.
    ///
    /// The traversal is [`Bvh::closest8`]'s, but of two children it goes first to the
    /// farther: a shadow ray starts on a surface, so the subtree around its origin is
    /// entered by every ray and seldom blocks it, while what does block it lies
    /// farther on, toward the light (`mesh-100k`'s render: 2.8 % fewer instructions,
    /// 6 % less time). An occluded ray's limit drops to −∞, so it enters no further
    /// box and no subtree is popped for it, and the traversal ends once every ray is
    /// occluded or has left the tree. Each ray is given every
    /// primitive [`Bvh::any`] would give it until one occludes it, so the answer is the
    /// same as alone.
    #[inline]
    pub fn any8<F: FnMut(&[u32], u32) -> u32>(
        &self,
        rays: &[SlabRay4; 2],
        t_min: f64,
        t_max: [f64; 8],
        active: u32,
        mut leaf: F,
    ) -> u32 {
        let mut occluded = 0;
        let mut limits = t_max;
        self.closest8::<true, _>(
            rays,
            t_min,
            &mut limits,
            active,
            #[inline(always)]
            |prims, rays_in, limits| {
                let open = rays_in & !occluded;
                if open == 0 {
                    return;
                }
                let found = leaf(prims, open) & open;
                occluded |= found;
                for lane in lanes_of(found) {
                    limits[lane] = f64::NEG_INFINITY;
                }
            },
        );
        occluded
    }

    /// [`Bvh::closest8`], testing each node's boxes with `pairs` (`rays` themselves, or
    /// the same rays in wider lanes).
    #[inline(always)]
    fn traverse8<const FAR_FIRST: bool, P: PairTest8, F: FnMut(&[u32], u32, &mut [f64; 8])>(
        &self,
        rays: &[SlabRay4; 2],
        pairs: &P,
        t_min: f64,
        t_max: &mut [f64; 8],
        active: u32,
        mut leaf: F,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let t_min = t_min as f32;
        // The limits as the box tests read them (the root's test too), rounded again
        // only when a leaf may have lowered them, not at every node.
        let mut limits = lanes8(t_max);
        // The whole tree's box is tested only where the root is a leaf, whose box is
        // then the only test before its primitives. An inner root's two boxes are
        // tested next, at about the cost of the root's one, and a ray that misses the
        // root's box misses theirs, which it holds (each rounded outward alike): tested
        // first, it cost every packet that enters the tree a test more (hit data
        // instructions −1.3 % on spheres-1k and −1.1 % on cubes-10k without it).
        let mut mask = active;
        if self.root & LEAF != 0 {
            let [lo, hi]: [f32x4; 2] = bytemuck::cast(limits);
            let enter = |r: &SlabRay4, t| r.enter(&self.root32, f32x4::splat(t_min), t).0;
            mask &= enter(&rays[0], lo) | enter(&rays[1], hi) << 4;
        }
        if mask == 0 {
            return;
        }
        // (subtree, its rays, their entry λ).
        let mut stack: ArrayVec<(u32, u32, f32x8), STACK_SIZE> = ArrayVec::new();
        let mut cur = self.root;
        loop {
            if cur & LEAF != 0 {
                let (start, count) = self.leaves[(cur & !LEAF) as usize];
                leaf(
                    &self.order[start as usize..(start + count) as usize],
                    mask,
                    t_max,
                );
                limits = lanes8(t_max);
            } else {
                let n = &self.packet[cur as usize];
                let [(m0, near0), (m1, near1)] = pairs.enter_pair8(&n.boxes, t_min, limits);
                let (m0, m1) = (m0 & mask, m1 & mask);
                if m0 != 0 && m1 != 0 {
                    // The nearer child first, as the first ray that enters both sees it
                    // (the farther with `FAR_FIRST`).
                    let both = m0 & m1;
                    let first = if both != 0 {
                        let lane = both.trailing_zeros() as usize;
                        (near1.to_array()[lane] < near0.to_array()[lane]) != FAR_FIRST
                    } else {
                        false
                    } as usize;
                    let (ms, nears) = ([m0, m1], [near0, near1]);
                    let other = 1 - first;
                    // A full stack drops the far subtree: unreachable within the depth
                    // bound the build guarantees.
                    let _ = stack.try_push((n.child[other], ms[other], nears[other]));
                    cur = n.child[first];
                    mask = ms[first];
                    continue;
                } else if m0 != 0 {
                    cur = n.child[0];
                    mask = m0;
                    continue;
                } else if m1 != 0 {
                    cur = n.child[1];
                    mask = m1;
                    continue;
                }
            }
            // Pop the next subtree that some ray may still find something nearer (or
            // tied) in.
            loop {
                let Some((node, m, near)) = stack.pop() else {
                    return;
                };
                let m = m & within8(near, limits);
                if m != 0 {
                    cur = node;
                    mask = m;
                    break;
                }
            }
        }
    }

    /// The first primitive met whose box the ray enters within `(t_min, t_max)` and
    /// for which `leaf(prim)` is true, if any (the first in the traversal's order, which
    /// is not the nearest); stops there.
    ///
    /// The wide tree is traversed, a node's eight boxes tested in single precision
    /// ([`WideTest`], the ray in every lane), where there is one (see `WIDE_FROM`), the
    /// ray's numbers fit that test and (on x86-64) the processor has AVX2; otherwise
    /// the binary tree in double precision. Neither misses a box the ray enters, so the
    /// answer is the same.
    // The primitive is returned, not written by `leaf` into a variable of the
    // caller's: such a variable would live in memory across the call into the
    // traversal compiled for AVX2, on every call, those that never take it too.
    #[inline]
    pub fn any<F: FnMut(u32) -> bool>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        leaf: F,
    ) -> Option<u32> {
        self.any_by_leaf(ray, t_min, t_max, first_blocker(leaf))
    }

    /// [`Bvh::any`] with the ray's numbers for the tree made by the caller,
    /// `made()`: nothing here enters code compiled for AVX2 by a call of its own, for
    /// a caller compiled for it that makes several rays' numbers at once
    /// ([`World::occluded_each`](super::world::World::occluded_each)).
    #[inline(always)]
    pub(crate) fn any_prepared<W: WideTest, F: FnMut(u32) -> bool>(
        &self,
        made: impl FnOnce() -> TreeRay<W>,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        leaf: F,
    ) -> Option<u32> {
        let mut leaf = first_blocker(leaf);
        match made() {
            TreeRay::Wide(lanes) if !self.wide.is_empty() => {
                self.any_wide(&lanes, t_min, t_max, &mut leaf)
            }
            TreeRay::Exact(slab, enters) => enters
                .then(|| self.any_exact_inside(&slab, t_min, t_max, leaf))
                .flatten(),
            _ => self.any_exact(&SlabRay::new(ray.origin, ray.dir), t_min, t_max, leaf),
        }
    }

    /// Whether the tree has a wide form ([`Bvh::any_prepared`] takes lanes for it).
    #[inline(always)]
    pub(crate) fn is_wide(&self) -> bool {
        !self.wide.is_empty()
    }

    /// Which of `rays` (prepared as `slabs`) enter the tree's box within
    /// `[t_min, t_max[k]]`, as a bit set: the binary tree's first test of each, made in
    /// lanes `n` ([`SlabRays8::enter8`]); none for an empty tree.
    #[inline(always)]
    pub(crate) fn enters8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: &Rays8,
        slabs: &SlabRays8,
        t_min: f64,
        t_max: &[f64; 8],
    ) -> u32 {
        self.nodes.first().map_or(0, |root| {
            slabs.enter8(n, rays, (root.min, root.max), t_min, t_max)
        })
    }

    /// [`Bvh::any`], a leaf at a time: the first of `leaf(prims)` over the leaves entered
    /// that is `Some` (what the caller makes of a leaf that blocks the ray).
    #[inline]
    pub fn any_by_leaf<T, F: FnMut(&[u32]) -> Option<T>>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        mut leaf: F,
    ) -> Option<T> {
        // On x86-64, the wide tree is traversed where the processor has AVX2 (a node's
        // eight boxes in one pass), the binary tree on the few without: each caller
        // inlines two copies of the traversal and its leaves' tests, not three.
        if !self.wide.is_empty() {
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = Avx2::detect() {
                // Always inlined into `run`'s function, so that the traversal (its
                // leaves' tests too) and the ray's lanes are compiled for AVX2; `None`
                // where the ray's numbers do not fit them.
                let wide = avx2.run(
                    #[inline(always)]
                    || {
                        let lanes = avx2.wide_ray(ray)?;
                        Some(self.any_wide(&lanes, t_min, t_max, &mut leaf))
                    },
                );
                if let Some(found) = wide {
                    return found;
                }
            }
            #[cfg(not(target_arch = "x86_64"))]
            if let Some(lanes) = SlabRay4::splat(ray) {
                return self.any_wide(&lanes, t_min, t_max, &mut leaf);
            }
        }
        self.any_exact(&SlabRay::new(ray.origin, ray.dir), t_min, t_max, leaf)
    }

    /// [`Bvh::any`] through the wide tree (which exists only for a tree of
    /// [`WIDE_FROM`] inner nodes or more, so never for an empty one), a node's boxes
    /// tested by `ray`'s [`WideTest`].
    #[inline(always)]
    fn any_wide<R: WideTest, T, F: FnMut(&[u32]) -> Option<T>>(
        &self,
        ray: &R,
        t_min: f64,
        t_max: f64,
        mut leaf: F,
    ) -> Option<T> {
        // Rounded to the nearest `f32`, as a packet's limits are (`lanes`). No test of
        // the whole tree's box first: the wide root is an inner node, its boxes lie
        // inside it (each rounded outward alike) and take one pass, as the root's box
        // alone does, so a ray that misses it is turned away at the same cost, and one
        // that enters (every shadow ray starting inside the tree's box) saves a pass.
        let (t_min, t_max) = (t_min as f32, t_max as f32);
        // The children entered but not yet visited, a node at a time: the node and
        // the bit set of them. A path has no more wide nodes than binary ones, so the
        // binary tree's bound holds (a child at a time, the stack took seven times as
        // much room, and every caller's frame a page more, probed on each call).
        let mut stack: ArrayVec<(u32, u32), STACK_SIZE> = ArrayVec::new();
        let mut cur = self.wide_root;
        loop {
            if cur & LEAF != 0 {
                if let found @ Some(_) = self.leaf_any(cur, &mut leaf) {
                    return found;
                }
            } else {
                let n = &self.wide[cur as usize];
                let entered = ray.enter_wide(&n.planes, t_min, t_max) & n.used;
                // The next node chosen by branches, not computed from the mask: the
                // processor then goes on to it while the box test is still in flight,
                // where an index computed from the mask made every node wait for the
                // last one's test.
                let first = match entered {
                    0 => None,
                    1 => Some(0),
                    2 => Some(1),
                    4 => Some(2),
                    8 => Some(3),
                    16 => Some(4),
                    32 => Some(5),
                    64 => Some(6),
                    128 => Some(7),
                    _ => {
                        let _ = stack.try_push((cur, entered & (entered - 1)));
                        Some(entered.trailing_zeros() as usize)
                    }
                };
                if let Some(c) = first {
                    cur = n.child[c];
                    continue;
                }
            }
            let (node, rest) = stack.last_mut()?;
            let c = rest.trailing_zeros() as usize;
            *rest &= *rest - 1;
            cur = self.wide[*node as usize].child[c];
            if *rest == 0 {
                stack.pop();
            }
        }
    }

    /// `leaf` of the primitives of leaf `reference`.
    #[inline(always)]
    fn leaf_any<T, F: FnMut(&[u32]) -> Option<T>>(
        &self,
        reference: u32,
        leaf: &mut F,
    ) -> Option<T> {
        let (start, count) = self.leaves[(reference & !LEAF) as usize];
        leaf(&self.order[start as usize..(start + count) as usize])
    }

    /// [`Bvh::any`] through the binary tree, its boxes tested in double precision.
    #[inline(always)]
    fn any_exact<T, F: FnMut(&[u32]) -> Option<T>>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        t_max: f64,
        leaf: F,
    ) -> Option<T> {
        let root = self.nodes.first()?;
        ray.enter(root.min, root.max, t_min, t_max)?;
        self.any_exact_inside(ray, t_min, t_max, leaf)
    }

    /// [`Bvh::any_exact`] of a ray known to enter the tree's box (of a tree with
    /// nodes).
    #[inline(always)]
    fn any_exact_inside<T, F: FnMut(&[u32]) -> Option<T>>(
        &self,
        ray: &SlabRay,
        t_min: f64,
        t_max: f64,
        mut leaf: F,
    ) -> Option<T> {
        let mut stack: ArrayVec<u32, STACK_SIZE> = ArrayVec::new();
        let mut cur = self.root;
        loop {
            if cur & LEAF != 0 {
                if let found @ Some(_) = self.leaf_any(cur, &mut leaf) {
                    return found;
                }
            } else {
                let n = &self.inner[cur as usize];
                let (h0, h1) = ray.enter2(&n.min, &n.max, t_min, t_max);
                let (h0, h1) = (h0.is_some(), h1.is_some());
                if h0 || h1 {
                    if h0 && h1 {
                        let _ = stack.try_push(n.child[1]);
                    }
                    cur = if h0 { n.child[0] } else { n.child[1] };
                    continue;
                }
            }
            match stack.pop() {
                Some(c) => cur = c,
                None => return None,
            }
        }
    }

    /// Primitives whose box the ray enters within `(t_min, t_max)`, in leaf order: the
    /// candidates a ray is tested against (for explaining a pixel).
    ///
    /// The boxes are tested in double precision, as built.
    pub fn candidates(&self, ray: &SlabRay, t_min: f64, t_max: f64) -> Vec<u32> {
        let mut out = Vec::new();
        self.any_exact(ray, t_min, t_max, |prims| {
            out.extend_from_slice(prims);
            None::<()>
        });
        out
    }
}

/// A leaf's test for [`Bvh::any`] from a primitive's, `leaf(prim)`: the first of the
/// leaf's primitives for which it is true.
// A loop, not `Iterator::find`: that was left a call, and the leaf function with it.
#[allow(clippy::manual_find)]
#[inline(always)]
fn first_blocker<F: FnMut(u32) -> bool>(mut leaf: F) -> impl FnMut(&[u32]) -> Option<u32> {
    #[inline(always)]
    move |prims| {
        for &p in prims {
            if leaf(p) {
                return Some(p);
            }
        }
        None
    }
}

/// A ray's numbers for the tree's test, made by a caller that makes several rays'
/// at once, for [`Bvh::any_prepared`].
pub(crate) enum TreeRay<W> {
    /// Its lanes for the wide tree.
    Wide(W),
    /// Its numbers for the binary tree ([`SlabRays8::lane`]), and whether it enters
    /// the tree's box ([`Bvh::enters8`]).
    Exact(SlabRay, bool),
    /// None made (its numbers do not fit the wide tree's test): made by the tree.
    Unmade,
}

/// How a build splits: a group's `test_cost` and the primitives a group holds (see
/// [`Bvh::build_in_groups`]; one for [`Bvh::build`]), and the size of subtree from
/// which its halves are built in parallel.
#[derive(Debug, Clone, Copy, Default)]
struct Split {
    test_cost: f64,
    lanes: usize,
    parallel_from: usize,
}

impl Split {
    /// The groups `n` primitives take.
    fn groups(&self, n: usize) -> f64 {
        // The world's tree counts primitives one by one: no integer division (the SAH
        // asks this twice for every split it weighs).
        if self.lanes <= 1 {
            n as f64
        } else {
            n.div_ceil(self.lanes) as f64
        }
    }

    /// Partitions `prims` (of [`Side`] `side`) and returns the split index, with both
    /// sides where the SAH's bins give them; `None` for a leaf.
    fn choose_split(
        &self,
        prims: &mut [BuildPrim],
        side: &Side,
        depth: usize,
    ) -> Option<(usize, Option<[Side; 2]>)> {
        let (bounds, cb) = (&side.bounds, &side.centroids);
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
            return Some((median_split(prims, axis), None));
        }
        let bin_of = |c: f64| {
            (((c - cb.min[axis]) / extent[axis] * SAH_BINS as f64) as usize).min(SAH_BINS - 1)
        };
        let mut counts = [0usize; SAH_BINS];
        let mut bins = [Side::EMPTY; SAH_BINS];
        for p in prims.iter_mut() {
            let b = bin_of(p.centroid[axis]);
            p.bin = b as u32;
            counts[b] += 1;
            bins[b] = bins[b].with(p);
        }
        // The sweeps visit only the bins that hold primitives: a union with an empty bin
        // changes nothing, and a split between two filled bins is the same split
        // wherever between them it falls (of equally cheap splits the lowest is taken,
        // as a sweep over all twelve took it). Most nodes are small, with a few of the
        // twelve bins filled, and sweeping the empty ones was most of their cost.
        let filled: ArrayVec<usize, SAH_BINS> = (0..SAH_BINS).filter(|&i| counts[i] > 0).collect();
        // The union of `filled[j..]`, at `j`.
        let mut right_area = [0.0; SAH_BINS];
        let mut right_n = [0usize; SAH_BINS];
        let (mut acc, mut acc_n) = (Aabb::EMPTY, 0);
        for j in (1..filled.len()).rev() {
            acc = acc.union(&bins[filled[j]].bounds);
            acc_n += counts[filled[j]];
            right_area[j] = acc.half_area();
            right_n[j] = acc_n;
        }
        // `best`: how many filled bins lie below the cheapest split (0: no split).
        let (mut best_cost, mut best) = (f64::INFINITY, 0);
        let (mut left, mut left_n) = (Aabb::EMPTY, 0);
        for j in 1..filled.len() {
            let below = filled[j - 1];
            left = left.union(&bins[below].bounds);
            left_n += counts[below];
            let cost =
                left.half_area() * self.groups(left_n) + right_area[j] * self.groups(right_n[j]);
            if cost < best_cost {
                best_cost = cost;
                best = j;
            }
        }
        // In tests of a node's boxes, for a ray entering this node: a leaf tests all n;
        // a split tests the node's boxes, then the side it enters.
        let c = self.test_cost;
        let leaf_cost = c * bounds.half_area() * self.groups(n);
        let split_cost = bounds.half_area() + c * best_cost;
        if best == 0 || (n <= MAX_LEAF_PRIMS && leaf_cost <= split_cost) {
            if n <= MAX_LEAF_PRIMS {
                return None;
            }
            return Some((median_split(prims, axis), None));
        }
        let last_below = filled[best - 1];
        let mut mid = 0;
        for i in 0..n {
            if (prims[i].bin as usize) <= last_below {
                prims.swap(i, mid);
                mid += 1;
            }
        }
        // Each side's unions are those of its bins: min and max are exact, so they are
        // the unions over its primitives, whatever the order.
        let union = |f: &[usize]| f.iter().fold(Side::EMPTY, |s, &b| s.join(&bins[b]));
        let (below, above) = filled.split_at(best);
        Some((mid, Some([union(below), union(above)])))
    }
}

/// A subtree as the build leaves it: built on one thread, into vectors of its own, or a
/// node whose two halves were built in parallel. [`Part::lay_out`] copies each node
/// once into the tree's one vector; appending each half to its parent as soon as it was
/// built copied a node once for every parallel level above it, into fresh pages each
/// time.
enum Part {
    Built(Builder),
    Split(Node, Box<(Part, Part)>),
}

impl Part {
    /// The tree over `prims`, its root at `depth` (`side` is [`Side::of`] them), its
    /// halves built in parallel on the current rayon pool where it has at least
    /// `split.parallel_from` primitives.
    fn build(prims: &mut [BuildPrim], depth: usize, split: Split, side: Side) -> Part {
        let chosen = if prims.len() < split.parallel_from {
            None
        } else {
            split.choose_split(prims, &side, depth)
        };
        let Some((mid, sides)) = chosen else {
            return Part::Built(Builder::subtree(prims, depth, split, side));
        };
        let [(left, l), (right, r)] = cut(prims, mid, sides);
        let halves = rayon::join(
            || Part::build(left, depth + 1, split, l),
            || Part::build(right, depth + 1, split, r),
        );
        Part::Split(Node::over(&side), Box::new(halves))
    }

    /// Appends the subtree to `whole` in depth-first order, the layout building it in
    /// place on one thread gives.
    fn lay_out(self, whole: &mut Builder) {
        match self {
            Part::Built(b) => whole.append(b),
            Part::Split(node, halves) => {
                let me = whole.nodes.len();
                whole.nodes.push(node);
                let (left, right) = *halves;
                left.lay_out(whole);
                whole.nodes[me].offset = whole.nodes.len() as u32;
                right.lay_out(whole);
            }
        }
    }
}

/// The binary tree being built: nodes in depth-first order (a node, its first subtree,
/// its second), and the primitive indices in leaf order.
#[derive(Default)]
struct Builder {
    nodes: Vec<Node>,
    order: Vec<u32>,
    split: Split,
}

impl Builder {
    /// The tree over `prims`, its root at `depth`; `side` is [`Side::of`] them.
    fn subtree(prims: &mut [BuildPrim], depth: usize, split: Split, side: Side) -> Builder {
        let mut b = Builder::reserved(prims.len(), split);
        b.build_node(prims, depth, side);
        b
    }

    /// The tree over `prims` (at least one), the halves of its subtrees of
    /// `split.parallel_from` primitives or more built in parallel: the same tree.
    fn tree(prims: &mut [BuildPrim], split: Split) -> Builder {
        let side = Side::of(prims);
        match Part::build(prims, 0, split, side) {
            Part::Built(whole) => whole,
            halves => {
                let mut whole = Builder::reserved(prims.len(), split);
                halves.lay_out(&mut whole);
                whole
            }
        }
    }

    /// An empty tree with room for one over `n` primitives.
    fn reserved(n: usize, split: Split) -> Builder {
        Builder {
            // A binary tree of n leaves has 2n − 1 nodes, and a leaf holds at least one
            // primitive: reserved once, the vector is never copied to grow (reserved
            // pages that stay unused are never touched).
            nodes: Vec::with_capacity((2 * n).saturating_sub(1)),
            order: Vec::with_capacity(n),
            split,
        }
    }

    /// Appends a subtree built on its own, moving its references to where its nodes
    /// and primitives now stand: the layout is the one building it in place gives.
    fn append(&mut self, sub: Builder) {
        let (nodes, order) = (self.nodes.len() as u32, self.order.len() as u32);
        self.nodes.extend(sub.nodes.into_iter().map(|mut n| {
            n.offset += if n.count > 0 { order } else { nodes };
            n
        }));
        self.order.extend(sub.order);
    }

    /// The node over `prims` and its subtrees; `side` is [`Side::of`] them, known from
    /// the parent's binning where its split was the SAH's.
    fn build_node(&mut self, prims: &mut [BuildPrim], depth: usize, side: Side) {
        let me = self.nodes.len();
        self.nodes.push(Node::over(&side));
        let split = if prims.len() <= 1 {
            None
        } else {
            self.split.choose_split(prims, &side, depth)
        };
        match split {
            None => {
                self.nodes[me].offset = self.order.len() as u32;
                self.nodes[me].count = prims.len() as u16;
                self.order.extend(prims.iter().map(|p| p.index));
            }
            Some((mid, sides)) => {
                let [(left, l), (right, r)] = cut(prims, mid, sides);
                self.build_node(left, depth + 1, l);
                self.nodes[me].offset = self.nodes.len() as u32;
                self.build_node(right, depth + 1, r);
            }
        }
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
        let bvh = Bvh::build(&boxes, 1.0);
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
    fn node_boxes_hold_their_primitives_and_halves_built_in_parallel_give_one_tree() {
        // Clustered boxes of many sizes, so that the SAH, the median splits and
        // leaves of every size all occur.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let boxes: Vec<Aabb> = (0..30_000)
            .map(|i| {
                let c = DVec3::new(next(), next(), next()) * if i % 3 == 0 { 100.0 } else { 5.0 };
                Aabb {
                    min: c,
                    max: c + DVec3::new(next(), next(), next()) * 0.3,
                }
            })
            .collect();
        let prims = || -> Vec<BuildPrim> {
            boxes
                .iter()
                .enumerate()
                .map(|(i, b)| BuildPrim {
                    bounds: b.padded(),
                    centroid: b.padded().centroid(),
                    index: i as u32,
                    bin: 0,
                })
                .collect()
        };
        let at = |parallel_from| Split {
            test_cost: 2.0,
            lanes: 1,
            parallel_from,
        };
        let build = |parallel_from| Builder::tree(&mut prims(), at(parallel_from));
        let whole = build(usize::MAX);
        // Each node's box, carried down from its parent's bins, is the union of its
        // primitives' boxes.
        fn union_below(b: &Builder, node: usize, boxes: &[Aabb]) -> (Aabb, usize) {
            let n = &b.nodes[node];
            if n.count > 0 {
                let leaf = &b.order[n.offset as usize..(n.offset + u32::from(n.count)) as usize];
                let u = leaf
                    .iter()
                    .fold(Aabb::EMPTY, |u, &i| u.union(&boxes[i as usize].padded()));
                return (u, node + 1);
            }
            let (first, end) = union_below(b, node + 1, boxes);
            assert_eq!(end, n.offset as usize, "the second child follows the first");
            let (second, end) = union_below(b, end, boxes);
            (first.union(&second), end)
        }
        let mut checked = 0;
        for node in 0..whole.nodes.len() {
            let (u, _) = union_below(&whole, node, &boxes);
            let n = &whole.nodes[node];
            assert_eq!((n.min, n.max), (u.min, u.max), "node {node}");
            checked += 1;
        }
        assert!(checked > 1000);
        for parallel_from in [2, 1000, PARALLEL_PRIMS] {
            let split = build(parallel_from);
            assert_eq!(split.order, whole.order, "from {parallel_from}");
            assert_eq!(split.nodes.len(), whole.nodes.len());
            for (a, b) in split.nodes.iter().zip(&whole.nodes) {
                assert_eq!(
                    (a.min, a.max, a.offset, a.count),
                    (b.min, b.max, b.offset, b.count),
                    "from {parallel_from}"
                );
            }
        }
    }

    /// The traversal layout numbers inner nodes and leaves in the order a depth-first
    /// walk from the root meets them, each child's boxes are its subtree's, and the
    /// layout flattened on every worker is the one flattened on one thread (a tree for
    /// groups too).
    #[test]
    fn the_layout_is_numbered_depth_first_on_one_thread_or_many() {
        let boxes: Vec<Aabb> = (0..20_000)
            .map(|i| {
                let k = i as f64;
                let c = DVec3::new((k * 0.37).sin(), (k * 0.61).cos(), (k * 0.13).sin()) * 40.0;
                Aabb {
                    min: c,
                    max: c + DVec3::splat(0.1 + (i % 7) as f64 * 0.3),
                }
            })
            .collect();
        let one = Bvh::build(&boxes, 1.0);
        let many = Bvh::build_in_parallel(&boxes, 1.0);
        let same = |one: &Bvh, many: &Bvh| {
            assert_eq!(one.root, many.root);
            assert_eq!(one.leaves, many.leaves);
            assert_eq!(one.order, many.order);
            assert_eq!(one.packet, many.packet);
            assert_eq!(one.inner.len(), many.inner.len());
            for (a, b) in one.inner.iter().zip(&many.inner) {
                assert_eq!((a.min, a.max, a.child), (b.min, b.max, b.child));
            }
        };
        same(&one, &many);
        // A tree for groups of four (a mesh's) likewise.
        same(
            &Bvh::build_in_groups(&boxes, 2.0, 4, false),
            &Bvh::build_in_groups(&boxes, 2.0, 4, true),
        );
        // Walking depth first from the root meets inner node 0, 1, 2, … and leaf 0,
        // 1, 2, …; each child holds its subtree's boxes and leaves.
        let (mut next_inner, mut next_leaf) = (0, 0);
        let mut stack = vec![(one.root, one.bounds())];
        let mut under = Vec::new();
        while let Some((r, bounds)) = stack.pop() {
            if r & LEAF != 0 {
                assert_eq!(r & !LEAF, next_leaf);
                next_leaf += 1;
                let (start, count) = one.leaves[(r & !LEAF) as usize];
                for &p in &one.order[start as usize..(start + count) as usize] {
                    let b = boxes[p as usize].padded();
                    assert!(
                        bounds.union(&b) == bounds,
                        "a leaf's box holds its primitives"
                    );
                    under.push(p);
                }
            } else {
                assert_eq!(r, next_inner);
                next_inner += 1;
                let n = &one.inner[r as usize];
                for k in [1, 0] {
                    let child = Aabb {
                        min: DVec3::new(n.min[0][k], n.min[1][k], n.min[2][k]),
                        max: DVec3::new(n.max[0][k], n.max[1][k], n.max[2][k]),
                    };
                    let p = &one.packet[r as usize];
                    assert_eq!(p.child[k], n.child[k]);
                    let b32 = p.boxes.child(k);
                    for a in 0..3 {
                        assert!(
                            f64::from(b32[a]) <= child.min[a]
                                && child.max[a] <= f64::from(b32[a + 3])
                        );
                    }
                    stack.push((n.child[k], child));
                }
            }
        }
        assert_eq!(next_inner as usize, one.inner.len());
        assert_eq!(next_leaf as usize, one.leaves.len());
        assert_eq!(
            under, one.order,
            "the leaves hold the primitives in leaf order"
        );
    }

    #[test]
    fn a_costlier_primitive_is_split_into_smaller_leaves() {
        // A jittered grid of overlapping boxes, which the SAH would rather leave
        // together than split.
        let boxes: Vec<Aabb> = (0..4096)
            .map(|i| {
                let k = i as f64;
                let c = DVec3::new((i % 16) as f64, ((i / 16) % 16) as f64, (i / 256) as f64);
                let jitter = DVec3::new((k * 0.37).sin(), (k * 0.61).cos(), (k * 0.13).sin());
                Aabb {
                    min: c + jitter * 0.3,
                    max: c + jitter * 0.3 + DVec3::splat(1.0 + (i % 5) as f64 * 0.5),
                }
            })
            .collect();
        let leaves = |test_cost| {
            let bvh = Bvh::build(&boxes, test_cost);
            assert_eq!(bvh.len(), boxes.len());
            bvh.leaves.len()
        };
        let (one, two, four) = (leaves(1.0), leaves(2.0), leaves(4.0));
        assert!(one < two && two < four, "{one} {two} {four} leaves");
    }

    #[test]
    fn leaves_counted_in_groups_are_fuller_and_start_a_group_each() {
        // A grid of small boxes, the kind of scatter a mesh's triangles make.
        let boxes: Vec<Aabb> = (0..2000)
            .map(|i| {
                let c = DVec3::new((i % 40) as f64, (i / 40) as f64 * 0.7, (i % 7) as f64 * 0.1);
                Aabb {
                    min: c,
                    max: c + DVec3::splat(0.6),
                }
            })
            .collect();
        let alone = Bvh::build(&boxes, 1.0);
        let grouped = Bvh::build_in_groups(&boxes, 2.0, 4, false);
        assert!(
            grouped.leaves.len() * 3 < alone.leaves.len() * 2,
            "{} leaves in groups, {} alone",
            grouped.leaves.len(),
            alone.leaves.len()
        );
        for (tree, most) in [(grouped, 1.25), (alone, 1.75)] {
            let prims = tree.order.clone();
            let (bvh, held) = tree.into_slots(4);
            // Every primitive in exactly one slot; each leaf's slots consecutive, in one
            // group, holding its own primitives.
            let mut seen = vec![0; boxes.len()];
            for &p in held.iter().flatten() {
                seen[p as usize] += 1;
            }
            assert!(seen.iter().all(|&n| n == 1));
            assert!(
                held.len() as f64 <= boxes.len() as f64 * most,
                "{} slots",
                held.len()
            );
            for &(first, count) in &bvh.leaves {
                let slots = &bvh.order[first as usize..(first + count) as usize];
                assert_eq!(slots[0] / 4, slots[slots.len() - 1] / 4, "{slots:?}");
                for (k, &slot) in slots.iter().enumerate() {
                    assert_eq!(slot, slots[0] + k as u32);
                    assert_eq!(held[slot as usize], Some(prims[first as usize + k]));
                }
            }
        }
        // One lane a group: slots are the leaf order itself.
        let (flat, held) = Bvh::build(&boxes, 1.0).into_slots(1);
        assert_eq!(held.len(), boxes.len());
        assert!(flat.order.iter().enumerate().all(|(k, &s)| s == k as u32));
    }

    #[test]
    fn identical_boxes_do_not_recurse_forever() {
        let boxes = vec![unit_box(DVec3::ZERO); 1000];
        let bvh = Bvh::build(&boxes, 1.0);
        let ray = SlabRay::new(DVec3::new(0.0, 0.0, -10.0), DVec3::Z);
        assert_eq!(bvh.candidates(&ray, 0.0, f64::INFINITY).len(), 1000);
    }

    #[test]
    fn any_stops_early_and_misses() {
        let boxes: Vec<Aabb> = (0..10)
            .map(|i| unit_box(DVec3::new(i as f64 * 3.0, 0.0, 0.0)))
            .collect();
        let bvh = Bvh::build(&boxes, 1.0);
        let up = Ray::new(DVec3::new(9.0, -5.0, 0.0), DVec3::Y);
        assert!(bvh.any(&up, 0.0, f64::INFINITY, |p| p == 3).is_some());
        assert!(bvh.any(&up, 0.0, 1.0, |_| true).is_none());
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

    /// Directions with no zero component (a packet's rays have none): the grid's
    /// diagonals, which run along box edges from grid points, and arbitrary ones.
    fn packet_dir() -> impl Strategy<Value = DVec3> + Clone {
        let diagonal = prop::array::uniform3(prop_oneof![Just(-1.0), Just(1.0), Just(0.5)])
            .prop_map(DVec3::from);
        let any =
            prop::array::uniform3(prop_oneof![-1.0f64..-1e-3, 1e-3f64..1.0]).prop_map(DVec3::from);
        prop_oneof![2 => diagonal, 1 => any]
    }

    /// [`Bvh::closest8`] in two passes of eight lanes where the processor has AVX2 (the
    /// portable four lanes elsewhere).
    fn in_eight_lanes(
        bvh: &Bvh,
        slab: &[SlabRay4; 2],
        limits: &mut [f64; 8],
        active: u32,
        leaf: impl FnMut(&[u32], u32, &mut [f64; 8]),
    ) {
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect() {
            return avx2.run(|| {
                let eight = slab.map(|s| avx2.widen(&s));
                bvh.traverse8::<false, _, _>(slab, &eight, 1e-9, limits, active, leaf)
            });
        }
        bvh.traverse8::<false, _, _>(slab, slab, 1e-9, limits, active, leaf)
    }

    /// Eight rays: from one grid point (as primary rays share the camera) or from
    /// eight.
    fn packet() -> impl Strategy<Value = [(DVec3, DVec3); 8]> {
        let point = prop::array::uniform3(-12i32..12)
            .prop_map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * 0.5);
        let dirs = || prop::array::uniform8(packet_dir());
        prop_oneof![
            (point.clone(), dirs()).prop_map(|(o, d)| d.map(|d| (o, d))),
            (prop::array::uniform8(point), dirs())
                .prop_map(|(o, d)| std::array::from_fn(|k| (o[k], d[k]))),
        ]
    }

    use crate::geometry::bounds::lanes_where;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// A split the SAH chooses is the first of the cheapest bin boundaries, each
        /// weighed from its two sides' primitives themselves (grid boxes, so that
        /// boundaries often cost the same), and its sides' unions are theirs.
        #[test]
        fn the_sah_takes_the_first_cheapest_bin_boundary(
            boxes in prop::collection::vec(grid_box(), 2..40),
            test_cost in prop_oneof![Just(0.5), Just(1.0), Just(4.0)],
            lanes in prop_oneof![Just(1usize), Just(4)],
        ) {
            let mut prims: Vec<BuildPrim> = boxes
                .iter()
                .enumerate()
                .map(|(i, &bounds)| BuildPrim {
                    bounds,
                    centroid: bounds.centroid(),
                    index: i as u32,
                    bin: 0,
                })
                .collect();
            let side = Side::of(&prims);
            let split = Split { test_cost, lanes, parallel_from: usize::MAX };
            let Some((mid, Some([below, above]))) = split.choose_split(&mut prims, &side, 0)
            else {
                return Ok(());
            };
            let groups = |n: usize| n.div_ceil(lanes) as f64;
            let mut cheapest = None;
            for boundary in 1..SAH_BINS as u32 {
                let (l, r): (Vec<&BuildPrim>, Vec<&BuildPrim>) =
                    prims.iter().partition(|p| p.bin < boundary);
                if l.is_empty() || r.is_empty() {
                    continue;
                }
                let area = |s: &[&BuildPrim]| {
                    s.iter().fold(Aabb::EMPTY, |b, p| b.union(&p.bounds)).half_area()
                };
                let cost = area(&l) * groups(l.len()) + area(&r) * groups(r.len());
                if cheapest.is_none_or(|(c, _)| cost < c) {
                    cheapest = Some((cost, boundary));
                }
            }
            let (_, boundary) = cheapest.expect("a split has two filled sides");
            prop_assert!(prims[..mid].iter().all(|p| p.bin < boundary));
            prop_assert!(prims[mid..].iter().all(|p| p.bin >= boundary));
            for (half, got) in [(&prims[..mid], below), (&prims[mid..], above)] {
                let want = Side::of(half);
                prop_assert_eq!(got.bounds, want.bounds);
                prop_assert_eq!(got.centroids, want.centroids);
            }
        }

        #[test]
        fn tree_finds_what_every_box_finds(
            boxes in prop::collection::vec(grid_box(), 1..80),
            rays in prop::collection::vec(grazing_ray(), 1..40),
            test_cost in prop_oneof![Just(1.0), Just(2.0), Just(4.0)],
        ) {
            let bvh = Bvh::build(&boxes, test_cost);
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
                    bvh.any(&Ray::new(o, d), 1e-9, t_max, blocked).is_some(),
                    (0..boxes.len() as u32).any(blocked)
                );
            }
        }

        #[test]
        fn the_wide_tree_finds_what_every_box_finds(
            boxes in prop::collection::vec(grid_box(), 40..160),
            rays in prop::collection::vec(
                (prop::array::uniform3(-12i32..12), packet_dir(), 0.0f64..1.5), 1..40),
            test_cost in prop_oneof![Just(1.0), Just(2.0), Just(4.0)],
        ) {
            let bvh = Bvh::build(&boxes, test_cost);
            prop_assert_eq!(!bvh.wide.is_empty(), bvh.inner.len() >= WIDE_FROM);
            // A wide node is full, or holds nothing left to open: only leaves.
            for n in &bvh.wide {
                let children = n.used.count_ones() as usize;
                let leaves = n.child[..children].iter().filter(|&&c| c & LEAF != 0).count();
                prop_assert!(
                    children == WIDE || leaves == children,
                    "{} children, {} of them leaves", children, leaves
                );
            }
            for (c, d, reach) in rays {
                // From grid points (on faces, edges and corners) along the grid's
                // diagonals or anywhere, as far as some box or as far as a box's face.
                let o = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * 0.5;
                let ray = Ray::new(o, d);
                prop_assert!(SlabRay4::splat(&ray).is_some());
                let nearest = (0..boxes.len())
                    .filter_map(|i| box_surface(&boxes[i], o, d, 1e-9, f64::INFINITY))
                    .min_by(f64::total_cmp);
                for t_max in [f64::INFINITY, reach, nearest.unwrap_or(reach)] {
                    let blocked =
                        |i: u32| box_surface(&boxes[i as usize], o, d, 1e-9, t_max).is_some();
                    let every = (0..boxes.len() as u32).any(blocked);
                    prop_assert_eq!(
                        bvh.any(&ray, 1e-9, t_max, blocked).is_some(), every,
                        "ray {:?} + λ {:?} to {}", o, d, t_max
                    );
                    let exact = SlabRay::new(o, d);
                    let blocked_in = |prims: &[u32]| prims.iter().copied().find(|&i| blocked(i));
                    prop_assert_eq!(bvh.any_exact(&exact, 1e-9, t_max, blocked_in).is_some(), every);
                    // The wide tree in two passes of four lanes a node, as traversed
                    // where the processor has no AVX2 (the dispatched `any` above
                    // takes one pass of eight where it has).
                    if let Some(lanes) = SlabRay4::splat(&ray).filter(|_| !bvh.wide.is_empty()) {
                        prop_assert_eq!(bvh.any_wide(&lanes, 1e-9, t_max, blocked_in).is_some(), every);
                    }
                    // Every box entered is seen, not only the first that blocks.
                    let mut seen = Vec::new();
                    bvh.any(&ray, 1e-9, t_max, |i| {
                        seen.push(i);
                        false
                    });
                    for i in 0..boxes.len() as u32 {
                        prop_assert!(!blocked(i) || seen.contains(&i), "box {} missed", i);
                    }
                }
            }
        }

        #[test]
        fn packets_find_what_every_box_finds(
            boxes in prop::collection::vec(grid_box(), 1..80),
            packets in prop::collection::vec(packet(), 1..12),
            active in 1u32..256,
            test_cost in prop_oneof![Just(1.0), Just(2.0), Just(4.0)],
        ) {
            let bvh = Bvh::build(&boxes, test_cost);
            for rays in packets {
                let slab = SlabRay4::pair(&rays.map(|(o, d)| Ray::new(o, d)))
                    .expect("no zero direction component");
                // The traversal as dispatched (sixteen lanes where the processor has
                // AVX-512, else eight where it has AVX2), the one of eight lanes, and
                // the portable one of four.
                let mut found = [[None; 8]; 3];
                for (path, best) in found.iter_mut().enumerate() {
                    let mut limits = [f64::INFINITY; 8];
                    let leaf = |prims: &[u32], lanes: u32, limits: &mut [f64; 8]| {
                        for (&i, lane) in prims.iter().flat_map(|i| lanes_of(lanes).map(move |l| (i, l))) {
                            let (o, d) = rays[lane];
                            // The rule of `closest_of`, ray by ray.
                            if let Some(t) =
                                box_surface(&boxes[i as usize], o, d, 1e-9, limits[lane])
                                && (t < limits[lane]
                                    || best[lane]
                                        .is_some_and(|(bt, bi): (f64, u32)| t == bt && i < bi))
                            {
                                best[lane] = Some((t, i));
                                limits[lane] = t;
                            }
                        }
                    };
                    match path {
                        0 => bvh.closest8::<false, _>(&slab, 1e-9, &mut limits, active, leaf),
                        1 => in_eight_lanes(&bvh, &slab, &mut limits, active, leaf),
                        _ => bvh.traverse8::<false, _, _>(&slab, &slab, 1e-9, &mut limits, active, leaf),
                    }
                }
                for (lane, &(o, d)) in rays.iter().enumerate() {
                    let slow = closest_of(&boxes, o, d, |leaf| {
                        let mut limit = f64::INFINITY;
                        for i in 0..boxes.len() as u32 {
                            limit = leaf(i, limit);
                        }
                    });
                    let expected = if active >> lane & 1 == 1 { slow } else { None };
                    for (path, best) in found.iter().enumerate() {
                        prop_assert_eq!(
                            best[lane], expected,
                            "path {} lane {} ray {:?} + λ {:?}", path, lane, o, d
                        );
                    }
                }
            }
        }

        #[test]
        fn packets_of_shadow_rays_find_what_every_box_finds(
            boxes in prop::collection::vec(grid_box(), 1..80),
            packets in prop::collection::vec(packet(), 1..12),
            active in 1u32..256,
            reach in prop::array::uniform8(prop_oneof![Just(f64::INFINITY), 0.5f64..30.0]),
        ) {
            let bvh = Bvh::build(&boxes, 1.0);
            for rays in packets {
                let slab = SlabRay4::pair(&rays.map(|(o, d)| Ray::new(o, d)))
                    .expect("no zero direction component");
                let blocks = |i: u32, lane: usize| {
                    let (o, d) = rays[lane];
                    box_surface(&boxes[i as usize], o, d, 1e-9, reach[lane]).is_some()
                };
                // Lanes shown a box: only active ones, and none once a box blocked it.
                let (mut shown, mut blocked, mut shown_after) = (0u32, 0u32, 0u32);
                let occluded = bvh.any8(&slab, 1e-9, reach, active, |prims, lanes| {
                    shown |= lanes;
                    shown_after |= lanes & blocked;
                    let found = lanes_where(lanes, |lane| prims.iter().any(|&i| blocks(i, lane)));
                    blocked |= found;
                    found
                });
                prop_assert_eq!(shown & !active, 0);
                prop_assert_eq!(shown_after, 0);
                for (lane, &(o, d)) in rays.iter().enumerate() {
                    let every = (0..boxes.len() as u32).any(|i| blocks(i, lane));
                    prop_assert_eq!(
                        occluded >> lane & 1 == 1, every && active >> lane & 1 == 1,
                        "lane {} ray {:?} + λ {:?} to {}", lane, o, d, reach[lane]
                    );
                }
            }
        }
    }
}
