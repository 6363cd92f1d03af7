//! Browser safety and early refusals, before any handler runs:
//!
//! - `Host` must be an IP literal, `localhost` or a name in
//!   `http.allowed_hosts` (a DNS-rebinding page carries its own domain name).
//! - A present `Origin` must be the daemon's own origin (the one the `Host`
//!   header names) or one of `http.allowed_origins`.
//! - A state-changing request (anything but GET, HEAD, OPTIONS) must carry
//!   `Content-Type: application/json` or an `Authorization: Bearer` header:
//!   neither can be sent cross-site without a CORS preflight, which this
//!   daemon never grants. (Multipart imports therefore need the header; in
//!   open-access mode any bearer value does.)
//! - A declared `Content-Length` above the route's limit is answered 413
//!   before a byte of the body is read.
//! - Every error response is a problem document ([`problem_everywhere`]),
//!   also the ones axum's extractors produce (path decoding, ...).
//!
//! The rules and their reasons: docs/http-hardening.md.

use super::problem::Problem;
use super::AppState;
use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::net::IpAddr;

/// The host part of a `Host` header value (`name`, `name:port`, `[v6]:port`), lowercased.
pub fn host_name(host: &str) -> &str {
    let h = host.trim();
    if let Some(rest) = h.strip_prefix('[') {
        return rest.split(']').next().unwrap_or("");
    }
    match h.rsplit_once(':') {
        // a bare IPv6 address has several colons and no port
        Some((name, port)) if !name.contains(':') && port.bytes().all(|b| b.is_ascii_digit()) => {
            name
        }
        _ => h,
    }
}

/// Whether a `Host` value may reach this daemon (see the module docs).
pub fn host_allowed(host: &str, allowed: &[String]) -> bool {
    let name = host_name(host).trim_end_matches('.');
    if name.is_empty() {
        return false;
    }
    name.parse::<IpAddr>().is_ok()
        || name.eq_ignore_ascii_case("localhost")
        || allowed.iter().any(|a| a.eq_ignore_ascii_case(name))
}

/// Whether an `Origin` value is the daemon's own (as named by `host`) or listed.
pub fn origin_allowed(origin: &str, host: Option<&str>, allowed: &[String]) -> bool {
    let o = origin.trim();
    if let Some(h) = host {
        for scheme in ["http://", "https://"] {
            if let Some(rest) = o.strip_prefix(scheme) {
                if rest.eq_ignore_ascii_case(h.trim()) {
                    return true;
                }
            }
        }
    }
    allowed.iter().any(|a| a.eq_ignore_ascii_case(o))
}

fn is_json(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(|ct| {
            ct.split(';')
                .next()
                .unwrap_or("")
                .trim()
                .eq_ignore_ascii_case("application/json")
        })
        .unwrap_or(false)
}

fn has_bearer(headers: &HeaderMap) -> bool {
    headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|s| s.split_once(' '))
        .map(|(scheme, tok)| scheme.eq_ignore_ascii_case("bearer") && !tok.trim().is_empty())
        .unwrap_or(false)
}

/// The declared body a request may have (bytes): a multipart recording set
/// `max_upload_bytes`, a WAV stimulus the smaller of it and the stimulus
/// file's limit, everything else `max_json_bytes`.
pub fn body_limit(cfg: &crate::config::Config, method: &Method, path: &str) -> usize {
    match (method == Method::POST, path) {
        (true, "/api/v1/measurements") => cfg.max_upload_bytes,
        (true, "/api/v1/stimuli") => cfg.max_upload_bytes.min(super::stimuli::MAX_STIMULUS_BYTES),
        _ => cfg.max_json_bytes,
    }
}

fn forbidden(kind: &'static str, title: &'static str, detail: String) -> Response {
    Problem::new(StatusCode::FORBIDDEN, kind, title, detail).into_response()
}

/// The Host and Origin rules of the module docs (also the fleet role's,
/// which serves the UI too): Some: the 403 to answer.
pub fn host_and_origin(http: &crate::config::HttpConfig, req: &Request) -> Option<Response> {
    let headers = req.headers();
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string)
        .or_else(|| req.uri().authority().map(|a| a.to_string()));
    if let Some(h) = &host {
        if !host_allowed(h, &http.allowed_hosts) {
            return Some(forbidden(
                "host-not-allowed",
                "Host not allowed",
                format!(
                    "Host '{}' is not a name of this daemon (IP literals, localhost and http.allowed_hosts are)",
                    host_name(h)
                ),
            ));
        }
    }
    if let Some(o) = headers.get(header::ORIGIN) {
        let o = o.to_str().unwrap_or("<not text>");
        if !origin_allowed(o, host.as_deref(), &http.allowed_origins) {
            return Some(forbidden(
                "origin-not-allowed",
                "Origin not allowed",
                format!("requests from origin '{o}' are refused (the daemon's own origin and http.allowed_origins are allowed)"),
            ));
        }
    }
    None
}

