//! What the hit-data formats share: which formats there are (with their names,
//! extensions and media types), the record a pixel is written as, and the record it is
//! read back as.

use serde::{Deserialize, Serialize};

use super::ReadError;
use crate::geometry::Surface;
use crate::render::Rect;
use crate::scene::Scene;

/// The hit-data formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HitFormat {
    /// One JSON document, pixels in row-major order.
    Json,
    /// One JSON document per tile and line, in the order tiles finish.
    Ndjson,
    /// A NumPy structured array of shape `(h, w)`.
    Npy,
    /// A CSV table with a header, pixels in row-major order.
    Csv,
}

impl HitFormat {
    /// Every format, the default (JSON) first.
    pub const ALL: [HitFormat; 4] = [
        HitFormat::Json,
        HitFormat::Ndjson,
        HitFormat::Npy,
        HitFormat::Csv,
    ];

    /// The name: `json`, `ndjson`, `npy`, `csv` (also the usual file extension).
    pub const fn name(self) -> &'static str {
        match self {
            HitFormat::Json => "json",
            HitFormat::Ndjson => "ndjson",
            HitFormat::Npy => "npy",
            HitFormat::Csv => "csv",
        }
    }

    /// The name as prose writes it: `JSON`, `NDJSON`, `NPY`, `CSV`.
    pub const fn title(self) -> &'static str {
        match self {
            HitFormat::Json => "JSON",
            HitFormat::Ndjson => "NDJSON",
            HitFormat::Npy => "NPY",
            HitFormat::Csv => "CSV",
        }
    }

    /// The media type.
    pub const fn media_type(self) -> &'static str {
        match self {
            HitFormat::Json => "application/json",
            HitFormat::Ndjson => "application/x-ndjson",
            HitFormat::Npy => "application/x-npy",
            HitFormat::Csv => "text/csv",
        }
    }

    /// The format of a name (case and surrounding space ignored); `jsonl` is NDJSON.
    pub fn from_name(s: &str) -> Option<HitFormat> {
        let s = s.trim().to_ascii_lowercase();
        if s == "jsonl" {
            return Some(HitFormat::Ndjson);
        }
        HitFormat::ALL.into_iter().find(|f| f.name() == s)
    }

    /// The format of a file name's extension (`.json`, `.ndjson` or `.jsonl`, `.npy`,
    /// `.csv`, in any case).
    pub fn from_path(p: &std::path::Path) -> Option<HitFormat> {
        HitFormat::from_name(p.extension()?.to_str()?)
    }

    /// The format of a media type, parameters ignored; `application/jsonl` is NDJSON.
    pub fn from_media_type(t: &str) -> Option<HitFormat> {
        let essence = t
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        if essence == "application/jsonl" {
            return Some(HitFormat::Ndjson);
        }
        HitFormat::ALL
            .into_iter()
            .find(|f| f.media_type() == essence)
    }
}

/// One pixel's hit data as raytile writes it: the fields JSON and NDJSON name; NPY and
/// CSV carry the same values in their own layout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PixelHit {
    /// Column.
    pub u: u32,
    /// Row.
    pub v: u32,
    /// Whether anything was hit.
    pub hit: bool,
    /// Index of the object hit.
    pub object: Option<u32>,
    /// Its name.
    pub name: Option<String>,
    /// Ray parameter along the unnormalised primary direction.
    pub lambda: Option<f64>,
    /// World-space point.
    pub point: Option<[f64; 3]>,
    /// Object-space point.
    pub object_point: Option<[f64; 3]>,
    /// Unit world-space normal.
    pub normal: Option<[f64; 3]>,
    /// Cube face (`"+x"` … `"-z"`).
    pub face: Option<String>,
}

impl PixelHit {
    /// The record of pixel `(u, v)`, the object named as `scene` names it.
    pub fn new(scene: &Scene, u: u32, v: u32, s: &Option<Surface>) -> PixelHit {
        let name = s.as_ref().and_then(|s| scene.object_name(s.object));
        PixelHit::from_surface(u, v, s, name)
    }

