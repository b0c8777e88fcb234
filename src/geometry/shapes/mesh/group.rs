//! A mesh's triangles stored four to a group, coordinate by coordinate, so that a ray
//! is tested against a BVH leaf's triangles at once, one triangle a lane: the
//! Möller–Trumbore numbers of each lane are those of
//! [`moller_trumbore`](super::moller_trumbore), operation for operation (the same
//! products, sums and one division, no fused steps), so the same bits.

use glam::DVec3;

use super::Tri;
#[cfg(test)]
use super::moller_trumbore;
use crate::geometry::arith::{Lanes4, Portable};
#[cfg(target_arch = "x86_64")]
use crate::geometry::bounds::x86::Avx2;
use crate::geometry::ray::Ray;

/// Triangles a group holds: the lanes of one pass.
pub(super) const LANES: usize = 4;

/// Four triangles prepared for Möller–Trumbore, `[coordinate][lane]`. A lane that holds
/// no triangle has zero edges: its determinant is zero, so it is never hit.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
pub(super) struct Group {
    v0: [[f64; LANES]; 3],
    e1: [[f64; LANES]; 3],
    e2: [[f64; LANES]; 3],
}

impl Group {
    /// The group of `tris`, lane by lane (`None`: an empty lane).
    pub(super) fn new(tris: [Option<Tri>; LANES]) -> Group {
        let mut g = Group {
            v0: [[0.0; LANES]; 3],
            e1: [[0.0; LANES]; 3],
            e2: [[0.0; LANES]; 3],
        };
        for (lane, tri) in tris.iter().enumerate() {
            if let Some(t) = tri {
                for a in 0..3 {
                    g.v0[a][lane] = t.v0[a];
                    g.e1[a][lane] = t.e1[a];
                    g.e2[a][lane] = t.e2[a];
                }
            }
        }
        g
    }

    /// The triangle of `lane`.
    #[inline(always)]
    pub(super) fn tri(&self, lane: usize) -> Tri {
        let at = |c: &[[f64; LANES]; 3]| DVec3::new(c[0][lane], c[1][lane], c[2][lane]);
        Tri {
            v0: at(&self.v0),
            e1: at(&self.e1),
            e2: at(&self.e2),
        }
    }

    /// Möller–Trumbore for `ray` and the four triangles: the bit set of the lanes whose
    /// triangle [`moller_trumbore`](super::moller_trumbore) would say is hit within
    /// `(t_min, ∞)`, and each lane's `λ`. A lane's hit within `(t_min, t_max)` is one of
    /// these whose `λ` is at most `t_max`. In one AVX register a number where the
    /// processor has AVX2, else in two SSE2 registers: the same bits either way.
    #[inline(always)]
    pub(super) fn hits(&self, ray: &Ray, t_min: f64) -> (u32, [f64; LANES]) {
        // Chosen here, for each leaf, not once a traversal: inside a packet's traversal
        // (compiled for AVX2 or wider) `run` inlines into it, and a lone ray's
        // traversal, compiled for the release's lanes, must not do its lane arithmetic
        // through calls (hoisted, renders took 2.3–2.8 times as long). So every caller
        // that loops over a leaf's groups does so in a plain loop the compiler inlines.
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect() {
            return avx2.run(|| self.hits_in(avx2, ray, t_min));
        }
        self.hits_in(Portable, ray, t_min)
    }

    /// [`Group::hits`] in the lanes of `l`.
    #[inline(always)]
    fn hits_in<L: Lanes4>(&self, l: L, ray: &Ray, t_min: f64) -> (u32, [f64; LANES]) {
        let s = |x: f64| l.splat(x);
        let [v0x, v0y, v0z] = self.v0.each_ref().map(|c| l.load(c));
        let [e1x, e1y, e1z] = self.e1.each_ref().map(|c| l.load(c));
        let [e2x, e2y, e2z] = self.e2.each_ref().map(|c| l.load(c));
        let (dx, dy, dz) = (s(ray.dir.x), s(ray.dir.y), s(ray.dir.z));
        // `p = d × e₂`, `det = e₁ · p`, as glam's `cross` and `dot` order them.
        let px = dy * e2z - e2y * dz;
        let py = dz * e2x - e2z * dx;
        let pz = dx * e2y - e2x * dy;
        let det = e1x * px + e1y * py + e1z * pz;
        let inv = s(1.0) / det;
        // `s = o − v₀`, `u = (s · p)·inv`, `q = s × e₁`, `v = (d · q)·inv`, `t = (e₂ · q)·inv`.
        let (sx, sy, sz) = (
            s(ray.origin.x) - v0x,
            s(ray.origin.y) - v0y,
            s(ray.origin.z) - v0z,
        );
        let u = (sx * px + sy * py + sz * pz) * inv;
        let qx = sy * e1z - e1y * sz;
        let qy = sz * e1x - e1z * sx;
        let qz = sx * e1y - e1x * sy;
        let w = (dx * qx + dy * qy + dz * qz) * inv;
        let t = (e2x * qx + e2y * qy + e2z * qz) * inv;
        let (zero, one) = (s(0.0), s(1.0));
        let hit =
            l.ne(det, zero) & l.ge(u, zero) & l.ge(w, zero) & l.le(u + w, one) & l.gt(t, s(t_min));
        (hit, l.store(t))
    }