/// The checks of the module docs, in that order.
pub async fn browser_safety(State(st): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(r) = host_and_origin(&st.cfg.http, &req) {
        return r;
    }
    let headers = req.headers();
    let m = req.method();
    let safe = m == Method::GET || m == Method::HEAD || m == Method::OPTIONS;
    if !safe && !is_json(headers) && !has_bearer(headers) {
        return Problem::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported-media-type",
            "JSON or bearer token required",
            "a state-changing request needs 'Content-Type: application/json' or an 'Authorization: Bearer' header (cross-site protection)",
        )
        .into_response();
    }
    let limit = body_limit(&st.cfg, m, req.uri().path());
    if let Some(len) = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|s| s.trim().parse::<u64>().ok())
    {
        if len > limit as u64 {
            let mut r = Problem::too_large(limit).into_response();
            // The body is not read: the connection cannot be reused.
            r.headers_mut().insert(
                header::CONNECTION,
                header::HeaderValue::from_static("close"),
            );
            return r;
        }
    }
    next.run(req).await
}

/// The body stopped arriving for longer than `http.body_read_timeout_s`.
pub fn body_timeout(detail: String) -> Problem {
    Problem::new(
        StatusCode::REQUEST_TIMEOUT,
        "timeout",
        "Request body timed out",
        detail,
    )
}

/// Turns every error response that is not JSON into a problem document
/// (axum's own rejections are text/plain), keeping status and headers.
pub async fn problem_everywhere(req: Request, next: Next) -> Response {
    let resp = next.run(req).await;
    let status = resp.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return resp;
    }
    // problem documents, and JSON bodies a handler chose (the /readyz report)
    let is_json = resp.headers().get(header::CONTENT_TYPE).is_some_and(|v| {
        v.as_bytes().starts_with(b"application/problem+json")
            || v.as_bytes().starts_with(b"application/json")
    });
    if is_json {
        return resp;
    }
    let (parts, body) = resp.into_parts();
    let text = match axum::body::to_bytes(body, 4096).await {
        Ok(b) if !b.is_empty() => String::from_utf8_lossy(&b).trim().to_string(),
        _ => status.canonical_reason().unwrap_or("error").to_string(),
    };
    let kind = match status {
        StatusCode::BAD_REQUEST => "bad-request",
        StatusCode::NOT_FOUND => "not-found",
        StatusCode::PAYLOAD_TOO_LARGE => "too-large",
        StatusCode::REQUEST_TIMEOUT => "timeout",
        StatusCode::UNSUPPORTED_MEDIA_TYPE => "unsupported-media-type",
        StatusCode::SERVICE_UNAVAILABLE => "unavailable",
        s if s.is_server_error() => "internal",
        _ => "client-error",
    };
    let title = status.canonical_reason().unwrap_or("Error");
    let mut p = Problem::new(status, kind, title, text).into_response();
    for (k, v) in parts.headers.iter() {
        if k != header::CONTENT_TYPE && k != header::CONTENT_LENGTH {
            p.headers_mut().insert(k.clone(), v.clone());
        }
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_names_are_parsed_with_and_without_ports() {
        assert_eq!(host_name("127.0.0.1:8750"), "127.0.0.1");
        assert_eq!(host_name("[::1]:8750"), "::1");
        assert_eq!(host_name("::1"), "::1");
        assert_eq!(host_name("Bench.lab"), "Bench.lab");
        assert_eq!(host_name("evil.example:80"), "evil.example");
    }

    #[test]
    fn hosts_ip_literals_localhost_and_listed_names() {
        let listed = vec!["bench-7.lab".to_string()];
        for ok in [
            "127.0.0.1:8750",
            "[::1]:8750",
            "10.0.0.7",
            "LOCALHOST:8750",
            "bench-7.lab:8750",
            "localhost.",
        ] {
            assert!(host_allowed(ok, &listed), "{ok}");
        }
        for bad in ["evil.example:8750", "127.0.0.1.nip.io", "", "bench-8.lab"] {
            assert!(!host_allowed(bad, &listed), "{bad}");
        }
    }

    #[test]
    fn origins_own_or_listed() {
        let listed = vec!["https://mes.lab".to_string()];
        assert!(origin_allowed(
            "http://127.0.0.1:8750",
            Some("127.0.0.1:8750"),
            &listed
        ));
        assert!(origin_allowed("https://mes.lab", Some("x"), &listed));
        assert!(!origin_allowed(
            "http://127.0.0.1:9999",
            Some("127.0.0.1:8750"),
            &listed
        ));
        assert!(!origin_allowed("null", Some("127.0.0.1:8750"), &listed));
        assert!(!origin_allowed("https://evil.example", None, &listed));
    }
}
