//! `GET /`: the studio, a single page to write a scene, render it, trace a pixel and grade
//! a file, built from `web/` into `web/dist/` (committed, so building the crate needs no
//! Node.js) and embedded here. Each asset is embedded twice, as written and gzipped by the
//! bundler, so that no compressor runs per request: a client that accepts gzip gets the
//! small one.
//!
//! The page talks only to this server's own `/v1/…` routes, so its policy forbids every
//! other origin; CodeMirror writes its styles into `<style>` elements, hence
//! `'unsafe-inline'` for styles (and only for styles).

use axum::Router;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use super::AppState;

/// The page's content security policy: nothing from elsewhere, images from the page's own
/// blobs and data URLs (the streamed render, the difference image).
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; \
     img-src 'self' blob: data:; connect-src 'self'; base-uri 'none'; form-action 'none'; \
     frame-ancestors 'none'";

/// One embedded file: its media type, its bytes, and the same bytes gzipped.
struct Asset {
    media_type: &'static str,
    plain: &'static [u8],
    gzip: &'static [u8],
}

macro_rules! asset {
    ($media:expr, $file:literal) => {
        Asset {
            media_type: $media,
            plain: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/web/dist/", $file)),
            gzip: include_bytes!(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/web/dist/",
                $file,
                ".gz"
            )),
        }
    };
}

static INDEX: Asset = asset!("text/html; charset=utf-8", "index.html");
static SCRIPT: Asset = asset!("text/javascript; charset=utf-8", "studio.js");
static STYLE: Asset = asset!("text/css; charset=utf-8", "studio.css");

/// The routes: `GET /` and the page's script and style sheet.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/", get(|h: HeaderMap| async move { serve(&INDEX, &h) }))
        .route(
            "/studio/studio.js",
            get(|h: HeaderMap| async move { serve(&SCRIPT, &h) }),
        )
        .route(
            "/studio/studio.css",
            get(|h: HeaderMap| async move { serve(&STYLE, &h) }),
        )
}

/// Whether `Accept-Encoding` names gzip with a non-zero weight.
fn accepts_gzip(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|coding| {
            let mut parts = coding.split(';').map(str::trim);
            let name = parts.next().unwrap_or("");
            let refused = parts.any(|p| {
                p.strip_prefix("q=")
                    .and_then(|q| q.parse::<f32>().ok())
                    .is_some_and(|q| q == 0.0)
            });
            (name.eq_ignore_ascii_case("gzip") || name == "*") && !refused
        })
}

fn serve(asset: &'static Asset, request: &HeaderMap) -> Response {
    let gzip = accepts_gzip(request);
    let body = if gzip { asset.gzip } else { asset.plain };
    let mut res = body.into_response();
    let h = res.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(asset.media_type),
    );
    if gzip {
        h.insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    }
    h.insert(header::VARY, HeaderValue::from_static("accept-encoding"));
    // The assets change only with the binary: revalidate rather than keep a stale page.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    res
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    fn with(value: &'static str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::ACCEPT_ENCODING, HeaderValue::from_static(value));
        h
    }

    #[test]
    fn gzip_only_when_accepted() {
        assert!(accepts_gzip(&with("gzip, deflate, br")));
        assert!(accepts_gzip(&with("br;q=1.0, GZIP;q=0.5")));
        assert!(accepts_gzip(&with("*")));
        assert!(!accepts_gzip(&with("gzip;q=0")));
        assert!(!accepts_gzip(&with("br, deflate")));
        assert!(!accepts_gzip(&HeaderMap::new()));
    }

    #[test]
    fn each_gzipped_asset_is_its_plain_twin() {
        for asset in [&INDEX, &SCRIPT, &STYLE] {
            let mut unzipped = Vec::new();
            flate2::read::GzDecoder::new(asset.gzip)
                .read_to_end(&mut unzipped)
                .unwrap();
            assert_eq!(unzipped, asset.plain, "{}", asset.media_type);
        }
    }

    #[test]
    fn the_page_stays_under_a_megabyte() {
        let total: usize = [&INDEX, &SCRIPT, &STYLE]
            .iter()
            .map(|a| a.plain.len())
            .sum();
        assert!(total < 1 << 20, "{total} bytes");
    }
}
