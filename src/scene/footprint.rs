//! What a scene costs in memory, estimated before it is allocated (the server charges it
//! to its memory budget first, `server::memory`):
//!
//! - [`parse_peak`]: reading and validating a document. Validation reads a well-formed
//!   document straight into its types, but a document with problems goes through a
//!   JSON tree (`serde_json::Value`) to report them all, and that tree is 30–60 times
//!   the size of its text for small objects (`{"hit": false}` is 14 bytes of text, a
//!   B-tree node of 600). So the estimate counts the tree's parts with a cheap pre-scan
//!   of the text ([`JsonShape::scan`], one pass, no allocation per value) and prices
//!   each at what it costs at most;
//! - [`built`]: what a validated scene holds while it renders (objects, materials,
//!   meshes and the bounding volume hierarchy over them), from its counts.
//!
//! Both are upper bounds: the tests measure the real peak with a counting allocator and
//! check that the estimate is not below it.

use crate::geometry::Shape;

use super::{Problem, Scene};

/// The structure of a JSON text: how many of each part its tree would have.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JsonShape {
    /// Bytes of text.
    pub bytes: u64,
    /// Objects (`{…}`).
    pub objects: u64,
    /// Members of all objects.
    pub members: u64,
    /// Arrays (`[…]`).
    pub arrays: u64,
    /// Elements of all arrays.
    pub elements: u64,
    /// Strings, keys included.
    pub strings: u64,
    /// Bytes inside strings, keys included.
    pub string_bytes: u64,
    /// The pointer of the array with the most elements, and how many: the field that
    /// drives the size of a large document.
    pub largest_array: Option<(String, u64)>,
}

/// One open container while scanning.
struct Open {
    array: bool,
    /// Elements (arrays) or members (objects) so far.
    count: u64,
    /// For an object, the byte range of the key of the member being read.
    key: (usize, usize),
}

impl JsonShape {
    /// Scans `text` once, counting its parts. Text that is not JSON is counted as far
    /// as it looks like JSON; the counts never exceed its length.
    pub fn scan(text: &[u8]) -> JsonShape {
        let mut s = JsonShape {
            bytes: text.len() as u64,
            ..JsonShape::default()
        };
        let mut stack: Vec<Open> = Vec::new();
        // Whether a value has started in the innermost array since its last comma
        // (a `[]` has no elements, a `[1]` one).
        let mut pending = false;
        let mut i = 0;
        while i < text.len() {
            let c = text[i];
            match c {
                b'"' => {
                    let start = i + 1;
                    i = start;
                    while i < text.len() && text[i] != b'"' {
                        i += if text[i] == b'\\' { 2 } else { 1 };
                    }
                    let end = i.min(text.len());
                    s.strings += 1;
                    s.string_bytes += (end - start) as u64;
                    if let Some(top) = stack.last_mut()
                        && !top.array
                        && is_key(text, i + 1)
                    {
                        top.key = (start, end);
                        top.count += 1;
                    } else {
                        pending = true;
                    }
                }
                b'{' | b'[' => {
                    if c == b'{' {
                        s.objects += 1;
                    } else {
                        s.arrays += 1;
                    }
                    pending = true;
                    count_element(&mut stack, &mut pending);
                    stack.push(Open {
                        array: c == b'[',
                        count: 0,
                        key: (0, 0),
                    });
                    pending = false;
                }
                b'}' | b']' => {
                    count_element(&mut stack, &mut pending);
                    if let Some(open) = stack.pop() {
                        if open.array {
                            s.elements += open.count;
                            if s.largest_array
                                .as_ref()
                                .is_none_or(|(_, n)| open.count > *n)
                            {
                                s.largest_array = Some((pointer(text, &stack), open.count));
                            }
                        } else {
                            s.members += open.count;
                        }
                    }
                    // The container itself is the value that was pending in its parent,
                    // counted when it opened.
                    pending = false;
                }
                b',' => count_element(&mut stack, &mut pending),
                b' ' | b'\t' | b'\n' | b'\r' | b':' => {}
                _ => pending = true,
            }
            i += 1;
        }
        s
    }
}

/// Whether the string that ended before `i` is a key (a `:` follows).
fn is_key(text: &[u8], mut i: usize) -> bool {
    while i < text.len() && text[i].is_ascii_whitespace() {
        i += 1;
    }
    text.get(i) == Some(&b':')
}

/// Counts the value pending in the innermost array, if any.
fn count_element(stack: &mut [Open], pending: &mut bool) {
    if *pending && let Some(top) = stack.last_mut().filter(|t| t.array) {
        top.count += 1;
    }
    *pending = false;
}

