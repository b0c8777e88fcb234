//! The canonical shapes of SPEC §2.2, each in its own object space, one file each.
//!
//! Every test takes a ray already carried into object space and returns the smallest
//! `λ` in `(t_min, t_max)` with the *part* that was hit (a cube face, a cap, a
//! triangle). Normals and other details are computed afterwards, for the closest hit
//! only. Each test reports its intermediate values to a [`Probe`](super::hit::Probe).

pub mod cone;
pub mod cube;
pub mod cylinder;
pub mod disk;
pub mod mesh;
pub mod plane;
pub mod sphere;

use std::sync::Arc;

pub use mesh::MeshData;

/// A shape as the scene describes it.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// The unit sphere `p · p = 1`.
    Sphere,
    /// The cube `[-1, 1]³`.
    Cube,
    /// The plane `y = 0`.
    Plane,
    /// The disk `y = 0, x² + z² ≤ 1`.
    Disk,
    /// The capped cylinder `x² + z² = 1, −1 ≤ y ≤ 1`.
    Cylinder,
    /// The capped cone with apex `(0, 1, 0)` and base radius 1 at `y = −1`.
    Cone,
    /// Triangles in object space.
    Mesh(Arc<MeshData>),
}

impl Shape {
    /// The name used in scene documents.
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Sphere => "sphere",
            Shape::Cube => "cube",
            Shape::Plane => "plane",
            Shape::Disk => "disk",
            Shape::Cylinder => "cylinder",
            Shape::Cone => "cone",
            Shape::Mesh(_) => "mesh",
        }
    }

    /// Closed shapes report the outward normal; open ones the side facing the ray.
    pub fn is_closed(&self) -> bool {
        matches!(
            self,
            Shape::Sphere | Shape::Cube | Shape::Cylinder | Shape::Cone
        )
    }
}

/// Solves `a λ² + b λ + c = 0` the way the lecture does, reporting to `probe`, and
/// returns the real roots in increasing order (`a > 0` assumed by callers that need order).
#[inline(always)]
pub(crate) fn solve_quadratic<P: super::hit::Probe>(
    surface: &'static str,
    a: f64,
    b: f64,
    c: f64,
    probe: &mut P,
) -> [Option<f64>; 2] {
    let disc = b * b - 4.0 * a * c;
    let roots = if disc < 0.0 || a == 0.0 {
        [None, None]
    } else if disc == 0.0 {
        [Some(-b / (2.0 * a)), None]
    } else {
        let s = disc.sqrt();
        let (r0, r1) = ((-b - s) / (2.0 * a), (-b + s) / (2.0 * a));
        [Some(r0.min(r1)), Some(r0.max(r1))]
    };
    if probe.active() {
        probe.quadratic(&super::hit::QuadraticTest {
            surface,
            a,
            b,
            c,
            discriminant: disc,
            roots,
        });
    }
    roots
}