    /// [`Group::hits`] one lane at a time by [`moller_trumbore`] itself: what the
    /// lanes must give, for the tests.
    #[cfg(test)]
    fn hits_one_by_one(&self, ray: &Ray, t_min: f64) -> (u32, [Option<f64>; LANES]) {
        let found: [Option<f64>; LANES] = std::array::from_fn(|lane| {
            moller_trumbore(&self.tri(lane), ray, t_min, f64::INFINITY, 0, &mut ())
        });
        let bits = (0..LANES)
            .filter(|&l| found[l].is_some())
            .map(|l| 1 << l)
            .sum();
        (bits, found)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Coordinates on a coarse grid (so that rays meet edges and corners exactly), or
    /// anywhere.
    fn coordinate() -> impl Strategy<Value = f64> {
        prop_oneof![(-4i32..4).prop_map(|k| k as f64 * 0.5), -4.0f64..4.0]
    }

    fn point() -> impl Strategy<Value = DVec3> {
        prop::array::uniform3(coordinate()).prop_map(DVec3::from)
    }

    fn tri() -> impl Strategy<Value = Option<Tri>> {
        prop::option::weighted(
            0.9,
            (point(), point(), point()).prop_map(|(a, b, c)| Tri {
                v0: a,
                e1: b - a,
                e2: c - a,
            }),
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        /// Each lane gives what Möller–Trumbore gives its triangle alone, bit for bit:
        /// rays through corners and along edges, in a triangle's plane, triangles
        /// without area, empty lanes.
        #[test]
        fn each_lane_is_the_triangle_tested_alone(
            tris in prop::array::uniform4(tri()),
            o in point(),
            d in point(),
            t_min in prop_oneof![Just(0.0), Just(1e-9), 0.0f64..2.0],
        ) {
            let g = Group::new(tris);
            let ray = Ray::new(o, d);
            let (want, alone) = g.hits_one_by_one(&ray, t_min);
            // As dispatched (one AVX register where the processor has AVX2), and in
            // two SSE2 registers.
            for (bits, t) in [g.hits(&ray, t_min), g.hits_in(Portable, &ray, t_min)] {
                prop_assert_eq!(bits, want);
                for lane in 0..LANES {
                    if let Some(a) = alone[lane] {
                        prop_assert_eq!(t[lane].to_bits(), a.to_bits(), "lane {}", lane);
                    }
                    if tris[lane].is_none() {
                        prop_assert_eq!(bits >> lane & 1, 0);
                    }
                }
            }
        }
    }

    #[test]
    fn a_lane_holds_its_triangle_and_an_empty_lane_is_never_hit() {
        let t = Tri {
            v0: DVec3::new(-1.0, -1.0, 0.0),
            e1: DVec3::new(2.0, 0.0, 0.0),
            e2: DVec3::new(0.0, 2.0, 0.0),
        };
        let g = Group::new([None, Some(t), None, None]);
        assert_eq!(g.tri(1).e2, t.e2);
        // Straight down onto the triangle's corner at (−1, −1): every empty lane
        // (its corner at the origin too) has no area, so only lane 1 is hit.
        let ray = Ray::new(DVec3::new(-0.5, -0.5, 3.0), DVec3::new(0.0, 0.0, -1.0));
        let (bits, t) = g.hits(&ray, 1e-9);
        assert_eq!(bits, 0b10);
        assert_eq!(t[1], 3.0);
    }
}
