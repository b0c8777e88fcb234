//! A rectangle of pixels, the region of a frame that the command line's `--region`, the
//! server's `?region=` and the bands of `render --servers` all name in one text form,
//! `x,y,w,h` ([`Rect`]'s `FromStr` and `Display`).

use std::fmt;
use std::str::FromStr;

/// A rectangle of pixels in full-frame coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
}

impl Rect {
    /// The whole `width × height` frame.
    pub fn frame(width: u32, height: u32) -> Rect {
        Rect {
            x: 0,
            y: 0,
            width,
            height,
        }
    }

    /// Number of pixels.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// Whether `self` lies within `outer`.
    pub fn within(&self, outer: &Rect) -> bool {
        self.x >= outer.x
            && self.y >= outer.y
            && self.x as u64 + self.width as u64 <= outer.x as u64 + outer.width as u64
            && self.y as u64 + self.height as u64 <= outer.y as u64 + outer.height as u64
    }

    /// The tiles of this rectangle, row-major, each at most `tile_px` square.
    pub fn tiles(&self, tile_px: u32) -> Vec<Rect> {
        self.tiles_of(tile_px, tile_px)
    }

    /// The tiles of this rectangle, row-major, each at most `tile_w × tile_h`; the tiles
    /// of one row of tiles share their top and height.
    pub fn tiles_of(&self, tile_w: u32, tile_h: u32) -> Vec<Rect> {
        let (tw, th) = (tile_w.max(1), tile_h.max(1));
        let mut out = Vec::new();
        let mut y = 0;
        while y < self.height {
            let h = th.min(self.height - y);
            let mut x = 0;
            while x < self.width {
                let w = tw.min(self.width - x);
                out.push(Rect {
                    x: self.x + x,
                    y: self.y + y,
                    width: w,
                    height: h,
                });
                x += w;
            }
            y += h;
        }
        out
    }
}

/// Why a text is not a region `x,y,w,h`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseRectError {
    /// Not four parts separated by commas.
    #[error("expected x,y,w,h (four whole numbers), got `{0}`")]
    Shape(String),
    /// A part that is not a whole number.
    #[error("`{0}` is not a whole number ≥ 0")]
    NotWhole(String),
    /// A width or height of 0.
    #[error("the region's width and height must be at least 1")]
    Empty,
}

impl FromStr for Rect {
    type Err = ParseRectError;

    /// Parses `x,y,w,h` (spaces around the numbers allowed), at least one pixel.
    fn from_str(s: &str) -> Result<Rect, ParseRectError> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        let [x, y, w, h] = parts.as_slice() else {
            return Err(ParseRectError::Shape(s.to_owned()));
        };
        let n = |t: &str| {
            t.parse::<u32>()
                .map_err(|_| ParseRectError::NotWhole(t.to_owned()))
        };
        let r = Rect {
            x: n(x)?,
            y: n(y)?,
            width: n(w)?,
            height: n(h)?,
        };
        if r.width == 0 || r.height == 0 {
            return Err(ParseRectError::Empty);
        }
        Ok(r)
    }
}

impl fmt::Display for Rect {
    /// `x,y,w,h`, as [`FromStr`] reads it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{},{},{}", self.x, self.y, self.width, self.height)
    }
}

/// A region that leaves the frame it was asked of.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the region {region} does not lie within the {width} × {height} frame")]
pub struct OutsideFrame {
    /// The region asked for.
    pub region: Rect,
    /// The frame's width.
    pub width: u32,
    /// The frame's height.
    pub height: u32,
}

/// The region asked for, or the whole `width × height` frame without one; an error when
/// it leaves the frame.
pub fn region_in_frame(
    region: Option<Rect>,
    width: u32,
    height: u32,
) -> Result<Rect, OutsideFrame> {
    let frame = Rect::frame(width, height);
    match region {
        None => Ok(frame),
        Some(r) if r.within(&frame) => Ok(r),
        Some(region) => Err(OutsideFrame {
            region,
            width,
            height,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x: u32, y: u32, width: u32, height: u32) -> Rect {
        Rect {
            x,
            y,
            width,
            height,
        }
    }

    #[test]
    fn regions_read_and_write_as_x_y_w_h() {
        assert_eq!("1,2,3,4".parse(), Ok(rect(1, 2, 3, 4)));
        assert_eq!(" 1, 2 ,3,4 ".parse(), Ok(rect(1, 2, 3, 4)));
        assert_eq!(rect(0, 7, 640, 1).to_string(), "0,7,640,1");
        let r = rect(4_294_967_295, 0, 1, 1);
        assert_eq!(r.to_string().parse(), Ok(r));
    }

    #[test]
    fn bad_regions_say_what_is_wrong() {
        let err = |s: &str| s.parse::<Rect>().unwrap_err().to_string();
        assert_eq!(
            err("1,2,3"),
            "expected x,y,w,h (four whole numbers), got `1,2,3`"
        );
        assert_eq!(err("-1, 0,1,1"), "`-1` is not a whole number ≥ 0");
        assert_eq!(
            err("0,0,4294967296,1"),
            "`4294967296` is not a whole number ≥ 0"
        );
        assert_eq!(
            err("0,0,0,5"),
            "the region's width and height must be at least 1"
        );
    }

    #[test]
    fn a_region_is_checked_against_its_frame() {
        assert_eq!(region_in_frame(None, 6, 5), Ok(rect(0, 0, 6, 5)));
        assert_eq!(
            region_in_frame(Some(rect(1, 1, 5, 4)), 6, 5),
            Ok(rect(1, 1, 5, 4))
        );
        assert_eq!(
            region_in_frame(Some(rect(0, 0, 7, 5)), 6, 5)
                .unwrap_err()
                .to_string(),
            "the region 0,0,7,5 does not lie within the 6 × 5 frame"
        );
    }
}
