//! The web UI: static pages, ES modules and the vendored plotting library,
//! compiled into the binary (`include_bytes!`) and served at `/` and
//! `/ui/...`. No build step, no network at view time. The pages talk to the
//! daemon only through the public API (`/api/v1/...`) with the bearer token
//! the user typed in; the pages themselves are public (they hold no data).
//! See docs/ui.md and docs/decisions/0017-web-ui-stack.md.

use axum::extract::Path;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

/// One compiled-in file.
pub struct Asset {
    /// Path below `/ui/`.
    pub path: &'static str,
    pub content_type: &'static str,
    pub body: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $ct:expr) => {
        Asset {
            path: $path,
            content_type: $ct,
            body: include_bytes!(concat!("assets/", $path)),
        }
    };
}

const JS: &str = "text/javascript; charset=utf-8";

/// Every file of the UI.
pub const ASSETS: &[Asset] = &[
    asset!("index.html", "text/html; charset=utf-8"),
    asset!("style.css", "text/css; charset=utf-8"),
    asset!("app.js", JS),
    asset!("api.js", JS),
    asset!("plots.js", JS),
    asset!("svgplot.js", JS),
    asset!("util.js", JS),
    asset!("operator.js", JS),
    asset!("parts.js", JS),
    asset!("measurement.js", JS),
    asset!("compare.js", JS),
    asset!("diagnostics.js", JS),
    asset!("longterm.js", JS),
    asset!("studies.js", JS),
    asset!("qc.js", JS),
    asset!("verdict.js", JS),
    asset!("export.js", JS),
    asset!("report.js", JS),
    asset!("favicon.svg", "image/svg+xml"),
    asset!("vendor/uplot/uPlot.esm.js", JS),
    asset!("vendor/uplot/uPlot.min.css", "text/css; charset=utf-8"),
    asset!("vendor/uplot/LICENSE", "text/plain; charset=utf-8"),
];

/// Paths served without a token (the pages; every datum comes from the API).
pub fn is_public(path: &str) -> bool {
    path == "/" || path == "/favicon.ico" || path.starts_with("/ui/")
}

/// The compiled-in asset at `path` (below `/ui/`).
pub fn asset(path: &str) -> Option<&'static Asset> {
    ASSETS.iter().find(|a| a.path == path)
}

/// Scripts, styles and data only from this origin (no CDN, no inline script);
/// the websocket to this host.
const CSP: &str = "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; connect-src 'self' ws: wss:; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'";

/// UI development: with `SPRINGBENCH_UI_DIR=src/ui/assets` the files are read
/// from that directory at each request (edit, reload; no rebuild). Only the
/// files of [`ASSETS`] are served either way.
fn body(a: &Asset) -> axum::body::Body {
    if let Some(dir) = std::env::var_os("SPRINGBENCH_UI_DIR") {
        if let Ok(b) = std::fs::read(std::path::Path::new(&dir).join(a.path)) {
            return b.into();
        }
    }
    a.body.into()
}

fn serve(a: &Asset) -> Response {
    let mut r = (StatusCode::OK, body(a)).into_response();
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(a.content_type),
    );
    // Always revalidate: a new binary brings new pages.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    r
}

async fn index() -> Response {
    serve(asset("index.html").expect("index.html is compiled in"))
}

async fn favicon() -> Response {
    serve(asset("favicon.svg").expect("favicon.svg is compiled in"))
}

/// The UI's routes (no state needed). `not_found` answers a path under
/// `/ui/` that is no asset (the API's problem document): the UI knows no
/// HTTP error format of its own, and the API, which mounts these routes,
/// stays the one module above it.
pub fn router<S: Clone + Send + Sync + 'static>(not_found: fn(&str) -> Response) -> Router<S> {
    Router::new()
        .route("/", get(index))
        .route("/favicon.ico", get(favicon))
        .route(
            "/ui/{*path}",
            get(move |Path(path): Path<String>| async move {
                match asset(&path) {
                    Some(a) => serve(a),
                    None => not_found(&path),
                }
            }),
        )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_module_import_is_compiled_in() {
        // A relative import of a file that is not in ASSETS would be a 404 in
        // the browser: check every `from './x.js'` of every script.
        for a in ASSETS.iter().filter(|a| a.path.ends_with(".js")) {
            let text = std::str::from_utf8(a.body).expect("utf-8 script");
            for part in text.split("from '").skip(1) {
                let Some(target) = part.split('\'').next() else {
                    continue;
                };
                let Some(rel) = target.strip_prefix("./") else {
                    continue;
                };
                let dir = a.path.rsplit_once('/').map(|(d, _)| d).unwrap_or("");
                let full = if dir.is_empty() {
                    rel.to_string()
                } else {
                    format!("{dir}/{rel}")
                };
                assert!(
                    asset(&full).is_some(),
                    "{} imports {full}, which is not compiled in",
                    a.path
                );
            }
        }
    }

    #[test]
    fn pages_are_public_and_the_api_is_not() {
        assert!(is_public("/"));
        assert!(is_public("/ui/app.js"));
        assert!(!is_public("/api/v1/jobs"));
        assert!(!is_public("/uix"));
        assert!(asset("index.html").is_some());
        assert!(asset("../Cargo.toml").is_none());
    }
}