/// The JSON pointer of the innermost open container, from the keys and indices of the
/// containers around it.
fn pointer(text: &[u8], stack: &[Open]) -> String {
    let mut p = String::new();
    for open in stack {
        p.push('/');
        if open.array {
            // The element being read is the one counted last.
            p.push_str(&open.count.saturating_sub(1).to_string());
        } else {
            let key = String::from_utf8_lossy(&text[open.key.0..open.key.1]);
            p.push_str(&key.replace('~', "~0").replace('/', "~1"));
        }
    }
    p
}

/// What each part of a JSON tree costs at most, in bytes, with serde_json's maps
/// (B-trees, or index maps with `preserve_order`) and the system allocator's rounding.
/// The `Value` of an element or member is 32 bytes; a vector grows by doubling, so an
/// element costs up to twice that; a B-tree leaf node of 11 members is about 630 bytes,
/// so a small object costs a node, and every five members of a large one another.
mod price {
    pub const OBJECT: u64 = 720;
    pub const MEMBER: u64 = 190;
    pub const ARRAY: u64 = 48;
    pub const ELEMENT: u64 = 64;
    pub const STRING: u64 = 48;
}

/// The most memory reading and validating a document of this shape may take: the text's
/// JSON tree (the path of a document with problems), the typed document and the scene
/// built from it, which hold no more than the tree, and the problems (bounded).
pub fn parse_peak(shape: &JsonShape) -> u64 {
    let tree = shape.objects * price::OBJECT
        + shape.members * price::MEMBER
        + shape.arrays * price::ARRAY
        + shape.elements * price::ELEMENT
        + shape.strings * price::STRING
        + shape.string_bytes * 2;
    // The typed document and the scene are smaller than the tree, measured at no more
    // than half of it; the problems and the rest are at most a MiB.
    tree + tree / 2 + shape.bytes + (1 << 20)
}

/// The fields that drive a document's parse: its largest array (`/objects`, a mesh's
/// `vertices`), or the whole document.
pub fn parse_fields(shape: &JsonShape) -> Vec<Problem> {
    match &shape.largest_array {
        Some((at, n)) if *n > 0 => vec![Problem::new(
            at.clone(),
            format!("{n} elements drive the memory its parsing needs"),
        )],
        _ => vec![Problem::new(
            "",
            "its size drives the memory its parsing needs",
        )],
    }
}

/// Bytes an object holds in a built scene at most, its document, transforms and share
/// of the bounding volume hierarchy included (2 300 measured for spheres).
const OBJECT_BYTES: u64 = 4096;
/// Bytes a mesh triangle holds at most: its indices, its share of the vertices and
/// normals, and its share of the mesh's own hierarchy (400 measured with its vertex,
/// when each triangle took 76 bytes in leaf order; stored in groups of four lanes, a
/// triangle takes at most 1.75 slots of those, 57 bytes more, and fewer nodes: a
/// whole `raytile hits` of 200 000 scattered triangles peaked at 132.3 MiB where it
/// had peaked at 134.6 MiB, of `mesh-100k` at 39.3 MiB where at 45.6 MiB).
const TRIANGLE_BYTES: u64 = 512;
/// Bytes a mesh vertex holds.
const VERTEX_BYTES: u64 = 64;

/// The memory a validated scene holds while it renders, from its counts: the scene, its
/// document and the acceleration structure built over it.
pub fn built(scene: &Scene) -> u64 {
    let mut vertices = 0u64;
    for o in &scene.objects {
        if let Shape::Mesh(m) = &o.shape {
            vertices += m.positions.len() as u64;
        }
    }
    scene.objects.len() as u64 * OBJECT_BYTES
        + scene.triangles() * TRIANGLE_BYTES
        + vertices * VERTEX_BYTES
        + (scene.materials.len() + scene.lights.len()) as u64 * OBJECT_BYTES
        + (64 << 10)
}

