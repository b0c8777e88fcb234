//! The largest scene a caller accepts. The server takes these from its configuration and
//! refuses what exceeds them as an invalid scene (422), before tracing anything.

/// The deepest `max_depth` any scene may ask for, whatever its caller's [`Limits`]: each
/// bounce of a ray is a level of recursion on a tracing thread's stack (up to some 2 KB
/// a level where a pixel is explained, on threads of 2 MiB), and between two facing
/// mirrors a deeper one would overflow that stack, which aborts the whole process.
pub const DEEPEST: u32 = 100;

/// Upper bounds on what a scene may ask for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest `width × height`.
    pub max_pixels: u64,
    /// Largest `image.samples` (rays per pixel are its square).
    pub max_samples: u32,
    /// Largest `max_depth` (never more than [`DEEPEST`], whatever this says).
    pub max_depth: u32,
    /// Most objects.
    pub max_objects: u64,
    /// Most triangles over all meshes.
    pub max_triangles: u64,
}

impl Limits {
    /// No bounds but the renderer's own, [`DEEPEST`] (the command line renders what its
    /// user asks for).
    pub const NONE: Limits = Limits {
        max_pixels: u64::MAX,
        max_samples: u32::MAX,
        max_depth: DEEPEST,
        max_objects: u64::MAX,
        max_triangles: u64::MAX,
    };
}

impl Default for Limits {
    /// The server's defaults: a 4096 × 4096 frame, 8 × 8 samples, depth 10, a million
    /// objects, four million triangles.
    fn default() -> Self {
        Limits {
            max_pixels: 4096 * 4096,
            max_samples: 8,
            max_depth: 10,
            max_objects: 1_000_000,
            max_triangles: 4_000_000,
        }
    }
}
