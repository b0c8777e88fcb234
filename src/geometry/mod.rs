//! Geometry exactly as the course teaches it (`docs/spec/`): rays with unnormalised
//! directions, affine transforms with their inverses, the canonical shapes, bounding
//! boxes, the BVH, and the world that finds a ray's first hit.

pub mod arith;
pub mod bounds;
pub mod bvh;
pub mod hit;
pub mod ray;
pub mod shapes;
pub mod transform;
pub mod world;

pub use hit::{Face, Hit, Probe, Surface};
pub use ray::{Ray, Rays8};
pub use shapes::{CanonicalShape, Mesh, NeedsData, Shape, ShapeName};
pub use transform::Transform;
pub use world::{ShadowHint, World};