/// The fields that drive a built scene's size: the objects.
pub fn built_fields(scene: &Scene) -> Vec<Problem> {
    vec![Problem::new(
        "/objects",
        format!(
            "{} objects and {} triangles drive the memory the scene holds",
            scene.objects.len(),
            scene.triangles()
        ),
    )]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure;
    use crate::scene::{Limits, parse};

    #[test]
    fn the_scan_counts_every_part() {
        let s = JsonShape::scan(br#"{"a": [1, "xy", {"b": []}, [2, 3]], "c": null}"#);
        assert_eq!(
            (s.objects, s.members, s.arrays, s.elements),
            (2, 3, 3, 6),
            "{s:?}"
        );
        assert_eq!((s.strings, s.string_bytes), (4, 5));
        assert_eq!(s.largest_array, Some(("/a".into(), 4)));
        let s = JsonShape::scan(
            br#"{"objects": [{"x": 1}, {"y": [[1,2,3],[4,5,6],[7,8,9],[1,1,1],[0,0,0]]}]}"#,
        );
        assert_eq!(s.largest_array, Some(("/objects/1/y".into(), 5)));
        // Escaped quotes stay inside their string; nonsense counts no more than it is long.
        let s = JsonShape::scan(br#"["a\"b", "c"]"#);
        assert_eq!((s.strings, s.elements), (2, 2));
        let junk = b"]]]}}}{{{[[[,,,::\"";
        let s = JsonShape::scan(junk);
        assert!(s.objects + s.arrays + s.elements + s.members <= junk.len() as u64);
    }

    fn spheres(n: usize, valid: bool) -> Vec<u8> {
        let one = if valid {
            r#"{"shape": "sphere", "material": "red", "transform": [{"translate": [0, 0, 5]}]}"#
        } else {
            r#"{"shape": "sphere", "radius": -1}"#
        };
        let objects = vec![one; n].join(",");
        document(&objects)
    }

    fn mesh(n: usize, valid: bool) -> Vec<u8> {
        let vertices: Vec<String> = (0..n + 2)
            .map(|i| format!("[{}, {}, -5]", i as f64 * 0.001, (i % 2) as f64))
            .collect();
        let faces: Vec<String> = (0..n)
            .map(|i| format!("[{}, {}, {}]", i, i + 1, i + 2))
            .collect();
        document(&format!(
            r#"{{"shape": "mesh", "material": "red", "positions": [{}], "indices": [{}]{}}}"#,
            vertices.join(","),
            faces.join(","),
            if valid { "" } else { r#", "bogus": 1"# }
        ))
    }

    fn document(objects: &str) -> Vec<u8> {
        format!(
            r#"{{"version": 1, "image": {{"width": 8, "height": 8}},
                "camera": {{"focal_length": 1}},
                "materials": {{"red": {{"diffuse": [0.8, 0.1, 0.1]}}}},
                "lights": [{{"type": "point", "position": [5, 5, 5], "colour": [1, 1, 1]}}],
                "objects": [{objects}]}}"#
        )
        .into_bytes()
    }

    fn limits() -> Limits {
        Limits {
            max_objects: 10_000_000,
            max_triangles: 10_000_000,
            ..Limits::default()
        }
    }

    /// The estimate of parsing `text` against the real peak, and of the scene built
    /// from it (with its hierarchy) against what it really holds.
    fn check(text: &[u8], expect_valid: bool) {
        let shape = JsonShape::scan(text);
        let estimate = parse_peak(&shape);
        let base = measure::live();
        let (scene, peak) = measure::peak(|| parse(text, &limits()));
        eprintln!(
            "parse: peak {peak}, estimate {estimate}, {} bytes",
            text.len()
        );
        assert!(
            estimate >= peak,
            "parse: estimate {estimate} < peak {peak} for {shape:?}"
        );
        assert_eq!(scene.is_ok(), expect_valid, "{:?}", scene.err());
        if let Ok(scene) = scene {
            let parsed = measure::live() - base;
            // Building the hierarchies over the objects and inside the meshes, and
            // tracing a ray through them.
            let ((scene, world), peak) = measure::peak(|| {
                let world = scene.world();
                let ray = crate::geometry::Ray::new(glam::DVec3::ZERO, glam::DVec3::Z);
                std::hint::black_box(world.closest(&ray, 1e-9, f64::INFINITY));
                (scene, world)
            });
            let held = measure::live() - base;
            let estimate = built(&scene);
            drop(world);
            assert!(
                estimate >= parsed + peak,
                "built: estimate {estimate} < the scene {parsed} and the hierarchy's peak {peak}"
            );
            assert!(estimate >= held, "built: estimate {estimate} < held {held}");
        }
    }

    #[test]
    fn a_document_with_many_invalid_objects_is_priced_above_its_tree() {
        crate::measure::alone_or_return!(
            a_document_with_many_invalid_objects_is_priced_above_its_tree
        );
        check(&spheres(20_000, false), false);
    }

    #[test]
    fn a_valid_document_of_many_objects_is_priced_above_its_peak() {
        crate::measure::alone_or_return!(a_valid_document_of_many_objects_is_priced_above_its_peak);
        check(&spheres(20_000, true), true);
    }

    #[test]
    fn a_large_mesh_is_priced_above_its_peak() {
        crate::measure::alone_or_return!(a_large_mesh_is_priced_above_its_peak);
        check(&mesh(40_000, true), true);
        // A problem sends it through the JSON tree.
        check(&mesh(40_000, false), false);
    }
}