    /// The record of pixel `(u, v)` whose first hit is `s`, on the object called `name`.
    pub fn from_surface(u: u32, v: u32, s: &Option<Surface>, name: Option<&str>) -> PixelHit {
        match s {
            None => PixelHit {
                u,
                v,
                hit: false,
                object: None,
                name: None,
                lambda: None,
                point: None,
                object_point: None,
                normal: None,
                face: None,
            },
            Some(s) => PixelHit {
                u,
                v,
                hit: true,
                object: Some(s.object),
                name: name.map(str::to_owned),
                lambda: Some(s.lambda),
                point: Some(s.point.to_array()),
                object_point: Some(s.object_point.to_array()),
                normal: Some(s.normal.to_array()),
                face: s.face.map(|f| f.label().to_owned()),
            },
        }
    }
}

/// Hit data as read, not yet placed in the frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HitData {
    /// The form it came in: a [`HitFormat::name`].
    pub format: &'static str,
    /// The frame size it declares (JSON's `width`/`height`, NPY's shape), if any.
    pub size: Option<(u32, u32)>,
    /// Groups of pixels; a group without explicit `u`, `v` is laid out row-major over its
    /// rectangle (a tile, a region, the NPY array, or else the whole frame).
    pub groups: Vec<Group>,
}

/// Pixels that share a layout.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Group {
    /// Where the group lies, when known.
    pub rect: Option<Rect>,
    /// Its pixels in order.
    pub pixels: Vec<SubmittedHit>,
}

/// One pixel as read: the fields grading compares.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SubmittedHit {
    /// Column, when given.
    pub u: Option<u32>,
    /// Row, when given.
    pub v: Option<u32>,
    /// Whether something was hit.
    pub hit: bool,
    /// Object index, when given.
    pub object: Option<u32>,
    /// Ray parameter.
    pub lambda: Option<f64>,
    /// World point.
    pub point: Option<[f64; 3]>,
    /// World normal.
    pub normal: Option<[f64; 3]>,
}

impl From<&PixelHit> for SubmittedHit {
    /// What a reader gives back of a written record.
    fn from(p: &PixelHit) -> SubmittedHit {
        SubmittedHit {
            u: Some(p.u),
            v: Some(p.v),
            hit: p.hit,
            object: p.object,
            lambda: p.lambda,
            point: p.point,
            normal: p.normal,
        }
    }
}

impl SubmittedHit {
    /// A hit must say where: `lambda` and `normal` are what is graded.
    pub(super) fn check(&self, at: impl Fn() -> String) -> Result<(), ReadError> {
        if self.hit {
            for (field, present) in [
                ("lambda", self.lambda.is_some()),
                ("normal", self.normal.is_some()),
            ] {
                if !present {
                    return Err(ReadError::BadValue {
                        at: at(),
                        message: format!("`hit` is true but `{field}` is missing"),
                    });
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geometry::Face;
    use glam::DVec3;

    /// Records that exercise every field: a miss, a hit without a face, a cube face hit
    /// with values that need all 17 digits to read back.
    pub fn sample_records() -> Vec<(u32, u32, Option<Surface>)> {
        let hit = |lambda, face| Surface {
            lambda,
            object: 3,
            point: DVec3::new(0.1 + 0.2, -0.0, 1e-300),
            object_point: DVec3::new(-1.0, 0.5, 2.0 / 3.0),
            normal: DVec3::new(1.0 / 3.0f64.sqrt(), -(2.0f64.sqrt()) / 2.0, 5e-324),
            front: true,
            face,
        };
        vec![
            (0, 0, None),
            (1, 0, Some(hit(2.0, None))),
            (
                0,
                1,
                Some(hit(std::f64::consts::PI * 1e10, Some(Face::NegZ))),
            ),
            (1, 1, None),
        ]
    }

    #[test]
    fn names_extensions_and_media_types_go_both_ways() {
        for f in HitFormat::ALL {
            assert_eq!(HitFormat::from_name(f.name()), Some(f));
            assert_eq!(HitFormat::from_media_type(f.media_type()), Some(f));
            let file = format!("out.{}", f.name().to_uppercase());
            assert_eq!(HitFormat::from_path(std::path::Path::new(&file)), Some(f));
        }
        assert_eq!(HitFormat::from_name(" JSONL "), Some(HitFormat::Ndjson));
        assert_eq!(
            HitFormat::from_media_type("text/csv; charset=utf-8"),
            Some(HitFormat::Csv)
        );
        assert_eq!(HitFormat::from_name("png"), None);
        assert_eq!(HitFormat::from_path(std::path::Path::new("out")), None);
    }
}
