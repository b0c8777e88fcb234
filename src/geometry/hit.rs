//! What a ray hits: the cheap record kept while searching (`Hit`), the full surface
//! record computed once for the closest hit (`Surface`), and the `Probe` through which a
//! shape test can report its intermediate values to `/v1/trace`.

use glam::DVec3;

/// The closest hit found so far: enough to rank hits, nothing more (pbrt's habit: the
/// full record only for the winner).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The ray parameter.
    pub lambda: f64,
    /// Index of the object in the scene's `objects`.
    pub object: u32,
    /// Which part of the shape: a cube face, a cylinder cap, a mesh triangle.
    pub part: u32,
}

impl Hit {
    /// Whether `self` ranks before `other`: smaller `λ`, ties to the object listed first
    /// (`docs/spec/shapes.md`, Which hit counts), then to the lower part index.
    #[inline]
    pub fn before(&self, other: &Hit) -> bool {
        self.lambda < other.lambda
            || (self.lambda == other.lambda
                && (self.object, self.part) < (other.object, other.part))
    }
}

/// A cube face, as `docs/spec/shapes.md` names them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Face {
    /// `x = +1`.
    PosX,
    /// `x = −1`.
    NegX,
    /// `y = +1`.
    PosY,
    /// `y = −1`.
    NegY,
    /// `z = +1`.
    PosZ,
    /// `z = −1`.
    NegZ,
}

impl Face {
    /// The faces in the order they are tested; a tie goes to the earlier one.
    pub const ALL: [Face; 6] = [
        Face::PosX,
        Face::NegX,
        Face::PosY,
        Face::NegY,
        Face::PosZ,
        Face::NegZ,
    ];

    /// `"+x"`, `"-x"`, …
    pub fn label(self) -> &'static str {
        match self {
            Face::PosX => "+x",
            Face::NegX => "-x",
            Face::PosY => "+y",
            Face::NegY => "-y",
            Face::PosZ => "+z",
            Face::NegZ => "-z",
        }
    }

    /// Parses a label.
    pub fn from_label(s: &str) -> Option<Face> {
        Face::ALL.into_iter().find(|f| f.label() == s)
    }

    /// The axis (0 = x) and the side (+1 or −1).
    pub fn axis_sign(self) -> (usize, f64) {
        let i = self as usize;
        (i / 2, if i.is_multiple_of(2) { 1.0 } else { -1.0 })
    }

    /// The outward normal in object space.
    pub fn normal(self) -> DVec3 {
        let (axis, sign) = self.axis_sign();
        let mut n = DVec3::ZERO;
        n[axis] = sign;
        n
    }
}

/// Everything known about the closest hit: the hit data of `docs/spec/hit-data.md`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// The ray parameter along the ray's own (unnormalised) direction.
    pub lambda: f64,
    /// Index of the object.
    pub object: u32,
    /// World-space point.
    pub point: DVec3,
    /// Object-space point.
    pub object_point: DVec3,
    /// Unit world-space normal as reported (`docs/spec/shapes.md`, Normals): outward for closed shapes, facing
    /// the ray's origin for open surfaces.
    pub normal: DVec3,
    /// Whether the ray arrives from the outside of the reported normal (`d · n < 0`).
    /// Shading uses it to know whether a refracted ray enters or leaves.
    pub front: bool,
    /// The cube face, for cubes.
    pub face: Option<Face>,
}

/// The values of one quadratic `a λ² + b λ + c = 0` (sphere, cylinder side, cone side).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadraticTest {
    /// Which surface: `"sphere"`, `"side"`.
    pub surface: &'static str,
    /// `a`.
    pub a: f64,
    /// `b`.
    pub b: f64,
    /// `c`.
    pub c: f64,
    /// `b² − 4ac`.
    pub discriminant: f64,
    /// The real roots, smaller first (one for a tangent).
    pub roots: [Option<f64>; 2],
}

/// The values of one planar face test (cube face, cap, plane, disk).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceTest {
    /// Which face: `"+x"`, `"top"`, `"plane"`, …
    pub face: &'static str,
    /// `λ` where the ray meets the face's plane; `None` when parallel (`|Δ| < 1e-12`).
    pub lambda: Option<f64>,
    /// The object-space point there.
    pub point: Option<DVec3>,
    /// Whether the point lies within the face.
    pub within: bool,
}

/// One triangle test of a mesh (Möller–Trumbore).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangleTest {
    /// Index of the triangle in the mesh's `indices`.
    pub triangle: u32,
    /// Barycentric `u`, `v` and `λ`; `None` when the ray is parallel to the triangle.
    pub uvt: Option<[f64; 3]>,
    /// Whether the triangle is hit in range.
    pub hit: bool,
}

/// Receives the intermediate values of a shape test. The tracer passes `()`, whose
/// methods are empty and compile away; `/v1/trace` passes a recorder.
pub trait Probe {
    /// An object's test begins: its index and the ray carried into its object space.
    #[inline(always)]
    fn object(&mut self, _index: u32, _object_ray: &crate::geometry::ray::Ray) {}
    /// A quadratic was solved.
    #[inline(always)]
    fn quadratic(&mut self, _q: &QuadraticTest) {}
    /// A planar face was tested.
    #[inline(always)]
    fn face(&mut self, _f: &FaceTest) {}
    /// A triangle was tested.
    #[inline(always)]
    fn triangle(&mut self, _t: &TriangleTest) {}
    /// Whether the probe wants values at all (lets callers skip building them).
    #[inline(always)]
    fn active(&self) -> bool {
        false
    }
}

impl Probe for () {}
